"""The layers hold (SPEC §5): no import circle among the project's modules, no import from a lower
floor to a higher one, the simulator and the companion never import each other, and the link
stays small (its facade under 200 lines, no module over 350).

Every ``import`` and ``from … import`` statement is read from the source with ``ast``, at any depth
(an import inside a function is still an arrow between modules).
"""
from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("companion", "behaviors", "sim", "harness")

#: floors, lowest first: a module may import from its own floor and those below
FLOORS: tuple[tuple[str, ...], ...] = (
    ("companion.errors", "companion.checks", "companion.interface"),
    ("companion.numerics",),
    ("companion.link",),
    ("behaviors",),
    ("companion.records",),
    ("companion.procedures",),
    ("companion.rehearsal",),
    ("companion.service",),
    ("companion.sweep",),
    ("companion.cli", "companion.__main__", "companion"),
)


def _modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module → the project modules it imports (a name imported from a package counts as the
    submodule when one exists by that name, else as the package)."""
    edges: dict[str, set[str]] = defaultdict(set)
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names]
            for target in targets:
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    edges[name].add(target)
    return edges


MODULES = _modules()
EDGES = _imports(MODULES)


def _floor(module: str) -> int | None:
    best: tuple[int, int] | None = None  # (prefix length, floor)
    for index, floor in enumerate(FLOORS):
        for prefix in floor:
            if module == prefix or module.startswith(prefix + "."):
                if best is None or len(prefix) > best[0]:
                    best = (len(prefix), index)
    return None if best is None else best[1]


def _cycles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(node: str) -> None:
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for target in EDGES.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for module in sorted(MODULES):
        if module not in index:
            visit(module)
    return found


def test_the_scan_sees_the_project():
    assert len(MODULES) > 100 and "companion.link.vehicle" in MODULES
    assert "companion.link.transport" in EDGES["companion.link.vehicle"]  # a known arrow is seen


def test_no_import_circle():
    assert _cycles() == []


def test_no_arrow_from_a_lower_floor_to_a_higher_one():
    upward = []
    for module, targets in EDGES.items():
        source = _floor(module)
        if source is None:
            continue
        for target in targets:
            floor = _floor(target)
            if floor is not None and floor > source:
                upward.append(f"{module} -> {target}")
    assert upward == []


@pytest.mark.parametrize("side, forbidden", [("sim", ("companion", "behaviors", "harness")),
                                             ("companion", ("sim", "harness")),
                                             ("behaviors", ("sim", "harness"))])
def test_the_simulator_and_the_companion_stand_apart(side, forbidden):
    crossing = [f"{module} -> {target}" for module, targets in EDGES.items()
                if module.split(".")[0] == side for target in targets if target.split(".")[0] in forbidden]
    assert crossing == []


def test_the_link_is_small_modules_around_a_thin_facade():
    lines = {path.name: len(path.read_text(encoding="utf-8").splitlines())
             for path in (ROOT / "companion" / "link").rglob("*.py")}
    assert lines["vehicle.py"] < 200
    assert max(lines.values()) <= 350, {name: n for name, n in lines.items() if n > 350}


def test_strategies_use_only_the_link_parts_they_are_given():
    """No strategy holds the connection object or calls a private method of another part."""
    offenders = []
    for path in (ROOT / "companion" / "link" / "autopilots").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Attribute) and (node.attr == "master" or (
                    node.attr.startswith("_") and not node.attr.startswith("__")
                    and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")))):
                offenders.append(f"{path.name}:{node.lineno} .{node.attr}")
    assert offenders == []
