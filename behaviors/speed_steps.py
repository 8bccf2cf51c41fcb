"""Speed steps to check a set of speed-loop gains (the speed loop's counterpart of the heading steps).

On an autopilot whose thrust level is a speed demand (ArduRover GUIDED: a fraction of WP_SPEED):
write the gains, hold the course at the low speed until settled, demand the high speed, hold, demand
the low speed again, hold. Each step is scored on the measured speed by the heading steps' metrics
(``behaviors.heading_steps.step_metrics``: smoothed, overshoot in % of the step, time to stay
within 5 % of it). A pure step function of telemetry on vehicle time.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Sequence, Union

import numpy as np

from behaviors.base import Behaviour, Footprint, Status
from behaviors.heading_steps import step_metrics
from behaviors.json_form import json_form
from companion.checks import require_finite, require_measured, require_positive
from companion.interface import Command, SetHeading, SetParameters, SetThrust, StatusText, Telemetry
from companion.numerics.angles import wrap_pi
from companion.numerics.step_figures import StepFigures


@dataclass(frozen=True)
class SpeedStepConfig:
    settle_s: float = 20.0  # at the low speed, with the gains written
    hold_s: float = 15.0  # after each step

    def __post_init__(self) -> None:
        require_positive(self, "settle_s", "hold_s")


@dataclass(frozen=True)
class FlownSpeedStep:
    """One flown speed step's ``figures`` (:func:`step_metrics` on the measured speed) from the speed
    ``start`` to ``target`` (m/s). Its JSON: the figures' keys, then ``start``, ``target``."""

    figures: StepFigures
    start: float
    target: float

    def __post_init__(self) -> None:
        if not isinstance(self.figures, StepFigures):
            raise ValueError(f"FlownSpeedStep.figures must be StepFigures, not {self.figures!r}")
        require_finite(self, "start", "target")

    def to_dict(self) -> dict:
        return {**self.figures.to_dict(), "start": self.start, "target": self.target}


@dataclass(frozen=True)
class SpeedStepsResult:
    """The speed step and its return flown with ``gains`` between ``speeds`` (m/s): each step's
    figures (:class:`FlownSpeedStep`), the largest overshoot (NaN: none
    measured), the summed settling time (a step that never settled counts as its hold; NaN: no step),
    the recorded series, and whether it was aborted."""

    label: str
    gains: dict[str, float]
    speeds: tuple[float, float]
    steps: tuple[FlownSpeedStep, ...]
    max_overshoot_pct: float
    settling_time_s: float
    config: SpeedStepConfig
    series: dict[str, list[float]]
    aborted: bool

    def __post_init__(self) -> None:
        require_measured(self, "max_overshoot_pct", "settling_time_s")
        if not (len(self.speeds) == 2 and all(speed > 0.0 for speed in self.speeds)):
            raise ValueError(f"SpeedStepsResult.speeds must be two speeds > 0 (from, to), not {self.speeds!r}")
        if any(not isinstance(step, FlownSpeedStep) for step in self.steps):
            raise ValueError(f"SpeedStepsResult.steps must be FlownSpeedStep, not {self.steps!r}")

    def to_dict(self) -> dict:
        return json_form({"label": self.label, "gains": self.gains, "speeds": self.speeds,
                          "steps": [step.to_dict() for step in self.steps],
                          "max_overshoot_pct": self.max_overshoot_pct, "settling_time_s": self.settling_time_s,
                          "config": asdict(self.config), "series": self.series, "aborted": self.aborted})


@dataclass(frozen=True)
class PredictedSpeedSteps:
    """Speed steps predicted on the surge model instead of flown (eq. S.7; the original gains' where
    the design's flight showed the model predicts them): each step's predicted metrics, the largest
    overshoot and the summed settling time (infinite: a step never settles)."""

    label: str
    steps: tuple[dict, ...]
    max_overshoot_pct: float
    settling_time_s: float

    def __post_init__(self) -> None:
        require_measured(self, "max_overshoot_pct", "settling_time_s")

    def to_dict(self) -> dict:
        return json_form({"label": self.label, "predicted": True, "steps": self.steps,
                          "max_overshoot_pct": self.max_overshoot_pct, "settling_time_s": self.settling_time_s})


