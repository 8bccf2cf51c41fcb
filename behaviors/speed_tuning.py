"""The speed loop identified and tuned from a campaign's own settles, verified by speed steps.

1. :class:`SurgeRecorder` keeps, while the identification manoeuvres settle at each thrust, the
   vehicle time, the throttle the autopilot outputs and the speed (straight running only:
   |yaw rate| below 3°/s), and the steady throttle and speed at the end of each level's last settle;
2. :class:`SpeedTuning` (built when its turn comes, after the heading checks) fits the surge model
   (``companion.numerics.surge``, eq. S.4), designs ArduRover's speed-loop gains
   (``companion.numerics.speed_gains``, eq. S.5), flies the design's speed steps in the holding mode
   (GUIDED) (``behaviors.speed_steps``), and keeps the design only when :class:`SpeedCheck` passes:
   at most 10 % overshoot on every step and settled sooner, summed over the steps, than with the
   original gains. The original gains' steps are predicted on the surge model when the design's
   flown steps show the model predicts them (eq. S.7, as eq. A.3 for the heading), and flown
   otherwise, or always with ``fly_original`` (the full comparison). Otherwise nothing is kept (the
   runner's restore point puts the original gains back, as for the heading gains).

The campaign writes the kept gains with its final heading gains, so a campaign that keeps nothing
(or fails) leaves the speed loop as it found it.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Sequence

from behaviors.base import Behaviour, Footprint, Status
from behaviors.json_form import json_form
from behaviors.sequence import SequenceBehavior
from behaviors.speed_steps import (PredictedSpeedSteps, SpeedStepConfig, SpeedStepFigures, SpeedStepsResult,
                                   SpeedStepTest)
from companion.checks import require_instance, require_non_negative, require_positive
from companion.interface import Command, StatusText, Telemetry
from companion.numerics.speed_gains import SpeedDesign, SpeedLoopGains, SpeedRules, design_speed_gains
from companion.numerics.surge import SurgeModel, fit_surge_model

log = logging.getLogger(__name__)

#: neutral parameters the speed tuning writes (and the restore point covers)
SPEED_GAINS = ("cruise_speed", "cruise_thrust", "speed_p", "speed_i")
#: neutral parameters it only reads: WP_SPEED (a thrust level's speed) and ATC_ACCEL_MAX
SPEED_CONTEXT = ("speed_default", "accel_max")
#: straight running: |yaw rate| below this (rad/s)
STRAIGHT_RATE = math.radians(3.0)
#: the steady level is the mean over this long before a settle ends (s)
STEADY_WINDOW_S = 2.0


@dataclass(frozen=True)
class SpeedCheck:
    """When the designed speed gains stay: every step within ``max_overshoot_pct``, and (with
    ``faster_than_original``) the summed settling time below the original gains' — flown, or
    predicted when the design's flown steps agree with their prediction (:meth:`agree`: every
    overshoot within ``overshoot_tolerance_pct`` points, the summed settling time within
    ``settling_tolerance_s``). Measured on ArduRover SITL: the original gains' steps flown at
    17.2/17.9 % overshoot and 5.9/6.9 s where 18.9/19.5 % and 6.0/6.9 s were predicted; the design's
    at 1.2/0.4 % and 2.0 s summed where 4.4/4.7 % and 1.6 s were."""

    max_overshoot_pct: float = 10.0
    faster_than_original: bool = True
    overshoot_tolerance_pct: float = 5.0
    settling_tolerance_s: float = 2.0

    def __post_init__(self) -> None:
        require_non_negative(self, "max_overshoot_pct")
        require_positive(self, "overshoot_tolerance_pct", "settling_tolerance_s")

    def agree(self, flown: SpeedStepsResult, predicted: Sequence[dict]) -> str | None:
        """None when the flown steps (``flown.steps``) match ``predicted`` (the same steps, in order)
        within the tolerances, else how they do not (eq. S.7)."""
        steps = flown.steps
        if len(steps) != len(predicted):
            return f"{len(steps)} speed steps flown where {len(predicted)} were predicted"
        for step, prediction in zip(steps, predicted):
            gap = abs(step.figures.overshoot_pct - prediction["overshoot_pct"])
            if not gap <= self.overshoot_tolerance_pct:
                return (f"speed step overshoot {step.figures.overshoot_pct:.1f} % where "
                        f"{prediction['overshoot_pct']:.1f} % "
                        f"was predicted")
        predicted_s = _summed(prediction["settling_time_s"] for prediction in predicted)
        if not abs(flown.settling_time_s - predicted_s) <= self.settling_tolerance_s:
            return f"speed steps settled in {flown.settling_time_s:.1f} s where {predicted_s:.1f} s was predicted"
        return None

    def verdict(self, original: SpeedStepFigures | None, design: SpeedStepsResult) -> str | None:
        """None when the design passes, else the reason."""
        for step in design.steps:
            overshoot = step.figures.overshoot_pct
            if not (isinstance(overshoot, float) and math.isfinite(overshoot)):
                return "a speed step without a measured overshoot"
            if overshoot > self.max_overshoot_pct:
                return f"speed step overshoot {overshoot:.1f} % > {self.max_overshoot_pct:.0f} %"
        if self.faster_than_original and original is not None:
            new, old = design.settling_time_s, original.settling_time_s
            if not new < old:
                how = " (predicted)" if isinstance(original, PredictedSpeedSteps) else ""
                return f"not faster than the original gains (settled in {new:.1f} s against {old:.1f} s{how})"
        return None


def _summed(values) -> float:
    """Summed settling times; a step that never settles makes the sum infinite."""
    total = 0.0
    for value in values:
        total += value if isinstance(value, (int, float)) and math.isfinite(value) else math.inf
    return total


@dataclass(frozen=True)
class SpeedLoopConfig:
    """Whether and how a campaign tunes the speed loop; ``enabled`` None: where the autopilot has one
    (its profile names the speed-loop gains), decided by ``CampaignConfig.resolved_for``."""

    enabled: bool | None = None
    rules: SpeedRules = SpeedRules()
    steps: SpeedStepConfig = SpeedStepConfig()
    check: SpeedCheck = SpeedCheck()


@dataclass
class SurgeRecord:
    """What :class:`SurgeRecorder` kept: the straight samples and the steady level of each thrust."""

    time: list[float] = field(default_factory=list)
    throttle: list[float] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    levels: dict = field(default_factory=dict)  # thrust level → (throttle, speed) at the end of its settle

    def stretches(self, max_gap_s: float = 0.5) -> list[tuple[int, int]]:
        """Index ranges [start, stop) of samples no more than ``max_gap_s`` apart."""
        out, start = [], 0
        for k in range(1, len(self.time) + 1):
            if k == len(self.time) or self.time[k] - self.time[k - 1] > max_gap_s:
                if k > start:
                    out.append((start, k))
                start = k
        return out


class SurgeRecorder:
    """Collects :class:`SurgeRecord` from the campaign's snapshots (module docstring, step 1)."""

    def __init__(self) -> None:
        self.record = SurgeRecord()
        self._window: list[tuple[float, float, float]] = []  # the current settle's last samples
        self._stage: tuple | None = None

    def add(self, telemetry: Telemetry, level: float | None, stage: str | None) -> None:
        """One snapshot; ``level`` the thrust level being identified, ``stage`` its manoeuvre stage."""
        key = (level, stage)
        if self._stage is not None and key != self._stage:
            self._close(*self._stage)
        self._stage = key if stage in ("settle", "resettle") else None
        if self._stage is None or not (telemetry.finite("speed_water") and telemetry.finite("thrust_ratio")):
            return
        sample = (telemetry.time_s, telemetry.thrust_ratio, telemetry.speed_water)
        self._window = [s for s in self._window if s[0] > telemetry.time_s - STEADY_WINDOW_S] + [sample]
        if telemetry.finite("yaw_rate") and abs(telemetry.yaw_rate) < STRAIGHT_RATE:
            self.record.time.append(sample[0])
            self.record.throttle.append(sample[1])
            self.record.speed.append(sample[2])

    def _close(self, level: float | None, stage: str | None) -> None:
        """A settle ended: its last samples are the level's steady throttle and speed (the last settle
        of a level counts: the longer at a level, the more settled its speed loop)."""
        if level is not None and self._window:
            n = len(self._window)
            self.record.levels[level] = (sum(s[1] for s in self._window) / n, sum(s[2] for s in self._window) / n)
        self._window = []


