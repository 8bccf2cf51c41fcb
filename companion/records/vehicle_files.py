"""Vehicle data files: the simulator's presets read as data (never imported) and user JSON files.

A dive-plane vehicle file is checked against a schema before it is used (``{}``, wrong
types or ``rho: -1000`` once gave defaults or nonsense silently). The file is a JSON object, either

* a simulator preset: a ``dive_plane`` section (or ``minspeed``…) holding the parameters; the
  preset's other sections belong to the simulator and are not read here; or
* flat: the parameters at top level, plus optionally ``name`` and ``description``.

Every :class:`~companion.numerics.minspeed.DivePlaneVehicle` parameter is required (by its field
name, the preset's name or the thesis symbol), except ``delta_max`` which may also come from the
preset's ``actuators.elevator_max`` or ``--delta-max``. Unknown keys, a key given twice, a value that
is not a finite number and a value outside its physical range (:data:`RANGES`) are refused with a
:class:`VehicleFileError` naming the file and the key.
"""
from __future__ import annotations

import importlib.util
import json
import math
from dataclasses import fields
from pathlib import Path
from typing import Any, Mapping

from companion.errors import UserError
from companion.numerics.minspeed import DIVE_PLANE_SECTIONS, DivePlaneVehicle, dive_plane_field

#: physical range of each parameter: (low, high, low inclusive, high inclusive, what it is)
RANGES: dict[str, tuple[float, float, bool, bool, str]] = {
    "rho": (500.0, 2000.0, True, True, "water density in kg/m³ (≈ 1000–1030)"),
    "mass": (0.0, math.inf, False, False, "dry mass in kg"),
    "mass_x": (0.0, math.inf, False, False, "surge mass incl. added mass in kg"),
    "mass_z": (0.0, math.inf, False, False, "heave mass incl. added mass in kg"),
    "weight": (0.0, math.inf, False, False, "weight in N"),
    "buoyancy": (0.0, math.inf, False, False, "buoyancy in N"),
    "inertia_y": (0.0, math.inf, False, False, "pitch inertia in kg·m²"),
    "z_cg": (-math.inf, math.inf, False, False, "CG below the CB in m"),
    "x_cg": (-math.inf, math.inf, False, False, "CG ahead of the CB in m"),
    "area_body": (0.0, math.inf, False, False, "body reference area in m²"),
    "area_fin": (0.0, math.inf, False, False, "fin area in m²"),
    "length": (0.0, math.inf, False, False, "length in m"),
    "x_fin": (0.0, math.inf, False, False, "fin arm behind the CB in m"),
    "c_d0": (-math.inf, 0.0, False, False, "drag coefficient (negative in the thesis's convention)"),
    "c_l_alpha": (-math.inf, 0.0, False, False, "lift slope (negative in the thesis's convention)"),
    "c_l_delta": (-math.inf, 0.0, False, False, "elevator lift slope (negative in the thesis's convention)"),
    "c_m_alpha": (-math.inf, 0.0, False, False, "moment slope (negative in the thesis's convention)"),
    "c_m_q": (-math.inf, 0.0, False, True, "pitch-rate moment (zero or negative: damping)"),
    "delta_max": (0.0, math.pi / 2, False, True, "elevator limit in rad"),
}
#: keys of a preset's dive-plane section the simulator uses and the analysis does not need
SIMULATOR_ONLY = frozenset({"pitch_damping_linear"})
#: descriptive keys a flat file may carry beside the parameters
DESCRIPTIVE = frozenset({"name", "description"})


class VehicleFileError(UserError, ValueError):
    """A vehicle file that cannot be used; the message names the file and the problem."""


def preset_path(name: str) -> Path:
    """Path of ``sim/presets/<name>.json`` found without importing ``sim``; a ``name`` ending in
    ``.json`` is a preset file of its own (a vehicle variant, :mod:`companion.records.variants`)."""
    if name.endswith(".json"):
        if not Path(name).is_file():
            raise FileNotFoundError(f"no preset file {name}")
        return Path(name)
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


def load_vehicle(preset: str | None, vehicle_file: str | None,
                 delta_max: float | None = None) -> tuple[DivePlaneVehicle, str]:
    """The vehicle and a label saying where it came from; ``delta_max`` (rad) overrides the file's.
    A file or preset that fails the schema raises :class:`VehicleFileError`."""
    if vehicle_file:
        return dive_plane_vehicle(read_json_object(vehicle_file), vehicle_file, delta_max), vehicle_file
    if preset:
        path = preset_path(preset)
        return dive_plane_vehicle(read_json_object(str(path)), f"preset {preset}", delta_max), f"preset:{preset}"
    vehicle = DivePlaneVehicle()
    return (vehicle if delta_max is None else vehicle.with_delta_max(delta_max)), "table-5.1"


