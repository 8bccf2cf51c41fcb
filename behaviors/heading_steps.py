"""Heading steps to check a set of heading gains (thesis Fig. 3.16; the campaign flies ±20° at each thrust).

At one thrust: write the gains, settle on course, command +step, hold, command the original course
(−step), hold. Each step is scored by its overshoot (percent of the step) and its 90 % rise time.
A pure step function of telemetry on vehicle time.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np

from behaviors.base import Behaviour, Footprint, Status
from behaviors.json_form import json_form
from companion.checks import require_count, require_measured, require_positive, require_range
from companion.interface import Command, SetHeading, SetMode, SetParameters, SetThrust, StatusText, Telemetry
from companion.numerics.angles import wrap_pi
from companion.numerics.step_figures import FlownStepFigures
from companion.numerics.step_response import OSCILLATION_BAND, SETTLE_BAND, smooth_heading, step_metrics  # noqa: F401


def reengage_hold(thrust: float, heading: float) -> list[Command]:
    """Re-enter the holding mode after writing a new rudder trim, then restore the set-points.

    The autopilot's heading integrator has learned the old rudder offset; a newly written trim
    (the identified δ0, fed forward) would otherwise count it twice, biasing the heading by
    ~offset/Kp (≈1° here) for the minutes a small integral gain takes to unwind. Autopilots reset
    their integrators on mode entry (ArduPilot does), and re-selecting the current mode is a no-op,
    hence hold → guided → hold. Mode entry also resets the set-points, so they are sent again."""
    return [SetMode("guided"), SetMode("hold"), SetThrust(thrust), SetHeading(wrap_pi(heading))]


@dataclass(frozen=True)
class StepTestConfig:
    step: float = math.radians(20.0)
    settle_s: float = 20.0
    hold_s: float = 25.0

    def __post_init__(self) -> None:
        require_range(self, "step", math.radians(1.0), math.radians(180.0))
        require_positive(self, "settle_s", "hold_s")


@dataclass(frozen=True)
class HeadingStepsResult:
    """The step and its return flown with ``gains`` at ``thrust``: each step's figures
    (``FlownStepFigures``: :func:`step_metrics` with ``step_deg`` and ``speed``), the largest overshoot
    (NaN: none measured), the summed step error and the most reversals, the recorded series, and
    whether it was aborted."""

    label: str
    thrust: float
    gains: dict[str, float]
    steps: tuple[FlownStepFigures, ...]
    max_overshoot_pct: float
    iae_s: float
    oscillations: int
    config: StepTestConfig
    series: dict[str, list[float]]
    aborted: bool

    def __post_init__(self) -> None:
        require_measured(self, "max_overshoot_pct", "iae_s")
        require_count(self, "oscillations")
        if any(not isinstance(step, FlownStepFigures) for step in self.steps):
            raise ValueError(f"HeadingStepsResult.steps must be FlownStepFigures, not {self.steps!r}")

    def to_dict(self) -> dict:
        return json_form({"label": self.label, "thrust": self.thrust, "gains": self.gains,
                          "steps": [step.to_dict() for step in self.steps],
                          "max_overshoot_pct": self.max_overshoot_pct, "iae_s": self.iae_s,
                          "oscillations": self.oscillations, "config": asdict(self.config), "series": self.series,
                          "aborted": self.aborted})


class HeadingStepTest(Behaviour):
    """Write ``gains`` (neutral names), settle at ``thrust``, then step +step and back."""

    def __init__(self, thrust: float, gains: dict[str, float] | None, config: StepTestConfig = StepTestConfig(),
                 label: str = "") -> None:
        super().__init__(f"heading steps {label}".strip())
        self.footprint = Footprint.of(parameters=tuple(gains or {}), setpoints=("mode", "thrust", "heading"))
        self.thrust = thrust
        self.gains = dict(gains or {})
        self.config = config
        self.label = label
        self._start: float | None = None
        self._course = math.nan
        self._phase = "settle"
        self._phase_start = math.nan
        self._unwrap_ref = math.nan
        self._unwrap_offset = 0.0
        self.series: dict[str, list[float]] = {"time": [], "heading": [], "target": [], "rudder": [], "speed": []}
        self.steps: list[FlownStepFigures] = []

    @property
    def aborted(self) -> bool:
        return self.status is Status.ABORTED

    def _unwrapped(self, yaw: float) -> float:
        if not math.isnan(self._unwrap_ref):
            jump = yaw - self._unwrap_ref
            if jump > math.pi:
                self._unwrap_offset -= 2 * math.pi
            elif jump < -math.pi:
                self._unwrap_offset += 2 * math.pi
        self._unwrap_ref = yaw
        return yaw + self._unwrap_offset

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        if not telemetry.finite("yaw"):
            return []
        now = telemetry.time_s
        heading = self._unwrapped(telemetry.yaw)
        commands: list[Command] = []
        if self._start is None:
            self._start, self._phase_start, self._course = now, now, heading
            if self.gains:
                commands.append(SetParameters(self.gains))
                if "rudder_trim" in self.gains:
                    commands += reengage_hold(self.thrust, self._course)
            commands += [SetThrust(self.thrust), SetHeading(wrap_pi(self._course)),
                         StatusText(f"heading steps {self.label} at thrust {self.thrust:.2f}")]
        target = {"settle": self._course, "up": self._course + self.config.step, "down": self._course}[self._phase]
        self.series["time"].append(now)
        self.series["heading"].append(heading)
        self.series["target"].append(target)
        self.series["rudder"].append(telemetry.rudder)
        self.series["speed"].append(telemetry.speed_water)
        elapsed = now - self._phase_start
        if self._phase == "settle" and elapsed >= self.config.settle_s:
            commands += self._begin("up", now, self._course + self.config.step)
        elif self._phase == "up" and elapsed >= self.config.hold_s:
            self._score(self._course, self._course + self.config.step)
            commands += self._begin("down", now, self._course)
        elif self._phase == "down" and elapsed >= self.config.hold_s:
            self._score(self._course + self.config.step, self._course)
            self.finish(Status.SUCCESS)
        return commands

    def _begin(self, phase: str, now: float, target: float) -> list[Command]:
        self._phase, self._phase_start = phase, now
        self._segment_start = len(self.series["time"])
        return [SetHeading(wrap_pi(target))]

    def _score(self, start: float, target: float) -> None:
        first = self._segment_start
        figures = step_metrics(self.series["time"][first:], self.series["heading"][first:], start, target)
        speeds = [s for s in self.series["speed"][first:] if math.isfinite(s)]
        self.steps.append(FlownStepFigures(figures, step_deg=math.degrees(target - start),
                                           speed=float(np.mean(speeds)) if speeds else math.nan))

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is not Status.ABORTED:
            return []
        return [SetHeading(wrap_pi(self._course))] if math.isfinite(self._course) else []

    def result(self) -> HeadingStepsResult:
        figures = [s.figures for s in self.steps]
        overshoots = [f.overshoot_pct for f in figures if math.isfinite(f.overshoot_pct)]
        return HeadingStepsResult(
            label=self.label, thrust=self.thrust, gains=dict(self.gains), steps=tuple(self.steps),
            max_overshoot_pct=max(overshoots) if overshoots else math.nan,
            iae_s=float(sum(f.iae_s for f in figures)) if figures else math.nan,
            oscillations=int(max((f.oscillations for f in figures), default=0)), config=self.config,
            series={k: list(v) for k, v in self.series.items()}, aborted=self.aborted)
