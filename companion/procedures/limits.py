"""The envelope a procedure must keep, per kind of vehicle (SPEC §4; leaving it aborts and restores).

The checks use only signals that mean what the check needs, and a vehicle is checked on what it
has: an underwater vehicle on depth (a pressure sensor), a surface vessel never on depth — a boat's
"depth" from GPS altitude is noise around wherever home was set (measured: 584 m on ArduRover SITL
with its default home, and a real GPS wanders metres) — but on roll, pitch and how far it went from
where the procedure started. Limits come from the autopilot profile's ``vehicle_kind``
(:meth:`SafetyLimits.for_profile`); the defaults are stated in docs/limitations.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from companion.checks import require_positive, require_range
from companion.interface import Telemetry
from companion.link.profile import AutopilotProfile


@dataclass(frozen=True)
class SafetyLimits:
    """The envelope (module docstring); a limit that is None is not checked. Defaults: a small AUV."""

    max_roll: float = math.radians(35.0)
    max_pitch: float = math.radians(35.0)
    max_depth: float | None = 50.0  # m
    min_depth: float | None = -1.0  # m (a surfaced vehicle may read slightly negative)
    max_distance_m: float | None = None  # from where the procedure started, over ground
    max_nan_samples: int = 40  # consecutive snapshots without attitude before aborting
    require_armed: bool = True  # a disarmed vehicle (or one disarmed during the procedure) aborts it
    mode_grace_s: float = 3.0  # vehicle seconds in a mode the procedure did not ask for before aborting

    def __post_init__(self) -> None:
        require_range(self, "max_roll", 1e-3, math.pi)
        require_range(self, "max_pitch", 1e-3, math.pi / 2)
        require_range(self, "max_depth", -10.0, 11000.0, optional=True)
        require_range(self, "min_depth", -10.0, 11000.0, optional=True)
        if self.min_depth is not None and self.max_depth is not None and self.min_depth > self.max_depth:
            raise ValueError(f"SafetyLimits: min_depth {self.min_depth} above max_depth {self.max_depth}")
        require_range(self, "max_distance_m", 1.0, 1e6, optional=True)
        require_positive(self, "mode_grace_s")
        if not (isinstance(self.max_nan_samples, int) and self.max_nan_samples >= 1):
            raise ValueError(f"SafetyLimits.max_nan_samples must be an integer ≥ 1, not {self.max_nan_samples!r}")

    @classmethod
    def for_profile(cls, profile: AutopilotProfile | None, *, max_distance_m: float | None = None) -> "SafetyLimits":
        """The envelope of the vehicle behind an autopilot profile: a surface vessel is not checked
        on depth; an underwater vehicle keeps the depth band. The distance from where the procedure
        started is checked only when the operator gives one (``identify --max-distance``): there is
        no default that fits, since a whole campaign runs as one procedure and its straight runs
        add up to kilometres (about 2.6 km for the default four speeds at 2 m/s)."""
        kind = profile.vehicle_kind if profile is not None else "underwater"
        if kind == "surface":
            return cls(max_roll=math.radians(30.0), max_pitch=math.radians(30.0), max_depth=None, min_depth=None,
                       max_distance_m=max_distance_m)
        return cls(max_distance_m=max_distance_m)

    def with_distance(self, metres: float | None) -> "SafetyLimits":
        return replace(self, max_distance_m=metres)

    def watch(self) -> "EnvelopeWatch":
        """A fresh check of one procedure's run (it remembers where the procedure started)."""
        return EnvelopeWatch(self)

    def violation(self, telemetry: Telemetry) -> str | None:
        """The attitude and depth limits (those that need no memory of the run)."""
        if math.isfinite(telemetry.roll) and abs(telemetry.roll) > self.max_roll:
            return f"roll {math.degrees(telemetry.roll):.1f} deg beyond {math.degrees(self.max_roll):.0f} deg"
        if math.isfinite(telemetry.pitch) and abs(telemetry.pitch) > self.max_pitch:
            return f"pitch {math.degrees(telemetry.pitch):.1f} deg beyond {math.degrees(self.max_pitch):.0f} deg"
        if math.isfinite(telemetry.depth):
            low = -math.inf if self.min_depth is None else self.min_depth
            high = math.inf if self.max_depth is None else self.max_depth
            if not low <= telemetry.depth <= high:
                return f"depth {telemetry.depth:.2f} m outside [{self.min_depth}, {self.max_depth}] m"
        return None


class EnvelopeWatch:
    """One run's check: :meth:`SafetyLimits.violation` plus the distance from the start."""

    def __init__(self, limits: SafetyLimits) -> None:
        self.limits = limits
        self.start: tuple[float, float] | None = None

    def check(self, telemetry: Telemetry) -> str | None:
        violation = self.limits.violation(telemetry)
        if violation or self.limits.max_distance_m is None or not telemetry.finite("north", "east"):
            return violation
        if self.start is None:
            self.start = (telemetry.north, telemetry.east)
            return None
        distance = math.hypot(telemetry.north - self.start[0], telemetry.east - self.start[1])
        if distance > self.limits.max_distance_m:
            return f"{distance:.0f} m from where the procedure started (at most {self.limits.max_distance_m:.0f} m)"
        return None
