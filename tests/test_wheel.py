"""The wheel: ``pip wheel . --no-deps`` builds with the package data inside (the simulator's presets
and parameter files, the status page), and installed from the wheel alone into a fresh environment
``companion --version`` answers and a command that reads package data runs.

One test, about 8 s on 2 cores (the build is most of it): the sources are copied to a temporary
folder (no ``build/`` left in the checkout), built without build isolation (offline: setuptools and
wheel from the test environment), and installed with ``--no-deps`` into a venv that sees the test
environment's packages (its site-packages as a path, so the editable install of this checkout is not
seen) and is run from a neutral folder.
"""
from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "companion", "behaviors", "sim", "harness")
PACKAGE_DATA = ("sim/presets/starfish.json", "sim/presets/boat.json", "sim/ardupilot/ardurover-boat.parm",
                "sim/px4/px4-uuv.params", "companion/service/static/status.html",
                "companion/service/static/status.js", "companion/service/static/status.css")


@pytest.mark.skipif(importlib.util.find_spec("wheel") is None or importlib.util.find_spec("setuptools") is None,
                    reason="setuptools and wheel are needed to build without build isolation (pip install '.[test]')")
def test_the_wheel_carries_its_data_and_runs_installed_alone(tmp_path):
    source = tmp_path / "src"
    for name in SOURCES:
        origin = ROOT / name
        if origin.is_dir():
            shutil.copytree(origin, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            source.mkdir(exist_ok=True)
            shutil.copy2(origin, source / name)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation",
                            "--no-index", "-q", "-w", str(tmp_path / "dist")], capture_output=True, text=True,
                           timeout=300)
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("marine_companion-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
    assert set(PACKAGE_DATA) <= names, sorted(set(PACKAGE_DATA) - names)
    assert not any(name.startswith(("tests/", "deploy/", "docs/")) for name in names)

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    # the dependencies (numpy, pymavlink, ...) from the test environment, as a plain path: its .pth
    # files, among them this checkout's editable install, are not read
    paths = dict.fromkeys([sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]])
    (site / "test-environment.pth").write_text("\n".join(paths) + "\n")
    installed = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps",
                                "--no-index", "-q", str(wheel)], capture_output=True, text=True, timeout=300)
    assert installed.returncode == 0, installed.stderr[-3000:]

    neutral = tmp_path / "elsewhere"
    neutral.mkdir()
    companion = venv / "bin" / "companion"
    env = {"PATH": f"{venv / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path)}
    version = subprocess.run([str(companion), "--version"], cwd=neutral, capture_output=True, text=True, env=env,
                             timeout=120)
    expected = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert version.returncode == 0 and version.stdout.strip() == f"companion {expected}", version.stderr
    where = subprocess.run([str(python), "-c", "import companion, sim; print(companion.__file__, sim.__file__)"],
                           cwd=neutral, capture_output=True, text=True, env=env, timeout=120)
    assert all(path.startswith(str(site)) for path in where.stdout.split()), where.stdout + where.stderr
    minspeed = subprocess.run([str(companion), "minspeed", "--preset", "starfish", "--json"], cwd=neutral,
                              capture_output=True, text=True, env=env, timeout=120)
    assert minspeed.returncode == 0, minspeed.stderr
    assert 0.674 <= json.loads(minspeed.stdout)["v_min"] <= 0.678  # SPEC §3.4, from the preset in the wheel
