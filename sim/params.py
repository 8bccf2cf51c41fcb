"""The simulator's parameter table (docs/PROTOCOL.md, "Parameters").

Each parameter has a name (≤ 16 characters, MAVLink ``param_id``), a default (some come from the
vehicle preset), a unit, bounds and an integer flag. :meth:`ParamTable.set` validates a write the
way ArduPilot does: an unknown name, a non-finite value or a value outside the bounds is refused
and the value stays as it was, so the echo a client receives does not match what it wrote.
Integer parameters are rounded (ArduPilot casts; PROTOCOL.md "capabilities": C-cast encoding).

No I/O and no MAVLink here: the server turns :class:`SetResult` into PARAM_VALUE + STATUSTEXT.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterator

from sim.skid_mixer import (
    FUNCTION_GROUND_STEERING,
    FUNCTION_THROTTLE,
    FUNCTION_THROTTLE_LEFT,
    FUNCTION_THROTTLE_RIGHT,
)

FULL_SCALE_RAD = 0.5236  # ±30° = PWM 1000…2000 on fin and mass channels (PROTOCOL.md)


@dataclass(frozen=True)
class ParamSpec:
    """One row of the PROTOCOL.md parameter table."""

    name: str
    default: float
    unit: str
    minimum: float
    maximum: float
    description: str
    integer: bool = False


@dataclass(frozen=True)
class SetResult:
    """Outcome of a parameter write: ``accepted`` and the value now held (echoed to the client)."""

    accepted: bool
    value: float | None  # None when the name is unknown (nothing to echo)
    message: str = ""


def _section_value(preset: Any, section: str, name: str, fallback: float) -> float:
    """``preset.<section>.<name>`` (sim.preset.Preset) if present, else ``fallback``."""
    value = getattr(getattr(preset, section, None), name, None)
    return float(fallback if value is None else value)


def default_specs(preset: Any = None) -> list[ParamSpec]:
    """The parameter table of PROTOCOL.md; gains, limits and cruise thrust from ``preset``
    (a :class:`sim.preset.Preset`; ``None`` gives the PROTOCOL.md defaults)."""

    def ap(name: str, fallback: float) -> float:
        return _section_value(preset, "autopilot", name, fallback)

    def act(name: str, fallback: float) -> float:
        return _section_value(preset, "actuators", name, fallback)

    hdg_p, hdg_i = ap("heading_p", 1.0), ap("heading_i", 0.05)
    hdg_imax, hdg_trim = ap("heading_imax", 0.15), ap("heading_trim", 0.0)
    dpt_p, dpt_i = ap("depth_p", -0.15), ap("depth_i", -0.01)
    pit_p, pit_i, pit_max = ap("pitch_p", -20.0), ap("pitch_i", -0.1), ap("pitch_max", 0.35)
    cruise = ap("cruise_thrust", 0.70)
    rud_max, rud_rate = act("rudder_max", 0.35), act("rudder_rate", 0.5)
    elev_max, elev_rate = act("elevator_max", 0.26), act("elevator_rate", 0.5)
    mass_max = act("mass_max", 0.349)
    fs = FULL_SCALE_RAD
    specs = [
        ParamSpec("SYSID_THISMAV", 1, "", 1, 255, "vehicle system id", integer=True),
        ParamSpec("SYSID_MYGCS", 255, "", 1, 255, "system id allowed to override RC", integer=True),
        ParamSpec("HDG_P", hdg_p, "rad/rad", 0.0, 20.0, "heading P gain"),
        ParamSpec("HDG_I", hdg_i, "rad/(rad s)", 0.0, 10.0, "heading integral gain"),
        ParamSpec("HDG_IMAX", hdg_imax, "rad", 0.0, fs, "heading integrator clamp"),
        ParamSpec("HDG_TRIM", hdg_trim, "rad", -fs, fs, "rudder trim, fed forward (delta0)"),
        ParamSpec("DPT_P", dpt_p, "rad/m", -10.0, 10.0, "depth P gain -> desired pitch"),
        ParamSpec("DPT_I", dpt_i, "rad/(m s)", -10.0, 10.0, "depth I gain -> desired pitch"),
        ParamSpec("PIT_P", pit_p, "rad/rad", -200.0, 200.0, "pitch P gain -> elevator"),
        ParamSpec("PIT_I", pit_i, "rad/(rad s)", -200.0, 200.0, "pitch I gain -> elevator"),
        ParamSpec("PIT_MAX", pit_max, "rad", 0.0, 1.2, "desired-pitch limit"),
        ParamSpec("RUD_MAX", rud_max, "rad", 0.0, fs, "rudder limit"),
        ParamSpec("RUD_RATE", rud_rate, "rad/s", 0.01, 20.0, "rudder rate limit"),
        ParamSpec("ELEV_MAX", elev_max, "rad", 0.0, fs, "elevator limit"),
        ParamSpec("ELEV_RATE", elev_rate, "rad/s", 0.01, 20.0, "elevator rate limit"),
        ParamSpec("CRUISE_THR", cruise, "ratio", 0.0, 1.0, "thrust set-point on entering hold"),
        ParamSpec("RC_OVR_TIME", 3.0, "s", -1.0, 120.0, "RC override timeout (-1: never)"),
        ParamSpec("MASS_SERVO", 9, "", 4, 16, "servo output of the rolling mass", integer=True),
        ParamSpec("MASS_MAX", mass_max, "rad", 0.0, fs, "rolling mass angle limit"),
        ParamSpec("SR_ATT_HZ", 20, "Hz", 0.0, 100.0, "ATTITUDE/SERVO_OUTPUT_RAW rate"),
        ParamSpec("SR_POS_HZ", 10, "Hz", 0.0, 100.0, "position/VFR_HUD/pressure rate"),
        ParamSpec("SIM_CUR_VN", 0.0, "m/s", -5.0, 5.0, "water current, north"),
        ParamSpec("SIM_CUR_VE", 0.0, "m/s", -5.0, 5.0, "water current, east"),
        ParamSpec("SIM_ROLL_KICK", 0.0, "deg", -90.0, 90.0, "one-shot roll angle (reads back 0)"),
        ParamSpec("SIM_ROLL_DIST", 0.0, "N m", 0.0, 100.0, "random roll disturbance amplitude"),
    ]
    return specs + _servo_function_specs(preset)


def _servo_function_specs(preset: Any) -> list[ParamSpec]:
    """A boat's actuation, discoverable as on ArduRover: SERVO1/3_FUNCTION 26/70 (ground steering,
    throttle) with a rudder, 73/74 (throttle left/right) with twin thrusters. Read-only (bounds = the
    value); appended after the other parameters so their indices stay; none for an underwater vehicle."""
    if not getattr(preset, "surface", False):
        return []
    if getattr(preset, "twin_thrusters", None) is not None:
        first, third = FUNCTION_THROTTLE_LEFT, FUNCTION_THROTTLE_RIGHT
    else:
        first, third = FUNCTION_GROUND_STEERING, FUNCTION_THROTTLE
    return [
        ParamSpec("SERVO1_FUNCTION", first, "", first, first, "output 1 function (ArduPilot numbers, read-only)",
                  integer=True),
        ParamSpec("SERVO3_FUNCTION", third, "", third, third, "output 3 function (ArduPilot numbers, read-only)",
                  integer=True),
    ]


class ParamTable:
    """Ordered parameter values with validation; indices follow the table order (PARAM protocol)."""

    def __init__(self, specs: list[ParamSpec]) -> None:
        self._specs = {spec.name: spec for spec in specs}
        self._names = [spec.name for spec in specs]
        self._index = {name: i for i, name in enumerate(self._names)}
        self._values = {spec.name: float(spec.default) for spec in specs}

    @classmethod
    def for_preset(cls, preset: Any = None) -> "ParamTable":
        return cls(default_specs(preset))

    # ------------------------------------------------------------------ reading
    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    @property
    def names(self) -> list[str]:
        return list(self._names)

    def spec(self, name: str) -> ParamSpec:
        return self._specs[name]

    def index(self, name: str) -> int:
        return self._index[name]

    def name_at(self, index: int) -> str | None:
        return self._names[index] if 0 <= index < len(self._names) else None

    def is_integer(self, name: str) -> bool:
        return self._specs[name].integer

    # ------------------------------------------------------------------ writing
    def set(self, name: str, value: float) -> SetResult:
        """Validate and store ``value``; refused writes leave the table unchanged."""
        spec = self._specs.get(name)
        if spec is None:
            return SetResult(False, None, f"Unknown parameter {name}")
        current = self._values[name]
        try:
            value = float(value)
        except (TypeError, ValueError):
            return SetResult(False, current, f"{name}: not a number")
        if not math.isfinite(value):
            return SetResult(False, current, f"{name}: value not finite")
        if spec.integer:
            value = float(round(value))
        if not spec.minimum <= value <= spec.maximum:
            return SetResult(
                False, current, f"{name}: {value:g} outside [{spec.minimum:g}, {spec.maximum:g}]"
            )
        self._values[name] = value
        return SetResult(True, value)

    def force(self, name: str, value: float) -> None:
        """Store without validation (the simulator's own bookkeeping, e.g. SIM_ROLL_KICK → 0)."""
        self._values[name] = float(value)