#: the speed steps a design is compared with: flown, or predicted on the surge model
SpeedStepFigures = Union[SpeedStepsResult, PredictedSpeedSteps]


class SpeedStepTest(Behaviour):
    """Write ``gains`` (neutral names), settle at ``speeds[0]``, step to ``speeds[1]`` and back;
    ``speed_per_thrust`` (m/s) turns a speed into the thrust level that demands it."""

    def __init__(self, gains: dict[str, float], speeds: tuple[float, float], speed_per_thrust: float,
                 config: SpeedStepConfig = SpeedStepConfig(), label: str = "") -> None:
        super().__init__(f"speed steps {label}".strip())
        if not (speed_per_thrust > 0.0 and all(0.0 < s <= speed_per_thrust for s in speeds)):
            raise ValueError(f"speed steps {speeds} need 0 < speed ≤ {speed_per_thrust:g} m/s (thrust level 1)")
        self.gains = dict(gains)
        self.speeds = speeds
        self.speed_per_thrust = speed_per_thrust
        self.config = config
        self.label = label
        self.footprint = Footprint.of(parameters=tuple(self.gains), setpoints=("mode", "thrust", "heading"))
        self._course = math.nan
        self._phase = "settle"
        self._phase_start = math.nan
        self._segment = 0
        self.series: dict[str, list[float]] = {"time": [], "speed": [], "demand": [], "throttle": []}
        self.steps: list[FlownSpeedStep] = []

    def _thrust(self, speed: float) -> SetThrust:
        return SetThrust(min(1.0, speed / self.speed_per_thrust))

    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        self._course = telemetry.yaw if telemetry.finite("yaw") else 0.0
        self._phase_start = telemetry.time_s
        return [SetParameters(self.gains), self._thrust(self.speeds[0]), SetHeading(wrap_pi(self._course)),
                StatusText(f"speed steps {self.label}: {self.speeds[0]:.2f}-{self.speeds[1]:.2f} m/s"[:50])]

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        now = telemetry.time_s
        demand = self.speeds[1] if self._phase == "up" else self.speeds[0]
        for key, value in (("time", now), ("speed", telemetry.speed_water), ("demand", demand),
                           ("throttle", telemetry.thrust_ratio)):
            self.series[key].append(value)
        elapsed = now - self._phase_start
        if self._phase == "settle" and elapsed >= self.config.settle_s:
            return self._begin("up", now, self.speeds[1])
        if self._phase == "up" and elapsed >= self.config.hold_s:
            self._score(*self.speeds)
            return self._begin("down", now, self.speeds[0])
        if self._phase == "down" and elapsed >= self.config.hold_s:
            self._score(self.speeds[1], self.speeds[0])
            self.finish(Status.SUCCESS)
        return []

    def _begin(self, phase: str, now: float, speed: float) -> list[Command]:
        self._phase, self._phase_start = phase, now
        self._segment = len(self.series["time"])
        return [self._thrust(speed), SetHeading(wrap_pi(self._course))]

    def _score(self, start: float, target: float) -> None:
        first = self._segment
        times = np.asarray(self.series["time"][first:], dtype=float)
        speed = np.asarray(self.series["speed"][first:], dtype=float)
        ok = np.isfinite(speed)
        self.steps.append(FlownSpeedStep(step_metrics(times[ok], speed[ok], start, target), start, target))

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is not Status.ABORTED:
            return []
        return [self._thrust(self.speeds[0])]

    def result(self) -> SpeedStepsResult:
        overshoots = [s.figures.overshoot_pct for s in self.steps if math.isfinite(s.figures.overshoot_pct)]
        return SpeedStepsResult(
            label=self.label, gains=dict(self.gains), speeds=(self.speeds[0], self.speeds[1]),
            steps=tuple(self.steps), max_overshoot_pct=max(overshoots) if overshoots else math.nan,
            settling_time_s=_total([s.figures.settling_time_s for s in self.steps], self.config.hold_s),
            config=self.config, series={k: list(v) for k, v in self.series.items()},
            aborted=self.status is Status.ABORTED)


def _total(times: list[float], hold_s: float) -> float:
    """Summed settling times, a step that never settled counting as its whole hold (NaN: no step)."""
    if not times:
        return math.nan
    return float(sum(t if math.isfinite(t) else hold_s for t in times))
