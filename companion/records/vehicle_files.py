"""Vehicle data files: the simulator's presets read as data (never imported) and user JSON files."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

from companion.numerics.minspeed import DivePlaneVehicle


def preset_path(name: str) -> Path:
    """Path of ``sim/presets/<name>.json`` found without importing ``sim``."""
    spec = importlib.util.find_spec("sim")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("the simulator package 'sim' is not installed; use --vehicle FILE.json")
    for folder in spec.submodule_search_locations:
        candidate = Path(folder) / "presets" / f"{name}.json"
        if candidate.is_file():
            return candidate
    available = sorted(
        p.stem for folder in spec.submodule_search_locations for p in (Path(folder) / "presets").glob("*.json")
    )
    raise FileNotFoundError(f"no preset {name!r}; available: {', '.join(available) or 'none'}")


def load_vehicle(preset: str | None, vehicle_file: str | None) -> tuple[DivePlaneVehicle, str]:
    """The vehicle and a label saying where it came from."""
    if vehicle_file:
        data: dict[str, Any] = json.loads(Path(vehicle_file).read_text(encoding="utf-8"))
        return DivePlaneVehicle.from_dict(data), vehicle_file
    if preset:
        path = preset_path(preset)
        return DivePlaneVehicle.from_dict(json.loads(path.read_text(encoding="utf-8"))), f"preset:{preset}"
    return DivePlaneVehicle(), "table-5.1"