def read_json_object(path: str) -> dict[str, Any]:
    """The JSON object in ``path`` (UTF-8, a byte-order mark allowed); NaN/Infinity literals refused."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except IsADirectoryError:
        raise VehicleFileError(f"{path}: is a directory, not a vehicle file") from None
    except OSError as exc:
        raise VehicleFileError(f"{path}: cannot read the vehicle file ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise VehicleFileError(f"{path}: not a UTF-8 text file ({exc.reason})") from None

    def refuse(constant: str) -> float:
        raise VehicleFileError(f"{path}: {constant} is not a number a vehicle file may hold")

    try:
        data = json.loads(text, parse_constant=refuse)
    except json.JSONDecodeError as exc:
        raise VehicleFileError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None
    if not isinstance(data, dict):
        raise VehicleFileError(f"{path}: a vehicle file holds a JSON object of parameters, not {_json_type(data)}")
    return data


def dive_plane_vehicle(data: Mapping[str, Any], where: str, delta_max: float | None = None) -> DivePlaneVehicle:
    """The :class:`DivePlaneVehicle` a checked file describes (see the module docstring)."""
    section, preset_form = _dive_plane_section(data, where)
    values = _parameters(section, where, allowed_extra=SIMULATOR_ONLY if preset_form else DESCRIPTIVE)
    if "delta_max" not in values:
        limit = _actuator_limit(data, where)
        if limit is not None:
            values["delta_max"] = limit
    if delta_max is not None:
        values["delta_max"] = delta_max
    missing = [f.name for f in fields(DivePlaneVehicle) if f.name not in values]
    if missing:
        hint = " (or actuators.elevator_max, or --delta-max)" if missing == ["delta_max"] else ""
        raise VehicleFileError(f"{where}: missing parameter(s) {', '.join(missing)}{hint}")
    for name, value in values.items():
        _check_range(name, value, where)
    return DivePlaneVehicle(**values)


def _dive_plane_section(data: Mapping[str, Any], where: str) -> tuple[Mapping[str, Any], bool]:
    """(the parameters' mapping, whether the file is a preset with a dive-plane section)."""
    for key, value in data.items():
        if str(key).lower() in DIVE_PLANE_SECTIONS:
            if not isinstance(value, dict):
                raise VehicleFileError(f"{where}: section {key!r} must be a JSON object, not {_json_type(value)}")
            return value, True
    return data, False


def _parameters(section: Mapping[str, Any], where: str, allowed_extra: frozenset[str]) -> dict[str, float]:
    """Field → float for every key of ``section``; unknown keys, repeats and non-numbers refused."""
    values: dict[str, float] = {}
    given_as: dict[str, str] = {}
    unknown = []
    for key, value in section.items():
        name = dive_plane_field(key)
        if name is None:
            if str(key).lower() not in allowed_extra:
                unknown.append(str(key))
            continue
        if name in values:
            raise VehicleFileError(f"{where}: {name} is given twice (as {given_as[name]!r} and {key!r})")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise VehicleFileError(f"{where}: {key!r} must be a number, not {_json_type(value)}")
        values[name], given_as[name] = float(value), str(key)
    if unknown:
        raise VehicleFileError(f"{where}: unknown parameter(s) {', '.join(map(repr, unknown))} (known: the fields of "
                               "DivePlaneVehicle, the preset names or the thesis symbols)")
    return values


def _actuator_limit(data: Mapping[str, Any], where: str) -> float | None:
    """``actuators.elevator_max`` of a preset, when there."""
    actuators = {str(k).lower(): v for k, v in data.items()}.get("actuators")
    if not isinstance(actuators, dict) or "elevator_max" not in actuators:
        return None
    value = actuators["elevator_max"]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise VehicleFileError(f"{where}: 'actuators.elevator_max' must be a number, not {_json_type(value)}")
    return float(value)


def _check_range(name: str, value: float, where: str) -> None:
    low, high, low_in, high_in, what = RANGES[name]
    above = value >= low if low_in else value > low
    below = value <= high if high_in else value < high
    if not (math.isfinite(value) and above and below):
        interval = f"{'[' if low_in else '('}{low:g}, {high:g}{']' if high_in else ')'}"
        raise VehicleFileError(f"{where}: {name} = {value:g} is outside {interval} ({what})")


def _json_type(value: Any) -> str:
    """How JSON calls the type of ``value`` (for messages)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "a list"
    return "an object"
