"""The type checker passes on the product (companion/ and behaviors/, ``[tool.mypy] files`` in
pyproject.toml), and guards its seams: the port between the procedures and the vehicle, and the
links that implement it (their conformance is checked in harness/port_stub.py).

A procedure that reads a member the port lacks, or a link that lacks a member of the port, fails
here, not silently at sea (a ``getattr(link, …, None)`` probe used to turn it into a None)."""
from __future__ import annotations

import ast
import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

if not os.environ.get("CI"):  # under CI the test extras are installed: a missing checker fails, never skips
    pytest.importorskip("mypy", reason="the type checker is in the test extras (pip install -e .[test])")


@pytest.mark.slow  # 6–21 s of one core (its cache cold, in a fresh clone): scheduled with the slow modules, first
def test_the_type_checker_passes_on_the_typed_seams():
    # mypy's own cache (.mypy_cache, ignored by git) keeps a developer's later runs to a few seconds; mypy
    # checks again whatever changed
    run = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr


def _link_probes(path: pathlib.Path) -> list[str]:
    """``getattr(link, …)`` or ``getattr(self.link, …)`` calls, and ``getattr`` on a link's part."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "getattr"
                and node.args):
            continue
        target = ast.unparse(node.args[0])
        if target in ("link", "self.link") or target.startswith(("link.", "self.link.", "getattr(link", "getattr(self.link")):
            found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_no_procedure_probes_the_link():
    probes = [probe for folder in ("companion/procedures", "companion/service", "behaviors")
              for path in sorted((ROOT / folder).glob("*.py")) for probe in _link_probes(path)]
    assert probes == [], "read the link through companion.link.port.VehiclePort:\n" + "\n".join(probes)
