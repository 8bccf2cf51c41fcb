"""Keep the heading gains matched to speed during a mission (SPEC C5, thesis §3.5, Fig. 3.16).

The speed is low-pass filtered on vehicle time; the gains the schedule gives at that speed are
written only when they differ from the last written ones by more than the hysteresis *and* the
last attempt is at least ``min_interval_s`` old: real autopilots save every PARAM_SET to flash
(SPEC §4), so writes must be rare. The caller executes the proposed write and reports back with
:meth:`GainScheduler.confirm` or :meth:`GainScheduler.reject`, so ``written`` only ever holds gains
the autopilot echoed. ``abort`` asks for the original gains back (the runner's RestorePoint does the
same, verified). Only Kp and Ki are scheduled: the trim (δ0, constant over speed) is written once
by the campaign, with the hold re-engaged so the integrator does not count it twice.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Callable, Sequence

from companion.interface import Command, NamedValue, SetParameters, StatusText, Telemetry


@dataclass(frozen=True)
class SchedulingConfig:
    speed_time_constant_s: float = 3.0  # low-pass filter on the water speed
    relative_hysteresis: float = 0.08  # rewrite when kp or ki moved by more than this fraction
    trim_hysteresis: float = 0.005  # rad
    min_interval_s: float = 10.0  # vehicle time between two writes
    duration_s: float | None = None  # None: run until aborted


def gains_differ(new: dict[str, float], old: dict[str, float] | None, config: SchedulingConfig) -> bool:
    """Hysteresis test between two neutral gain sets."""
    if old is None:
        return True
    for name in ("heading_p", "heading_i"):
        a, b = new.get(name, 0.0), old.get(name, 0.0)
        if abs(a - b) > config.relative_hysteresis * max(abs(b), 1e-6):
            return True
    return abs(new.get("rudder_trim", 0.0) - old.get("rudder_trim", 0.0)) > config.trim_hysteresis


class GainScheduler:
    """Write ``gains_at(speed)`` (neutral names) as the speed changes, rate-limited with hysteresis."""

    def __init__(self, gains_at: Callable[[float], dict[str, float]], config: SchedulingConfig = SchedulingConfig(),
                 original: dict[str, float] | None = None) -> None:
        self.gains_at = gains_at
        self.config = config
        self.original = original
        self.speed = math.nan
        self._last_time = math.nan
        self._start = math.nan
        self._last_write_time = -math.inf
        self.written: dict[str, float] | None = None
        self.proposed: dict[str, float] | None = None
        self.writes: list[dict] = []
        self._done = False

    @property
    def done(self) -> bool:
        return self._done

    def _filter_speed(self, telemetry: Telemetry) -> None:
        if not telemetry.finite("speed_water"):
            return
        if math.isnan(self.speed):
            self.speed = telemetry.speed_water
        else:
            dt = max(0.0, telemetry.time_s - self._last_time)
            alpha = 1.0 - math.exp(-dt / self.config.speed_time_constant_s)
            self.speed += alpha * (telemetry.speed_water - self.speed)
        self._last_time = telemetry.time_s

    def step(self, telemetry: Telemetry) -> Sequence[Command]:
        if self._done:
            return []
        if math.isnan(self._start):
            self._start = telemetry.time_s
        self._filter_speed(telemetry)
        if self.config.duration_s is not None and telemetry.time_s - self._start >= self.config.duration_s:
            self._done = True
            return []
        if math.isnan(self.speed) or telemetry.time_s - self._last_write_time < self.config.min_interval_s:
            return []
        gains = self.gains_at(self.speed)
        if not gains_differ(gains, self.written, self.config):
            return []
        self.proposed = dict(gains)
        self._last_write_time = telemetry.time_s  # rate-limits retries of a refused write too
        return [SetParameters(dict(gains)), NamedValue("sched_kp", gains.get("heading_p", math.nan)),
                StatusText(f"gains for {self.speed:.2f} m/s: kp {gains.get('heading_p', math.nan):.3f} "
                           f"ki {gains.get('heading_i', math.nan):.3f}")]

    def confirm(self) -> None:
        """The proposed gains were written and echoed."""
        if self.proposed is not None:
            self.written = self.proposed
            self.writes.append({"time_s": self._last_write_time, "speed": self.speed, **self.proposed})
            self.proposed = None

    def reject(self) -> None:
        """The proposed write failed: the last confirmed gains stand."""
        self.proposed = None

    def abort(self, reason: str) -> Sequence[Command]:
        self._done = True
        return [SetParameters(dict(self.original))] if self.original else []

    def result(self) -> dict:
        return {"writes": self.writes, "config": asdict(self.config), "original": self.original}
