"""Gains scheduled on speed: what a schedule is, its design record, and the behaviour that keeps
the autopilot's gains matched to speed during a mission (SPEC C5, thesis §3.5, Fig. 3.16).

A :class:`ScheduleKind` is one gain schedule the product can design and run (the heading PI in
``heading_schedule.py``, the pitch PI in ``pitch_schedule.py``): the identification axis it is
designed from, the neutral parameters it writes, the one function that fits its schedule from the
accepted models, and the gains it gives at a speed. The campaign designs every registered kind
(``companion.procedures.registry``), the resident loop schedules them, and the restore point
covers their parameters because the kind declares them (:attr:`ScheduleKind.footprint`).

:class:`GainScheduler`: the speed is low-pass filtered on vehicle time; the gains the schedule
gives at that speed are written only when they differ from the last written ones by more than
the hysteresis *and* the last attempt is at least ``min_interval_s`` old: real autopilots save
every PARAM_SET to flash (SPEC §4), so writes must be rare. The caller executes the proposed write
and reports back with :meth:`GainScheduler.confirm` or :meth:`GainScheduler.reject`, so ``written``
only ever holds gains the autopilot echoed. An abort asks for the original gains back (the
runner's RestorePoint does the same, verified). Trims (names ending in ``_trim``) are written once
by the campaign and never scheduled.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Sequence

from behaviors.base import Behaviour, Footprint, Status
from behaviors.json_form import json_form
from companion.checks import require_non_negative, require_positive, require_range
from companion.interface import Command, NamedValue, SetParameters, StatusText, Telemetry


# --------------------------------------------------------------------------- schedule kinds
@dataclass
class DesignPoint:
    """The gains at one identified speed: from that speed's own model, and from the schedule."""

    thrust: float | None
    speed: float
    own: dict[str, float]
    scheduled: dict[str, float]


@dataclass
class GainDesign:
    """One kind's design: the fitted schedule (exactly the one whose gains are written), its gains at
    each identified speed, and the design rules it was made with (``rules``: the kind's registered,
    storable rule value — ``GainBounds``, ``CascadeRules`` or ``PitchGainBounds`` — and the b2 speed
    law of its fit), so a stored design gives back its own kind (``behaviors.schedules.kind_of``).
    ``rules`` is None only in a design stored before designs carried their rules."""

    kind: str
    schedule: Any  # YawSchedule | PitchSchedule (a registered record type)
    points: list[DesignPoint] = field(default_factory=list)
    rules: Any = None
    speed_law: str | None = None


@dataclass(frozen=True)
class ScheduleKind:
    """One gain schedule (see the module docstring).

    ``fit(speeds, models)`` returns the schedule (ValueError when none can be fitted);
    ``gains(schedule_or_model, speed)`` the neutral parameters at a speed (ValueError when the
    design has no solution there); ``model_gains(model, speed)`` those of one model alone."""

    name: str
    axis: str
    scheduled: tuple[str, ...]  # neutral names rewritten as the speed changes
    fixed: tuple[str, ...]  # neutral names written once with the design (trims)
    fit: Callable[[Sequence[float], Sequence[Any]], Any]
    gains: Callable[[Any, float], dict[str, float]]
    model_gains: Callable[[Any, float], dict[str, float]]
    live_value: str = ""  # NAMED_VALUE_FLOAT name (≤ 10 chars) of the first scheduled gain
    rules: Any = None  # the design rules the kind was built with (a registered record type)
    speed_law: str | None = None  # the b2 speed law its fit keeps when the models cannot tell (eq. S.3)

    @property
    def parameters(self) -> tuple[str, ...]:
        return self.scheduled + self.fixed

    @property
    def footprint(self) -> Footprint:
        return Footprint.of(parameters=self.parameters)

    def design(self, attempts: Sequence[Any]) -> GainDesign:
        """Fit this kind's schedule over the accepted attempts of its axis (ValueError if none)."""
        usable = [a for a in attempts if a.axis == self.axis and a.accepted and math.isfinite(a.speed)]
        if not usable:
            raise ValueError(f"no accepted {self.axis} model with a measured speed")
        schedule = self.fit([a.speed for a in usable], [a.model for a in usable])
        points = [DesignPoint(thrust=a.thrust, speed=a.speed, own=self.model_gains(a.model, a.speed),
                              scheduled=self.gains(schedule, a.speed)) for a in usable]
        return GainDesign(kind=self.name, schedule=schedule, points=points, rules=self.rules,
                          speed_law=self.speed_law)

    def scheduled_gains(self, schedule: Any, speed: float) -> dict[str, float]:
        gains = self.gains(schedule, speed)
        return {name: gains[name] for name in self.scheduled}


