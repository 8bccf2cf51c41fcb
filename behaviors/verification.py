"""One heading step that decides whether designed gains may stay on the vehicle (eq. A.3; SPEC C5: "every
design is checked by heading steps through the autopilot before it is kept").

The gains go on the vehicle as a trial, the thrust is set, and the vehicle settles on its course
only until it is steady (the steadiness rule: speed, yaw rate and heading; no fixed wait). A step
chained right after a record settles the same way: after a doublet the autopilot's heading hold is
re-engaged and its integrator still converging (on ArduRover at 2.5 m/s a step started 3 s after the
validation record, once the speed alone was steady, overshot 13.5 % where 3.4 % was predicted), and
re-entering the holding mode to engage a new trim runs the thrust at the autopilot's cruise value
until the set-point follows. Then one step of
``step`` rad (its sign alternating, so a campaign stays near its course) and the record **ends
when it has decided**: once the heading has been within the settle band (5 % of the step) for
``band_hold_s`` after its peak, or after ``max_s`` without settling. A step that cannot decide is
repeated once — the water speed at its end differs from its start by more than ``max_speed_change``
(a disturbance, a thrust change not settled; the turn's own dip is not one: once the heading has
decided, the record goes on until the speed is back, up to ``max_s``), or the rudder sat at its limit
for more than ``max_saturated_s`` longer than the step's prediction on its model says it does (the
predicted steps include the rudder's limit, eq. A.3; saturation they do not predict means the model
does not stand for the step) — and a second such step ends it undecided. The figures of
merit are :func:`companion.numerics.step_response.step_metrics`'s, recorded with how the step ended
as a ``companion.numerics.step_figures.FlownStepFigures``.

Chaining: the course the step ends on is the next check's course; nothing returns to the start.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np

from behaviors.base import Behaviour, Footprint, Status
from behaviors.heading_steps import reengage_hold
from behaviors.json_form import json_form
from behaviors.steadiness import SteadinessDetector, SteadinessRule
from companion.checks import require_count, require_measured, require_positive, require_range
from companion.interface import Command, SetHeading, SetParameters, SetThrust, StatusText, Telemetry
from companion.numerics.angles import wrap_pi
from companion.numerics.step_figures import FlownStepFigures
from companion.numerics.step_response import SETTLE_BAND, smooth_heading, step_metrics


@dataclass(frozen=True)
class VerificationConfig:
    """How one verification step is flown and when it has decided (module docstring)."""

    step: float = math.radians(20.0)  # rad; the campaign may shrink it so the rudder stays linear
    settle_max_s: float = 20.0  # vehicle seconds to wait for a steady vehicle before the step
    band_hold_s: float = 1.5  # within the settle band this long after the peak: decided
    max_s: float = 25.0  # a step not settled by then has decided (against the gains)
    max_speed_change: float = 0.10  # relative change of the water speed from the step's start to its end: disturbed
    max_saturated_s: float = 2.0  # rudder at its limit longer than this: the step cannot decide
    repeats: int = 1  # an undecided step is flown again this many times
    steadiness: SteadinessRule = field(default_factory=SteadinessRule)

    def __post_init__(self) -> None:
        require_range(self, "step", math.radians(2.0), math.radians(90.0))
        require_positive(self, "settle_max_s", "band_hold_s", "max_s", "max_speed_change", "max_saturated_s")
        if not (isinstance(self.repeats, int) and 0 <= self.repeats <= 3):
            raise ValueError(f"VerificationConfig.repeats must be an integer in 0..3, not {self.repeats!r}")


@dataclass(frozen=True)
class VerificationResult:
    """One verification step as flown (module docstring): whether it ``decided`` (False: disturbed or
    saturated twice, or aborted) and why not, how many flights it took and why each undecided one was,
    the flown step's overshoot, step error and reversals (NaN, NaN, 0 before a step was scored), its
    figures (a ``FlownStepFigures``: :func:`step_metrics` with ``step_deg``, ``speed``, ``ended``,
    ``duration_s``; none before), the recorded series, the vehicle seconds per stage, and whether it
    was aborted."""

    label: str
    thrust: float
    gains: dict[str, float]
    decided: bool
    why_undecided: str | None
    flights: int
    undecided: tuple[str, ...]
    max_overshoot_pct: float
    iae_s: float
    oscillations: int
    steps: tuple[FlownStepFigures, ...]
    config: VerificationConfig
    series: dict[str, list[float]]
    stage_times: dict[str, float]
    aborted: bool

    def __post_init__(self) -> None:
        require_count(self, "flights", "oscillations")
        require_measured(self, "max_overshoot_pct", "iae_s")
        if any(not seconds >= 0.0 for seconds in self.stage_times.values()):
            raise ValueError(f"VerificationResult.stage_times must be durations ≥ 0, not {self.stage_times!r}")
        if any(not isinstance(step, FlownStepFigures) for step in self.steps):
            raise ValueError(f"VerificationResult.steps must be FlownStepFigures, not {self.steps!r}")
        if self.decided and (self.why_undecided is not None or self.aborted):
            raise ValueError("VerificationResult: a step that decided is neither undecided "
                             f"({self.why_undecided!r}) nor aborted")

    def to_dict(self) -> dict:
        return json_form({"label": self.label, "thrust": self.thrust, "gains": self.gains, "decided": self.decided,
                          "why_undecided": self.why_undecided, "flights": self.flights,
                          "undecided": self.undecided, "max_overshoot_pct": self.max_overshoot_pct,
                          "iae_s": self.iae_s, "oscillations": self.oscillations,
                          "steps": [step.to_dict() for step in self.steps],
                          "config": asdict(self.config), "series": self.series, "stage_times": self.stage_times,
                          "aborted": self.aborted})


class VerificationStep(Behaviour):
    """Trial ``gains`` at ``thrust``, one decisive heading step (module docstring); ``result()`` is
    its :class:`VerificationResult`."""

    def __init__(self, thrust: float, gains: dict[str, float], config: VerificationConfig = VerificationConfig(),
                 *, sign: float = 1.0, rudder_max: float = math.inf, label: str = "scheduled",
                 predicted_saturated_s: float = 0.0) -> None:
        super().__init__(f"verify {label} at {thrust:.2f}")
        if not (math.isfinite(predicted_saturated_s) and predicted_saturated_s >= 0.0):
            raise ValueError(f"predicted_saturated_s is a time ≥ 0, not {predicted_saturated_s!r}")
        self.footprint = Footprint.of(parameters=tuple(gains), setpoints=("mode", "thrust", "heading"))
        self.thrust, self.gains, self.config, self.label = thrust, dict(gains), config, label
        self.sign = 1.0 if sign >= 0 else -1.0
        self.rudder_max = rudder_max
        # the time its prediction sits at the rudder's limit: a step the model predicts saturated (a
        # slow boat's large step, its turn rate at the rudder's limit) is compared with that
        # prediction; only saturation beyond it by ``max_saturated_s`` makes the step undecided
        self.predicted_saturated_s = predicted_saturated_s
        self._phase = "settle"
        self._phase_start = math.nan
        self._course = math.nan
        self._target = math.nan
        self._unwrap = (math.nan, 0.0)  # (last yaw, offset)
        self._steady: SteadinessDetector | None = None
        self._speeds: list[tuple[float, float]] = []  # (time, water speed) during the step
        self._saturated_s = 0.0
        self._last_time = math.nan
        self._band_since: float | None = None
        self._peaked = False
        self.flights = 0
        self.why_undecided: str | None = None
        self.undecided: list[str] = []  # why each flight that could not decide did not (figures included)
        self.metrics: FlownStepFigures | None = None
        self.series: dict[str, list[float]] = {"time": [], "heading": [], "target": [], "rudder": [], "speed": []}
        self.stage_times: dict[str, float] = {}

    # ------------------------------------------------------------------ helpers
    def _unwrapped(self, yaw: float) -> float:
        last, offset = self._unwrap
        if math.isfinite(last):
            offset += -2 * math.pi if yaw - last > math.pi else (2 * math.pi if yaw - last < -math.pi else 0.0)
        self._unwrap = (yaw, offset)
        return yaw + offset

    def _enter(self, phase: str, now: float) -> None:
        if math.isfinite(self._phase_start):
            self.stage_times[self._phase] = self.stage_times.get(self._phase, 0.0) + now - self._phase_start
        self._phase, self._phase_start = phase, now

    # ------------------------------------------------------------------ lifecycle
    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        self._phase_start = telemetry.time_s
        self._course = self._unwrapped(telemetry.yaw) if telemetry.finite("yaw") else 0.0
        self._steady = SteadinessDetector(self.config.steadiness, "yaw", wrap_pi(self._course))
        commands: list[Command] = [SetParameters(dict(self.gains))]
        if "rudder_trim" in self.gains:
            commands += reengage_hold(self.thrust, wrap_pi(self._course))
        return commands + [SetThrust(self.thrust), SetHeading(wrap_pi(self._course)),
                           StatusText(f"verifying {self.label} gains at thrust {self.thrust:.2f}"[:50])]

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        if not telemetry.finite("yaw"):
            return []
        now = telemetry.time_s
        heading = self._unwrapped(telemetry.yaw)
        if self._phase == "settle":
            steady = self._steady
            if steady is None:  # initialise and every settle after it make one
                raise RuntimeError(f"{self.name} settling without a steadiness detector")
            steady.add(now, telemetry.speed_water, telemetry.yaw_rate, telemetry.pitch_rate, telemetry.yaw)
            if steady.steady(now) or now - self._phase_start >= self.config.settle_max_s:
                return self._begin_step(now, heading)
            return []
        self._record(telemetry, now, heading)
        verdict = self._decided(telemetry, now, heading)
        if verdict is None:
            return []
        return self._conclude(verdict, now, heading)

    def _begin_step(self, now: float, heading: float) -> list[Command]:
        self.flights += 1
        self._enter("step", now)
        self._course = heading
        self._target = heading + self.sign * self.config.step
        self._speeds, self._saturated_s, self._band_since, self._peaked = [], 0.0, None, False
        self._last_time = now
        self._first_index = len(self.series["time"])
        return [SetHeading(wrap_pi(self._target))]

    def _record(self, telemetry: Telemetry, now: float, heading: float) -> None:
        self.series["time"].append(now)
        self.series["heading"].append(heading)
        self.series["target"].append(self._target)
        self.series["rudder"].append(telemetry.rudder)
        self.series["speed"].append(telemetry.speed_water)
        if telemetry.finite("speed_water"):
            self._speeds.append((now, telemetry.speed_water))
        if math.isfinite(telemetry.rudder) and abs(telemetry.rudder) >= 0.98 * self.rudder_max:
            self._saturated_s += max(0.0, now - self._last_time)
        self._last_time = now

    def _decided(self, telemetry: Telemetry, now: float, heading: float) -> str | None:
        """``"settled"``, ``"timeout"``, ``"disturbed"``, ``"saturated"`` or None (keep flying)."""
        if self._saturated_s > self.config.max_saturated_s + self.predicted_saturated_s:
            return "saturated"
        size = self._target - self._course
        progress = (heading - self._course) / size
        if progress >= 1.0:
            self._peaked = True  # crossed the target: the peak is at or after here
        if self._peaked and abs(progress - 1.0) <= SETTLE_BAND:
            if self._band_since is None:
                self._band_since = now
            if now - self._band_since >= self.config.band_hold_s and self._past_peak():
                if self._disturbed() is None:
                    return "settled"
                # the heading has settled but the speed is not back yet: the turn's own dip recovers
                # (a skid boat at low throttle slows in its own turn), a disturbance does not — so
                # the record goes on, and only a speed still off at ``max_s`` makes the step disturbed
        else:
            self._band_since = None
        if now - self._phase_start >= self.config.max_s:
            return self._disturbed() or "timeout"
        return None

    def _disturbed(self) -> str | None:
        """"disturbed" when the water speed over the step's last ``band_hold_s`` differs from its
        first by more than ``max_speed_change``: the thrust or the water changed under the step. The
        dip of the turn itself, recovered by the end, is the step's own response (a real hull loses
        10-20 % of its speed in a 40° turn)."""
        if len(self._speeds) < 4:
            return None
        start_time, end_time = self._speeds[0][0], self._speeds[-1][0]
        hold = self.config.band_hold_s
        first = [v for t, v in self._speeds if t <= start_time + hold]
        last = [v for t, v in self._speeds if t >= end_time - hold]
        start, end = float(np.mean(first)), float(np.mean(last))
        return "disturbed" if abs(end - start) > self.config.max_speed_change * max(abs(start), 1e-6) else None

    def _undecided_detail(self, verdict: str) -> str:
        """One flight's verdict with its figures: the speed change or the time at the rudder's limit."""
        if verdict == "saturated":
            return (f"saturated: rudder at its limit for {self._saturated_s:.1f} s "
                    f"(predicted {self.predicted_saturated_s:.1f} s)")
        if verdict == "disturbed" and len(self._speeds) >= 2:
            start, end = self._speeds[0][1], self._speeds[-1][1]
            return f"disturbed: water speed {start:.2f} -> {end:.2f} m/s over the step"
        return verdict

    def _past_peak(self) -> bool:
        """The smoothed heading has turned back from its extreme (the overshoot is in the record)."""
        first = self._first_index
        times = np.asarray(self.series["time"][first:])
        heading = np.asarray(self.series["heading"][first:])
        if len(times) < 7:
            return False
        smooth = smooth_heading(times, heading) * self.sign
        return int(np.argmax(smooth)) < len(smooth) - 3

    def _conclude(self, verdict: str, now: float, heading: float) -> list[Command]:
        first = self._first_index
        speeds = self._speeds
        self.metrics = FlownStepFigures(
            step_metrics(self.series["time"][first:], self.series["heading"][first:], self._course, self._target),
            step_deg=math.degrees(self._target - self._course),
            speed=float(np.mean([v for _, v in speeds])) if speeds else math.nan, ended=verdict,
            duration_s=now - self._phase_start)
        if verdict in ("settled", "timeout"):
            self.why_undecided = None
            self._enter("done", now)
            self.finish(Status.SUCCESS)
            return []
        self.why_undecided = f"the step was {verdict}"
        self.undecided.append(self._undecided_detail(verdict))
        if self.flights > self.config.repeats:
            self._enter("done", now)
            self.finish(Status.FAILURE, f"{self.label} gains at thrust {self.thrust:.2f}: "
                                        f"{self.why_undecided} twice, the step could not decide")
            return []
        self.sign = -self.sign  # fly it again, back the other way, once steady
        self._enter("settle", now)
        self._steady = SteadinessDetector(self.config.steadiness, "yaw", wrap_pi(heading))
        return [SetHeading(wrap_pi(self._target))]

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is Status.ABORTED and math.isfinite(self._course):
            return [SetHeading(wrap_pi(self._course))]
        return []

    @property
    def decided(self) -> bool:
        return self.status is Status.SUCCESS

    def result(self) -> VerificationResult:
        figures = self.metrics.figures if self.metrics is not None else None
        return VerificationResult(
            label=self.label, thrust=self.thrust, gains=dict(self.gains), decided=self.decided,
            why_undecided=self.why_undecided, flights=self.flights, undecided=tuple(self.undecided),
            max_overshoot_pct=figures.overshoot_pct if figures is not None else math.nan,
            iae_s=figures.iae_s if figures is not None else math.nan,
            oscillations=figures.oscillations if figures is not None else 0,
            steps=(self.metrics,) if self.metrics is not None else (),
            config=self.config, series={k: list(v) for k, v in self.series.items()},
            stage_times=dict(self.stage_times), aborted=self.status is Status.ABORTED)
