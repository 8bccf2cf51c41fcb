"""Fault injection: a vehicle property that changes at a given vehicle time (for health monitoring).

A :class:`Fault` scales one physical property of the simulated vehicle by ``factor`` from vehicle
time ``at_s`` on, for the rest of the run:

* ``b2`` — fin (rudder) effectiveness: both terms of b2(V) = (b2_constant + b2_per_speed_squared·V²)
  ·f(V) are scaled, so the linearised b2 at every speed is ``factor`` × the healthy one and the
  rudder offset δ0 is unchanged (a damaged or fouled fin);
* ``thrust`` — thrust efficiency: the thruster's force Ft(TR) (SPEC §3.5) is scaled (a fouled
  propeller): the vehicle goes slower at the same thrust ratio;
* ``damping`` (alias ``a22``) — yaw damping: a22(V) and the quadratic term N_rr are scaled (a
  changed payload or hull appendage).

Written on the command line as ``KIND=FACTOR@SECONDS`` (``b2=0.7@600``: 30 % loss of fin
effectiveness from vehicle time 600 s; ``@SECONDS`` may be left out for a fault present from the
start), or in a preset file as ``"faults": [{"kind": "b2", "factor": 0.7, "at_s": 600}]``.
The physics applies them (:class:`sim.vehicle.Vehicle`); the telemetry says nothing about them,
so a client can only find a fault by what the vehicle does.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Iterable

#: fault kinds and what they scale (aliases map to the canonical name)
FAULT_KINDS = {"b2": "fin effectiveness b2", "thrust": "thrust efficiency", "damping": "yaw damping a22"}
ALIASES = {"a22": "damping", "fin": "b2"}
#: a factor outside this range is refused: 0 removes the property, > 5 is not a fault but another vehicle
FACTOR_RANGE = (0.0, 5.0)


@dataclass(frozen=True)
class Fault:
    """``kind`` scaled by ``factor`` from vehicle time ``at_s`` (s) on (see the module docstring)."""

    kind: str
    factor: float
    at_s: float = 0.0

    def __post_init__(self) -> None:
        kind = ALIASES.get(self.kind, self.kind)
        if kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}; known: {', '.join(FAULT_KINDS)} "
                             f"(aliases {', '.join(ALIASES)})")
        object.__setattr__(self, "kind", kind)
        low, high = FACTOR_RANGE
        if not (isinstance(self.factor, (int, float)) and math.isfinite(self.factor) and low < self.factor <= high):
            raise ValueError(f"fault factor must be a number in ({low:g}, {high:g}], not {self.factor!r}")
        if not (isinstance(self.at_s, (int, float)) and math.isfinite(self.at_s) and self.at_s >= 0.0):
            raise ValueError(f"fault time must be a vehicle time ≥ 0 s, not {self.at_s!r}")

    def describe(self) -> str:
        return f"{FAULT_KINDS[self.kind]} ×{self.factor:g} from t = {self.at_s:g} s"


def parse_fault(text: str) -> Fault:
    """``KIND=FACTOR[@SECONDS]`` → :class:`Fault` (ValueError with the expected form otherwise)."""
    kind, sep, rest = text.strip().partition("=")
    factor_text, _, at_text = rest.partition("@")
    if not sep or not kind.strip() or not factor_text.strip():
        raise ValueError(f"{text!r}: expected KIND=FACTOR@SECONDS, e.g. b2=0.7@600 "
                         f"(kinds: {', '.join(FAULT_KINDS)})")
    try:
        factor = float(factor_text)
        at_s = float(at_text) if at_text.strip() else 0.0
    except ValueError:
        raise ValueError(f"{text!r}: FACTOR and SECONDS must be numbers, e.g. b2=0.7@600") from None
    return Fault(kind.strip(), factor, at_s)


def faults_from_json(items: Any) -> tuple[Fault, ...]:
    """The ``faults`` list of a preset file (ValueError naming the bad entry)."""
    if items is None:
        return ()
    if not isinstance(items, list):
        raise ValueError("preset field 'faults' must be a list of {kind, factor, at_s} objects")
    out = []
    for index, item in enumerate(items):
        if not isinstance(item, dict) or set(item) - {"kind", "factor", "at_s"} or not {"kind", "factor"} <= set(item):
            raise ValueError(f"preset faults[{index}]: expected {{\"kind\", \"factor\", \"at_s\"}}, not {item!r}")
        try:
            out.append(Fault(str(item["kind"]), item["factor"], item.get("at_s", 0.0)))
        except ValueError as exc:
            raise ValueError(f"preset faults[{index}]: {exc}") from None
    return tuple(out)


def scale_yaw(constants: Any, fault: Fault) -> Any:
    """The yaw constants (:class:`sim.physics.yaw.YawConstants`) with ``fault`` applied (b2 or damping);
    any other kind leaves them as they are."""
    k = fault.factor
    if fault.kind == "b2":
        return replace(constants, b2_constant=constants.b2_constant * k,
                       b2_per_speed_squared=constants.b2_per_speed_squared * k)
    if fault.kind == "damping":
        return replace(constants, a22_constant=constants.a22_constant * k, a22_per_speed=constants.a22_per_speed * k,
                       yaw_damping_quadratic=constants.yaw_damping_quadratic * k)
    return constants


def in_time_order(faults: Iterable[Fault]) -> list[Fault]:
    """The faults sorted by onset (stable: faults at the same time apply in the order given)."""
    return sorted(faults, key=lambda f: f.at_s)