# --------------------------------------------------------------------------- the scheduler
@dataclass(frozen=True)
class SchedulingConfig:
    speed_time_constant_s: float = 3.0  # low-pass filter on the water speed
    relative_hysteresis: float = 0.08  # rewrite when a gain moved by more than this fraction
    trim_hysteresis: float = 0.005  # rad
    min_interval_s: float = 10.0  # vehicle time between two writes
    duration_s: float | None = None  # None: run until aborted

    def __post_init__(self) -> None:
        require_positive(self, "speed_time_constant_s", "min_interval_s")
        require_non_negative(self, "relative_hysteresis", "trim_hysteresis")
        require_range(self, "duration_s", 1e-3, 1e9, optional=True)


def gains_differ(new: dict[str, float], old: dict[str, float] | None, config: SchedulingConfig) -> bool:
    """Hysteresis test between two neutral gain sets (relative on gains, absolute on trims)."""
    if old is None:
        return True
    for name in set(new) | set(old):
        a, b = new.get(name, 0.0), old.get(name, 0.0)
        if name.endswith("_trim"):
            if abs(a - b) > config.trim_hysteresis:
                return True
        elif abs(a - b) > config.relative_hysteresis * max(abs(b), 1e-6):
            return True
    return False


@dataclass(frozen=True)
class SchedulingResult:
    """What the scheduler wrote: each confirmed write (``time_s``, the filtered ``speed``, the gains),
    in vehicle-time order, its configuration, and the gains it found (None: not read)."""

    writes: tuple[dict, ...]
    config: SchedulingConfig
    original: dict[str, float] | None

    def __post_init__(self) -> None:
        times = [write["time_s"] for write in self.writes]
        if any(later < earlier for earlier, later in zip(times, times[1:])):
            raise ValueError(f"SchedulingResult.writes must be in vehicle-time order, not at {times}")

    def to_dict(self) -> dict:
        return json_form({"writes": self.writes, "config": asdict(self.config), "original": self.original})


class GainScheduler(Behaviour):
    """Write ``gains_at(speed)`` (neutral names) as the speed changes, rate-limited with hysteresis."""

    def __init__(self, gains_at: Callable[[float], dict[str, float]], config: SchedulingConfig = SchedulingConfig(),
                 original: dict[str, float] | None = None, *, parameters: Sequence[str] = ("heading_p", "heading_i"),
                 live_value: str = "sched_kp", label: str = "gains") -> None:
        super().__init__(f"{label} scheduling")
        self.gains_at = gains_at
        self.config = config
        self.original = original
        self.footprint = Footprint.of(parameters=parameters)
        self.live_value = live_value
        self.label = label
        self.speed = math.nan
        self._last_time = math.nan
        self._last_write_time = -math.inf
        self.written: dict[str, float] | None = None
        self.proposed: dict[str, float] | None = None
        self.writes: list[dict] = []
        self.released: set[str] = set()  # parameters someone else set: no longer scheduled

    def release(self, names) -> None:
        """Stop scheduling ``names`` (neutral): someone else set them, and their value stands."""
        self.released |= set(names)
        if self.written is not None:
            self.written = {k: v for k, v in self.written.items() if k not in self.released}

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

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        self._filter_speed(telemetry)
        if self.config.duration_s is not None and telemetry.time_s - self.started_s >= self.config.duration_s:
            self.finish(Status.SUCCESS)
            return []
        if math.isnan(self.speed) or telemetry.time_s - self._last_write_time < self.config.min_interval_s:
            return []
        gains = {k: v for k, v in self.gains_at(self.speed).items() if k not in self.released}
        if not gains or not gains_differ(gains, self.written, self.config):
            return []
        self.proposed = dict(gains)
        self._last_write_time = telemetry.time_s  # rate-limits retries of a refused write too
        first = next(iter(gains.values()), math.nan)
        text = " ".join(f"{name.split('_')[-1]} {value:.3f}" for name, value in gains.items())
        return [SetParameters(dict(gains)), NamedValue(self.live_value, first),
                StatusText(f"{self.label} for {self.speed:.2f} m/s: {text}"[:50])]

    def confirm(self) -> None:
        """The proposed gains were written and echoed."""
        if self.proposed is not None:
            self.written = self.proposed
            self.writes.append({"time_s": self._last_write_time, "speed": self.speed, **self.proposed})
            self.proposed = None

    def reject(self) -> None:
        """The proposed write failed: the last confirmed gains stand."""
        self.proposed = None

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is Status.ABORTED and self.original:
            return [SetParameters(dict(self.original))]
        return []

    def result(self) -> SchedulingResult:
        return SchedulingResult(tuple(dict(write) for write in self.writes), self.config,
                                None if self.original is None else dict(self.original))