@dataclass(frozen=True)
class SpeedTuningResult:
    """The speed loop as tuned (module docstring): how it ended, why it could not be designed
    (``error``), the surge model and the design (typed records, tagged in the JSON as the store
    writes them), the original speed gains and the context read with them, the speed steps flown
    per gain set, the verdict ("passed", or why the design was refused; None: not decided), what the
    design was compared with (flown or predicted) and why the original gains were flown, the gains
    kept, and every n-th sample of the surge record (``time``, ``throttle``, ``speed``, ``levels``,
    ``decimation``)."""

    status: Status
    reason: str | None
    error: str | None
    surge: SurgeModel | None
    design: SpeedDesign | None
    original: dict[str, float]
    context: dict[str, float]
    steps: dict[str, SpeedStepsResult]
    verdict: str | None
    original_steps: SpeedStepFigures | None
    original_flown_because: str | None
    kept: dict[str, float] | None
    record: dict

    def __post_init__(self) -> None:
        require_instance(self, "status", Status)
        if self.kept and (self.design is None or self.verdict != "passed"):
            raise ValueError("SpeedTuningResult: gains are kept only from a design whose verdict passed, "
                             f"not {self.verdict!r}")

    def to_dict(self) -> dict:
        return json_form({"status": self.status.value, "reason": self.reason, "error": self.error,
                          "surge": self.surge, "design": self.design, "original": self.original,
                          "context": self.context, "steps": {k: r.to_dict() for k, r in self.steps.items()},
                          "verdict": self.verdict,
                          "original_steps": None if self.original_steps is None else self.original_steps.to_dict(),
                          "original_flown_because": self.original_flown_because, "kept": self.kept,
                          "record": self.record})


