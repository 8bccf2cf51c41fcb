"""Parameter files as ground stations load them: ArduPilot's ``.parm`` and QGroundControl's ``.params``.

* ``parm`` — one ``NAME VALUE`` per line, ``#`` starts a comment: what MAVProxy's ``param load``
  and Mission Planner's "Load from file" read (and ArduPilot's own ``defaults.parm``).
* ``qgc`` — QGroundControl's format (its "Save to file" writes it, "Load from file" reads it;
  PX4's tools too): ``#`` comment lines, the column header
  ``# Vehicle-Id Component-Id Name Value Type``, then one tab-separated line per parameter with
  the MAV_PARAM_TYPE of its value (9 REAL32 for every gain; integers written as integers).

Values are written as the vehicle will hold them, float32, in the shortest text that reads back to
the same float32 (``0.2``, not ``0.200000003``), so a loaded file matches what was designed bit for
bit. Pure text in, text out; :func:`read_parm` and :func:`read_qgc` read both formats back.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

MAV_PARAM_TYPE_REAL32 = 9
#: MAV_PARAM_TYPE of the integer types (UINT8 … INT32)
INTEGER_TYPES = (1, 2, 3, 4, 5, 6)
FORMATS = ("parm", "qgc")
_NAME = re.compile(r"^[A-Za-z0-9_]{1,16}$")


@dataclass(frozen=True)
class ParamFile:
    """What one file holds: native names → values (in order), the comment lines at its top, the
    MAV_PARAM_TYPE of names that are not REAL32, and (QGC only) the ids it names."""

    values: Mapping[str, float]
    comments: tuple[str, ...] = ()
    types: Mapping[str, int] = field(default_factory=dict)
    system_id: int = 1
    component_id: int = 1

    def __post_init__(self) -> None:
        if not self.values:
            raise ValueError("ParamFile.values: no parameter to write")
        for name, value in self.values.items():
            if not _NAME.match(name):
                raise ValueError(f"ParamFile: {name!r} is not a parameter name (1-16 letters, digits, _)")
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ValueError(f"ParamFile: {name} = {value!r} is not a finite number")
        for name in ("system_id", "component_id"):
            if not 0 <= getattr(self, name) <= 255:
                raise ValueError(f"ParamFile.{name} must be 0-255, not {getattr(self, name)!r}")
        if any("\n" in line for line in self.comments):
            raise ValueError("ParamFile.comments: one line per comment")

    def type_of(self, name: str) -> int:
        return int(self.types.get(name, MAV_PARAM_TYPE_REAL32))


def float32_text(value: float) -> str:
    """The shortest decimal text that reads back as the float32 nearest ``value``."""
    return np.format_float_positional(np.float32(value), unique=True, trim="-")


def value_text(value: float, param_type: int) -> str:
    if param_type in INTEGER_TYPES:
        if float(value) != round(value):
            raise ValueError(f"{value!r} is not a whole number, as an integer parameter needs")
        return str(int(round(value)))
    return float32_text(value)


def write_parm(params: ParamFile) -> str:
    lines = [f"# {c}" if c else "#" for c in params.comments]
    lines += [f"{name} {value_text(value, params.type_of(name))}" for name, value in params.values.items()]
    return "\n".join(lines) + "\n"


def write_qgc(params: ParamFile) -> str:
    lines = [f"# {c}" if c else "#" for c in params.comments] + ["#", "# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"{params.system_id}\t{params.component_id}\t{name}\t{value_text(value, params.type_of(name))}\t"
              f"{params.type_of(name)}" for name, value in params.values.items()]
    return "\n".join(lines) + "\n"


def write(params: ParamFile, kind: str) -> str:
    """``params`` as a ``parm`` or ``qgc`` file's text."""
    if kind == "parm":
        return write_parm(params)
    if kind == "qgc":
        return write_qgc(params)
    raise ValueError(f"parameter file format {kind!r}: use {' or '.join(FORMATS)}")


def read_parm(text: str) -> dict[str, float]:
    """``NAME VALUE`` (or ``NAME,VALUE``) lines, ``#`` comments, as MAVProxy reads them."""
    out: dict[str, float] = {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = re.split(r"[\s,]+", line)
        if len(parts) < 2 or not _NAME.match(parts[0]):
            raise ValueError(f"line {number}: {raw!r} is not NAME VALUE")
        out[parts[0]] = float(parts[1])
    return out


def read_qgc(text: str) -> list[tuple[int, int, str, float, int]]:
    """(vehicle id, component id, name, value, MAV_PARAM_TYPE) of each parameter line."""
    out = []
    for number, raw in enumerate(text.splitlines(), 1):
        if not raw.strip() or raw.lstrip().startswith("#"):
            continue
        parts = raw.split("\t")
        if len(parts) != 5:
            raise ValueError(f"line {number}: {raw!r} does not have 5 tab-separated columns")
        out.append((int(parts[0]), int(parts[1]), parts[2], float(parts[3]), int(parts[4])))
    return out
