"""Pitch PI gains from the identified pitch model, and their speed schedule (thesis App. B; SPEC C3, C5).

Plant (eq. B.14): θ/δs' = d2 / (s² + c22·s + c23), δs' = δs + δs0.
Autopilot pitch loop (Table 5.1's inner loop, as the simulator and ArduSub's angle loop run it):
δs = Kp·(θd − θ) + Ki·∫(θd − θ).

Design rule (the heading rule of ``gains.py`` carried over): with P action the closed loop is
d2·Kp / (s² + c22·s + c23 + d2·Kp). Keep the identified damping term c22 and choose Kp so the
pair has ζ = 0.7071: ωn = c22/√2 and **Kp = (c22²/2 − c23)/d2** (the sign of Kp follows d2: a
negative d2, elevator down pitching nose down, gives a negative Kp, as Table 5.1's −20).
The integral zero sits N = 100 times below ωn, **Ki = Kp·ωn/N**; the plant is type 0 (c23 > 0),
so the integrator only removes the steady elevator offset δs0 and barely moves the pair.

When c22²/2 ≤ c23 the plant's own damping is already below 0.7071 and a P(I) loop can only lower
it: no gain meets the rule and :func:`design_pitch_gains` raises ValueError (the autopilot keeps
its gains). All gains are bounded by :class:`PitchGainBounds` (magnitudes).

Schedule: over speed, c22 grows about linearly with u, d2 with u² and c23 is hydrostatic
(constant); the schedule interpolates each parameter **linearly in u between the identified
speeds** (held constant outside them, no extrapolation), and designs at the interpolated model.
With a single speed it is that model's gains everywhere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .identification import PitchModel

DESIGN_DAMPING = 1.0 / math.sqrt(2.0)


@dataclass(frozen=True)
class PitchGainBounds:
    """Magnitude limits of the designed pitch gains (rad of elevator per rad of pitch error, per rad·s)."""

    kp_min: float = 0.1
    kp_max: float = 50.0
    ki_max: float = 5.0
    integral_ratio: float = 100.0  # N: PI zero at ωn/N


@dataclass
class PitchGains:
    """δs = kp·(θd − θ) + ki·∫(θd − θ) (signs follow d2)."""

    kp: float
    ki: float
    speed: float | None = None
    clamped: tuple[str, ...] = ()


def design_pitch_gains(model: PitchModel, bounds: PitchGainBounds = PitchGainBounds(),
                       speed: float | None = None) -> PitchGains:
    """Kp = (c22²/2 − c23)/d2, Ki = Kp·ωn/N (module docstring); ValueError when the rule has no solution."""
    c22, c23, d2 = float(model.c22), float(model.c23), float(model.d2)
    if not all(math.isfinite(v) for v in (c22, c23, d2)):
        raise ValueError(f"pitch model parameters must be finite: {model}")
    if c22 <= 0.0:
        raise ValueError(f"c22 must be positive (pitch damping), got {c22}")
    if d2 == 0.0:
        raise ValueError("d2 is zero: the elevator has no authority in this model")
    stiffness = c22 * c22 / 2.0 - c23
    if stiffness <= 0.0:
        raise ValueError(f"the plant's own damping is below {DESIGN_DAMPING:.4f} (c22²/2 = {c22 * c22 / 2:.4g}"
                         f" ≤ c23 = {c23:.4g}): a P(I) pitch loop cannot reach it")
    kp = stiffness / d2
    natural_frequency = c22 / math.sqrt(2.0)
    clamped: list[str] = []
    magnitude = abs(kp)
    if magnitude < bounds.kp_min or magnitude > bounds.kp_max:
        clamped.append("kp")
        kp = math.copysign(min(max(magnitude, bounds.kp_min), bounds.kp_max), kp)
    ki = kp * natural_frequency / bounds.integral_ratio
    if abs(ki) > bounds.ki_max:
        clamped.append("ki")
        ki = math.copysign(bounds.ki_max, ki)
    return PitchGains(kp=kp, ki=ki, speed=speed, clamped=tuple(clamped))


@dataclass
class PitchSchedule:
    """Identified pitch models by speed, interpolated linearly in u (module docstring)."""

    speeds: list[float]
    c22: list[float]
    c23: list[float]
    d2: list[float]
    cb: list[float] = field(default_factory=list)

    def model_at(self, speed: float) -> PitchModel:
        def at(values: list[float]) -> float:
            return float(np.interp(speed, self.speeds, values))
        cb = at(self.cb) if self.cb else 0.0
        return PitchModel(c22=at(self.c22), c23=at(self.c23), d2=at(self.d2), cb=cb)

    def gains_at(self, speed: float, bounds: PitchGainBounds = PitchGainBounds()) -> PitchGains:
        return design_pitch_gains(self.model_at(speed), bounds, speed=float(speed))

    def describe(self) -> str:
        return (f"pitch models at {len(self.speeds)} speeds {min(self.speeds):.2f}–{max(self.speeds):.2f} m/s,"
                " interpolated linearly in u")


def pitch_schedule_from_models(speeds: Sequence[float], models: Sequence[PitchModel]) -> PitchSchedule:
    """The schedule over the models with a finite speed, sorted by speed; models at the same speed
    (within 1 mm/s) are averaged. ValueError when none is usable or a model has no solution."""
    rows = sorted(((float(u), m) for u, m in zip(speeds, models) if math.isfinite(u)), key=lambda row: row[0])
    if not rows:
        raise ValueError("no pitch model with a measured speed")
    merged: dict[float, list[PitchModel]] = {}
    for speed, model in rows:
        merged.setdefault(round(speed, 3), []).append(model)
    grid = sorted(merged)
    mean = {name: [float(np.mean([getattr(m, name) for m in merged[u]])) for u in grid]
            for name in ("c22", "c23", "d2", "cb")}
    schedule = PitchSchedule(speeds=grid, **mean)
    for speed in grid:  # every identified point must admit a design
        schedule.gains_at(speed)
    return schedule