class SpeedTuning(Behaviour):
    """Design from the record, then the speed steps with the original gains and the design."""

    #: every n-th sample of the surge record goes into the result (the report's plot, a refit offline)
    RECORD_DECIMATION = 5

    def __init__(self, record: SurgeRecord, original: dict[str, float], config: SpeedLoopConfig = SpeedLoopConfig(),
                 fly_original: bool = False) -> None:
        super().__init__("speed loop")
        self.record = record
        self.config = config
        self.fly_original = fly_original
        self.original_flown_because: str | None = None  # why the original gains' steps were flown
        self.original_figures: SpeedStepFigures | None = None  # flown, or predicted
        self._per_thrust = math.nan
        self._requested: set[str] = set()  # the gain sets whose speed steps were asked for
        self.original = {k: v for k, v in original.items() if k in SPEED_GAINS}
        self.context = {k: v for k, v in original.items() if k in SPEED_CONTEXT}
        self.footprint = Footprint.of(parameters=SPEED_GAINS, setpoints=("mode", "thrust", "heading"))
        self.surge: SurgeModel | None = None
        self.design: SpeedDesign | None = None
        self.error: str | None = None
        self.step_results: dict[str, SpeedStepsResult] = {}
        self.kept: dict[str, float] | None = None
        self.verdict: str | None = None
        self._sequence: SequenceBehavior | None = None
        self._prepare(record)

    def _prepare(self, record: SurgeRecord) -> None:
        try:
            levels = list(record.levels.values())
            self.surge = fit_surge_model(record.time, record.throttle, record.speed, levels, record.stretches())
            original = SpeedLoopGains.from_params(self.original) if len(self.original) == len(SPEED_GAINS) else None
            speeds = [speed for _, speed in levels]
            cruise = self.original.get("cruise_speed", math.nan)
            per_thrust = self.context.get("speed_default", math.nan)
            if not per_thrust > 0.0:
                raise ValueError("no WP_SPEED: the speed a thrust level demands is unknown")
            self.design = design_speed_gains(self.surge, cruise, (min(speeds), max(speeds)), self.config.rules,
                                             self.context.get("accel_max", 1.0), original, speed_max=per_thrust)
            self._per_thrust = per_thrust
            if self.design.keeps_original:  # eq. S.5r: nothing predicted better, nothing to write or fly
                self.verdict = self.design.reason()
                return
            predictable = "original" in self.design.predicted
            if not predictable and self.original:
                self.original_flown_because = "the original gains are not complete enough to predict"
            labels = ("original", "design") if self.fly_original or not predictable else ("design",)
            if self.fly_original:
                self.original_flown_because = "the full comparison"
            self._sequence = self._steps(labels)
        except (ValueError, KeyError) as exc:
            self.error = str(exc)
            log.warning("speed loop not tuned: %s", exc)

    def _designed(self) -> SpeedDesign:
        """The design (set by ``_prepare`` with the surge model and the steps, or the behaviour fails at once)."""
        if self.design is None:
            raise RuntimeError(f"speed loop not designed: {self.error}")
        return self.design

    def _steps(self, labels: Sequence[str]) -> SequenceBehavior:
        design = self._designed()
        gains = {"original": self.original, "design": design.gains.params()}
        self._requested.update(labels)
        steps = [SpeedStepTest(gains[label], design.step, self._per_thrust, self.config.steps, label)
                 for label in labels if gains[label]]
        return SequenceBehavior(steps, on_complete=self._on_step, name="speed steps")

    def _original_figures(self) -> SpeedStepFigures | None:
        """The original gains' steps as flown, or as predicted when the design's flight agreed with its
        prediction (None: the original gains must be flown, or there are none)."""
        if "original" in self.step_results:
            return self.step_results["original"]
        predicted = self._designed().predicted
        if not self.original or "original" not in predicted:
            return None
        design = self.step_results.get("design")
        if design is None:  # asked only once the design's steps are flown (update)
            raise RuntimeError("the design's speed steps were not flown")
        why = self.config.check.agree(design, [predicted["design"], predicted["design_back"]])
        if why is not None:
            self.original_flown_because = why
            return None
        steps = (predicted["original"], predicted["original_back"])
        return PredictedSpeedSteps("original", steps, max(step["overshoot_pct"] for step in steps),
                                   _summed(step["settling_time_s"] for step in steps))

    def _on_step(self, step: Behaviour) -> None:
        if isinstance(step, SpeedStepTest):
            self.step_results[step.label] = step.result()

    @property
    def keeps_original(self) -> bool:
        """The design found nothing predicted better than the vehicle's own speed gains (eq. S.5r):
        no step is flown and nothing is written."""
        return self.design is not None and self.design.keeps_original

    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        if self.keeps_original:
            self.finish(Status.SUCCESS, self.verdict)
            log.info("speed loop: %s", self.verdict)
            return [StatusText("speed loop: own gains kept (none better)")]
        if self._sequence is None or self.surge is None:  # _prepare sets both, or neither
            self.finish(Status.FAILURE, f"speed loop not tuned: {self.error}")
            return [StatusText(f"speed loop not tuned: {self.error}"[:50], 4)]
        return [StatusText(f"speed loop: {self.surge.describe()}"[:50])]

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        sequence = self._sequence
        if sequence is None:  # initialise failed the behaviour: no update follows
            raise RuntimeError("speed loop updated without its speed steps")
        commands = list(sequence.tick(telemetry))
        if sequence.done:
            design = self.step_results.get("design")
            original = None
            if design is not None and self.original:
                original = self._original_figures()
                if original is None and "original" not in self._requested:  # not predictable: fly them
                    log.info("speed loop: %s; the original gains are flown", self.original_flown_because)
                    commands.append(StatusText("speed loop: original gains flown too"))
                    self._sequence = self._steps(("original",))
                    return commands
            if design is None:
                self.verdict = "the design's speed steps did not complete"
            else:
                self.verdict = self.config.check.verdict(original, design)
            self.original_figures = original
            if self.verdict is None:
                self.kept = self._designed().gains.params()
                self.finish(Status.SUCCESS)
                commands.append(StatusText("speed gains verified"))
            else:
                self.finish(Status.FAILURE, f"speed gains rejected: {self.verdict}")
                commands.append(StatusText(f"speed gains rejected: {self.verdict}"[:50], 4))
        return commands

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is Status.ABORTED and self._sequence is not None:
            return self._sequence.stop(self.reason or "aborted")
        return []

    def result(self) -> SpeedTuningResult:
        return SpeedTuningResult(
            status=self.status, reason=self.reason, error=self.error, surge=self.surge, design=self.design,
            original=dict(self.original), context=dict(self.context), steps=dict(self.step_results),
            verdict=self.verdict or ("passed" if self.kept else None), original_steps=self.original_figures,
            original_flown_because=self.original_flown_because, kept=None if self.kept is None else dict(self.kept),
            record=self._record_sample())

    def _record_sample(self) -> dict:
        n = self.RECORD_DECIMATION
        record = self.record
        return {"time": record.time[::n], "throttle": record.throttle[::n], "speed": record.speed[::n],
                "levels": [[level, throttle, speed] for level, (throttle, speed) in sorted(record.levels.items())],
                "decimation": n}
