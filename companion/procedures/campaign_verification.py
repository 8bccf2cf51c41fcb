"""The short campaign's verification: the steps it flies, their predictions and the verdict
(``companion.procedures.verified_design`` says which steps and why).

:class:`CampaignVerification` is the campaign's bookkeeping for it. The campaign asks it for the
next step to fly at each of its slots — the lowest speed's own design right after that model was
accepted, then, after the design, the schedule at the highest speed (where the vehicle is), the
schedule at the lowest where the own design's flight does not stand for it, and the original gains
where a flown step was not predicted by its model — each slot answering None when there is nothing
to fly. Every flown step is recorded with the model's prediction for the same gains; the schedule
and the original gains are predicted at every identified speed; :meth:`decide` applies the
:class:`~companion.procedures.verified_design.KeepRule`.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Sequence

from behaviors.gain_scheduling import GainDesign, ScheduleKind
from behaviors.json_form import json_form
from behaviors.verification import VerificationConfig, VerificationStep
from companion.numerics.step_response import SETTLE_BAND
from companion.numerics.step_figures import PredictedStep
from companion.procedures.verified_design import (CONTROLLERS, FlownStep, HeadingLimits, KeepRule, PredictedAtSpeed,
                                                  predicted_step)

log = logging.getLogger(__name__)


#: whether the lowest speed's own-design flight stands for the schedule there
COVERAGE = ("covered", "not covered")


@dataclass(frozen=True)
class VerifiedSteps:
    """What the verification flew and predicted, as it stood: each flown step with its prediction
    (:class:`FlownStep`), each predicted step (:class:`PredictedAtSpeed`: ``predicted_step``'s step
    with its ``thrust``, ``speed`` and ``label``, scheduled or original), the coverage by thrust
    (:data:`COVERAGE`), and the controller and limits the predictions were made with. The JSON
    (:meth:`summary`): ``flown`` (figures only, no series), ``predicted``, ``coverage`` (by thrust, two
    decimals), ``settle_band``, ``controller``, ``limits``."""

    flown: tuple[FlownStep, ...]
    predicted: tuple[PredictedAtSpeed, ...]
    coverage: dict[float, str]
    controller: str
    limits: HeadingLimits

    def __post_init__(self) -> None:
        if any(value not in COVERAGE for value in self.coverage.values()):
            raise ValueError(f"VerifiedSteps.coverage is one of {', '.join(COVERAGE)} by thrust, not {self.coverage!r}")
        if any(not isinstance(step, PredictedAtSpeed) for step in self.predicted):
            raise ValueError("VerifiedSteps.predicted steps are each a PredictedAtSpeed (its thrust and label)")

    def summary(self) -> dict:
        """Flown and predicted steps (figures only, no series), the coverage and the rule, as
        computed (NaN where a figure is not known: the command lines print it so)."""
        def predicted_figures(step: PredictedAtSpeed) -> dict:
            figures = step.step.figures
            return {"thrust": step.thrust, "label": step.label, "iae_s": figures.iae_s,
                    "oscillations": figures.oscillations, "overshoot_pct": figures.overshoot_pct,
                    "settling_time_s": figures.settling_time_s, "rise_time_s": figures.rise_time_s,
                    "speed": step.speed, "saturated": step.step.saturated}

        def flown_figures(step: FlownStep) -> dict:
            out = {"thrust": step.thrust, "label": step.label, "decided": step.decided,
                   "why_undecided": step.why_undecided, "undecided": list(step.undecided), "flights": step.flights,
                   "max_overshoot_pct": step.max_overshoot_pct, "iae_s": step.iae_s, "oscillations": step.oscillations}
            if step.steps:
                flown = step.steps[0]
                out["settling_time_s"] = flown.figures.settling_time_s
                out["duration_s"] = flown.duration_s if flown.duration_s is not None else math.nan
            if step.predicted is not None:
                predicted = step.predicted.figures
                out["predicted"] = {"overshoot_pct": predicted.overshoot_pct, "iae_s": predicted.iae_s,
                                    "settling_time_s": predicted.settling_time_s,
                                    "oscillations": predicted.oscillations, "saturated": step.predicted.saturated}
            return out

        return {"flown": [flown_figures(s) for s in self.flown], "predicted": [predicted_figures(s) for s in self.predicted],
                "coverage": {f"{t:.2f}": v for t, v in self.coverage.items()}, "settle_band": SETTLE_BAND,
                "controller": self.controller, "limits": dataclasses.asdict(self.limits)}  # what was predicted with

    def to_dict(self) -> dict:
        """:meth:`summary` in strict JSON (NaN and infinities null)."""
        return json_form(self.summary())


class CampaignVerification:
    """Which verification steps to fly, their predictions, and the verdict (module docstring)."""

    def __init__(self, kind: ScheduleKind, config: VerificationConfig, rule: KeepRule,
                 limits: HeadingLimits) -> None:
        self.kind, self.config, self.rule, self.limits = kind, config, rule, limits
        self.controller = CONTROLLERS.get(kind.name, "pi")
        self.flown: list[FlownStep] = []
        self.predicted: list[PredictedAtSpeed] = []
        self.coverage: dict[float, str] = {}  # lowest thrust -> whether its own-design flight stands for the schedule
        self._sign = 1.0
        self._attempts: Sequence = ()  # the accepted identifications last seen (the steps' predictions)

    # ------------------------------------------------------------------ the models
    @staticmethod
    def _yaw(attempts: Sequence) -> list:
        return sorted((a for a in attempts if a.axis == "yaw" and a.accepted), key=lambda a: a.thrust)

    def attempt_at(self, attempts: Sequence, thrust: float):
        """The accepted yaw identification nearest ``thrust`` (its model and speed), None without one."""
        models = self._yaw(attempts)
        return min(models, key=lambda a: abs(a.thrust - thrust)) if models else None

    def model_at(self, attempts: Sequence, thrust: float):
        attempt = self.attempt_at(attempts, thrust)
        return attempt.model if attempt is not None else None

    def step_prediction(self, model, gains: dict[str, float], duration_s: float | None = None,
                        speed: float | None = None) -> PredictedStep:
        """The model's step with ``gains`` at ``speed``, over ``duration_s`` (default: the longest a
        flown step lasts)."""
        duration = duration_s if duration_s and math.isfinite(duration_s) and duration_s > 1.0 else self.config.max_s
        return predicted_step(self.controller, model, gains, self.limits, self.config.step, duration, speed)

    def _predicted_saturation_s(self, thrust: float, gains: dict[str, float]) -> float:
        """How long the step of ``gains`` at ``thrust`` sits at the rudder's limit on its model (0 without one)."""
        attempt = self.attempt_at(self._attempts, thrust)
        if attempt is None:
            return 0.0
        return self.step_prediction(attempt.model, gains, speed=attempt.speed).saturated_s

    def _step(self, thrust: float, gains: dict[str, float], label: str) -> VerificationStep:
        step = VerificationStep(thrust, gains, self.config, sign=self._sign, rudder_max=self.limits.rudder_max,
                                label=label, predicted_saturated_s=self._predicted_saturation_s(thrust, gains))
        self._sign = -self._sign  # alternate, so the campaign stays near its course
        return step

    # ------------------------------------------------------------------ the slots
    def own_step(self, attempts: Sequence, thrust: float) -> VerificationStep | None:
        """The lowest speed's own design, flown right after its model was accepted (None without one)."""
        self._attempts = tuple(attempts)
        models = [a for a in self._yaw(attempts) if a.thrust == thrust]
        if not models:
            return None
        attempt = models[-1]
        try:
            gains = self.kind.model_gains(attempt.model, attempt.speed)
        except ValueError as exc:  # no design at this speed: the schedule is flown there later
            log.info("no own design at thrust %.2f: %s", thrust, exc)
            return None
        return self._step(thrust, gains, "own")  # right after the validation record, at its speed

    def ends(self, design: GainDesign) -> tuple[float, float] | None:
        """The lowest and highest identified thrusts of the design (None without points)."""
        thrusts = sorted(point.thrust for point in design.points if point.thrust is not None)
        return (thrusts[0], thrusts[-1]) if thrusts else None

    def scheduled_step(self, design: GainDesign | None, end: str) -> VerificationStep | None:
        """The schedule at the ``"highest"`` or ``"lowest"`` identified speed, unless already flown
        there (the schedule itself, or an own design the schedule agrees with)."""
        if design is None:
            return None
        ends = self.ends(design)
        if ends is None:
            return None
        thrust = ends[1] if end == "highest" else ends[0]
        if any(s.thrust == thrust and s.label == "scheduled" for s in self.flown):
            return None
        if self.coverage.get(thrust) == "covered":
            return None
        point = next(p for p in design.points if p.thrust == thrust)
        return self._step(thrust, dict(point.scheduled), "scheduled")

    def original_step(self, original: dict[str, float], end: str, design: GainDesign | None) -> VerificationStep | None:
        """The original gains at a verified speed whose flown step its model did not predict (the
        comparison with them is then flown, not predicted); None otherwise."""
        ends = self.ends(design) if design is not None else None
        if ends is None or not original:
            return None
        thrust = ends[1] if end == "highest" else ends[0]
        designed = [s for s in self.flown if s.thrust == thrust and s.label in ("scheduled", "own")]
        if not designed or any(s.thrust == thrust and s.label == "original" for s in self.flown):
            return None
        step = designed[-1]
        if step.predicted is None or self.rule.agree(step, step.predicted) is None:
            return None
        log.info("thrust %.2f: %s; the original gains are flown there", thrust, self.rule.agree(step, step.predicted))
        return self._step(thrust, dict(original), "original")

    # ------------------------------------------------------------------ records
    def record(self, step: VerificationStep, attempts: Sequence) -> FlownStep:
        """A flown step's result with the model's prediction for its gains."""
        attempt = self.attempt_at(attempts, step.thrust)
        flown_s = step.metrics.duration_s if step.metrics is not None else None
        predicted = self.step_prediction(attempt.model, step.gains, flown_s, attempt.speed) \
            if attempt is not None else None
        result = FlownStep.of(step.result(), predicted)
        self.flown.append(result)
        return result

    def predict(self, design: GainDesign, attempts: Sequence, original: dict[str, float]) -> None:
        """The schedule's and the original gains' steps at every identified speed, on its model; and
        whether the lowest speed's own-design flight stands for the schedule there."""
        self._attempts = tuple(attempts)
        self.predicted = []
        for point in design.points:
            if point.thrust is None:  # not flown at a thrust of this campaign (``ends`` skips it too)
                continue
            model = self.model_at(attempts, point.thrust)
            if model is None:
                continue
            scheduled = self.step_prediction(model, point.scheduled, speed=point.speed)
            self.predicted.append(PredictedAtSpeed(point.thrust, point.speed, "scheduled", scheduled))
            if original:
                self.predicted.append(PredictedAtSpeed(point.thrust, point.speed, "original",
                                                       self.step_prediction(model, original, speed=point.speed)))
            own = next((s for s in self.flown if s.thrust == point.thrust and s.label == "own"), None)
            if own is not None and own.predicted is not None:
                self.coverage[point.thrust] = "covered" if self.rule.covers(own.predicted, scheduled) else \
                    "not covered"

    def decide(self) -> str | None:
        """The keep rule's verdict (None: the gains may be written)."""
        return self.rule.verdict(self.flown, self.predicted)

    def originals_stand(self) -> bool:
        """The design was refused only for not beating the original gains, which pass themselves."""
        return self.rule.originals_stand(self.flown, self.predicted)

    def verified(self) -> VerifiedSteps:
        """What was flown and predicted so far, as a record."""
        return VerifiedSteps(tuple(self.flown), tuple(self.predicted), dict(self.coverage),
                             self.controller, self.limits)

    def summary(self) -> dict:
        """Flown and predicted steps (figures only, no series), the coverage and the rule, for JSON
        (:meth:`VerifiedSteps.summary`)."""
        return self.verified().summary()
