"""Every behaviour's result is a frozen record: its ``to_dict`` is strict JSON (no NaN, no infinity,
records tagged as the store writes them) and a record that breaks its invariant is refused where it
is made (docs/store.md, "Behaviour results")."""
from __future__ import annotations

import dataclasses
import json
import math
from typing import Any, Callable

import numpy as np
import pytest

from behaviors.base import LifecycleResult, Status
from behaviors.gain_scheduling import SchedulingConfig, SchedulingResult
from behaviors.health_monitor import HealthAlarm, HealthResult
from behaviors.heading_steps import HeadingStepsResult, StepTestConfig
from behaviors.identification import IdentificationAttempt, IdentificationResult, ManoeuvreConfig
from behaviors.min_speed_result import MinSpeedResult
from behaviors.observe import ObserveResult
from behaviors.roll_kick import RollKickResult
from behaviors.roll_stabilisation import RollStabilisationResult, default_gains
from behaviors.sequence import SequenceResult
from behaviors.speed_steps import FlownSpeedStep, PredictedSpeedSteps, SpeedStepConfig, SpeedStepsResult
from behaviors.speed_tuning import SpeedTuningResult
from behaviors.steady_state import SquareConfig, SquaresResult, TurnConfig, TurnOutcome, TurnsResult
from behaviors.verification import VerificationConfig, VerificationResult
from companion.numerics.drift import DriftConfig
from companion.numerics.identification import YawModel
from companion.numerics.speed_gains import design_speed_gains
from companion.numerics.steady_state import StraightLegFit, TurnFit
from companion.numerics.step_figures import FlownStepFigures, PredictedStep, StepFigures
from companion.numerics.surge import SurgeModel
from companion.procedures.verified_design import FlownStep
from companion.records.serialise import json_ready, to_json

NAN = math.nan
SERIES = {"time": [0.0, 0.1, 0.2], "heading": [0.0, NAN, 0.3]}
STEP = StepFigures(overshoot_pct=4.0, rise_time_s=2.0, settling_time_s=NAN, iae_s=1.5, oscillations=0)
HEADING_STEP = FlownStepFigures(STEP, step_deg=20.0, speed=1.6)
VERIFIED_STEP = FlownStepFigures(STEP, step_deg=-20.0, speed=1.6, ended="settled", duration_s=9.5)
SPEED_STEP = FlownSpeedStep(STEP, 1.0, 2.0)
PREDICTED_STEP = PredictedStep(STEP, rudder_peak=0.31, saturated=False, saturated_s=0.0)
#: a speed step predicted on the surge model (``companion.numerics.speed_gains``' figures)
PREDICTED_SPEED_STEP = {"overshoot_pct": 4.0, "rise_time_s": 2.0, "settling_time_s": NAN, "iae_s": 1.5,
                        "oscillations": 0}
SURGE = SurgeModel(gain=2.5, exponent=1.0, gamma=0.28, lag=0.4)  # r2 NaN: not scored


def heading_steps(**changes: Any) -> HeadingStepsResult:
    fields = dict(label="scheduled", thrust=0.8, gains={"heading_p": 0.6}, steps=(HEADING_STEP, HEADING_STEP),
                  max_overshoot_pct=4.0, iae_s=3.0, oscillations=0, config=StepTestConfig(), series=SERIES, aborted=False)
    return HeadingStepsResult(**(fields | changes))


def verification(**changes: Any) -> VerificationResult:
    fields = dict(label="own", thrust=0.6, gains={"heading_p": 0.8}, decided=True, why_undecided=None, flights=1,
                  undecided=(), max_overshoot_pct=4.0, iae_s=1.5, oscillations=0, steps=(VERIFIED_STEP,),
                  config=VerificationConfig(), series=SERIES, stage_times={"settle": 3.0, "step": 9.5}, aborted=False)
    return VerificationResult(**(fields | changes))


def speed_steps(**changes: Any) -> SpeedStepsResult:
    fields = dict(label="design", gains={"speed_p": 0.2}, speeds=(1.0, 2.0), steps=(SPEED_STEP, SPEED_STEP),
                  max_overshoot_pct=4.0,
                  settling_time_s=NAN, config=SpeedStepConfig(), series={"time": [0.0], "speed": [NAN]}, aborted=False)
    return SpeedStepsResult(**(fields | changes))


def speed_tuning(**changes: Any) -> SpeedTuningResult:
    design = design_speed_gains(SURGE, 2.0, (1.0, 2.0), speed_max=2.0)
    fields = dict(status=Status.SUCCESS, reason=None, error=None, surge=SURGE, design=design,
                  original={"speed_p": 0.1}, context={"speed_default": 2.5}, steps={"design": speed_steps()},
                  verdict="passed",
                  original_steps=PredictedSpeedSteps("original", (PREDICTED_SPEED_STEP,), 19.0, math.inf),
                  original_flown_because=None, kept=design.gains.params(),
                  record={"time": [0.0], "throttle": [0.5], "speed": [NAN], "levels": [], "decimation": 5})
    return SpeedTuningResult(**(fields | changes))


def identification(**changes: Any) -> IdentificationResult:
    attempt = IdentificationAttempt(attempt=1, axis="yaw", thrust=0.7, speed=NAN, model=YawModel(-1.0, 0.7, 0.01),
                                    r2=0.95, accepted=True, converged=True, converged_s=None, criterion_met_from_s=None,
                                    training_s=8.0, samples=160)
    fields = dict(axis="yaw", thrust=0.7, outcome="accepted", abort_reason=None, config=ManoeuvreConfig(),
                  attempts=(attempt,), best=attempt)
    return IdentificationResult(**(fields | changes))


def min_speed(**changes: Any) -> MinSpeedResult:
    fields = dict(aborted=False, abort_reason="", thrust_ratio_final=0.44, speed_final=0.69, settle_time_s=None,
                  max_depth_error_m=NAN, max_depth_error_settled_m=None, depth_setpoint_m=2.0, reversals_last_30s=0,
                  decisions=120, theta_e_crossover=0.026, start_reached_s=None, governed_stalled=False,
                  depth_offset_max_m=0.0, depth_offset_faded_s=None, duration_s=200.0,
                  series={"time": [0.0, 1.0], "decision": [0, -1], "depth": [2.0, NAN]})
    return MinSpeedResult(**(fields | changes))


def legs_fit() -> StraightLegFit:
    return StraightLegFit(velocity_water=np.array([1.6, -0.01, 0.0]), current=np.array([0.01, 0.02]),
                          covariance=np.eye(5) * 1e-6, condition_number=1.1, residual_std=0.01,
                          residuals=np.zeros((4, 3)), samples=4)


def turn_fit() -> TurnFit:
    return TurnFit(center=np.zeros(2), current=np.array([0.01, 0.0]), rate=0.05, phase=0.1, radius=15.0, t0=0.0,
                   covariance=np.eye(7) * 1e-6, residual_std=0.1, residuals=np.zeros((20, 2)), samples=20)


def turns(**changes: Any) -> TurnsResult:
    fields = dict(status="partial", config=TurnConfig(),
                  turns=(TurnOutcome(0.22, turn_fit(), 20, 1.3, -0.05, NAN), TurnOutcome(-0.22, error="too few samples")))
    return TurnsResult(**(fields | changes))


def health(**changes: Any) -> HealthResult:
    fields = dict(label="campaign 1", config=DriftConfig(), speed_range=(1.0, 2.0), verdicts=(),
                  alarm=HealthAlarm("b2", 480.0, -31.0, NAN), restarts=0)
    return HealthResult(**(fields | changes))


#: each result type: a valid one, and one that breaks its invariant
CASES: dict[str, tuple[Callable[[], Any], Callable[[], Any]]] = {
    "lifecycle": (lambda: LifecycleResult("settle", Status.SUCCESS),
                  lambda: LifecycleResult("settle", "success")),  # a word, not a lifecycle status
    "sequence": (lambda: SequenceResult("roll", Status.FAILURE, "aborted", (LifecycleResult("prepare", Status.SUCCESS),
                                                                             heading_steps())),
                 lambda: SequenceResult("roll", "done", None, ())),
    "heading steps": (heading_steps, lambda: heading_steps(oscillations=-1)),
    "verification step": (verification, lambda: verification(why_undecided="the step was saturated")),
    "flown step with its prediction": (lambda: FlownStep.of(verification(), PREDICTED_STEP),
                                       lambda: FlownStep.of(verification(stage_times={"step": -1.0}), None)),
    "step figures": (lambda: STEP, lambda: dataclasses.replace(STEP, oscillations=1.5)),
    "predicted step": (lambda: PREDICTED_STEP, lambda: dataclasses.replace(PREDICTED_STEP, saturated_s=-0.1)),
    "flown heading step": (lambda: VERIFIED_STEP, lambda: dataclasses.replace(VERIFIED_STEP, ended="finished")),
    "flown speed step": (lambda: SPEED_STEP, lambda: FlownSpeedStep(STEP, 1.0, NAN)),
    "speed steps": (speed_steps, lambda: speed_steps(speeds=(0.0, 2.0))),
    "predicted speed steps": (lambda: PredictedSpeedSteps("original", (PREDICTED_SPEED_STEP,), 19.0, math.inf),
                              lambda: PredictedSpeedSteps("original", (PREDICTED_SPEED_STEP,), 19.0, -1.0)),
    "speed tuning": (speed_tuning, lambda: speed_tuning(verdict="not faster than the original gains")),
    "identification": (identification, lambda: identification(outcome="maybe")),
    "observation": (lambda: ObserveResult("open loop", 60.0, False, {"time": [0.0, 0.1], "roll": [NAN, 0.01]}),
                    lambda: ObserveResult("open loop", 60.0, False, {"time": [0.0, 0.1], "roll": [0.01]})),
    "roll impulse": (lambda: RollKickResult("roll kick open loop", Status.SUCCESS, 12.0, None),
                     lambda: RollKickResult("roll kick open loop", Status.FAILURE, None, 4.0)),
    "roll stabilisation": (lambda: RollStabilisationResult(False, "", 0, None, None, None, None, None, default_gains(),
                                                           {"time": [0.0], "mass_angle": [NAN]}),
                           lambda: RollStabilisationResult(False, "", 10, 0.1, 0.4, 0.0, 3.0, 1.5, default_gains(), {})),
    "minimum speed": (min_speed, lambda: min_speed(decisions=-1)),
    "squares": (lambda: SquaresResult("completed", SquareConfig(), 5000, legs_fit(), 4000),
                lambda: SquaresResult("completed", SquareConfig(), 5000)),  # completed without a fit
    "one turn": (lambda: TurnOutcome(0.22, error="the turn did not reach a steady rate long enough"),
                 lambda: TurnOutcome(0.22)),  # neither a fit nor the reason why not
    "turns": (turns, lambda: turns(status="completed")),  # one of its turns was not fitted
    "health alarm": (lambda: HealthAlarm("a22", 300.0, 25.0, 6.1), lambda: HealthAlarm("c22", 300.0, 25.0, 6.1)),
    "health session": (health, lambda: health(restarts=-2)),
    "gain scheduling": (lambda: SchedulingResult(({"time_s": 10.0, "speed": NAN, "heading_p": 0.5},),
                                                 SchedulingConfig(), None),
                        lambda: SchedulingResult(({"time_s": 20.0}, {"time_s": 10.0}), SchedulingConfig(), {})),
}


@pytest.mark.parametrize("kind", CASES)
def test_a_result_is_strict_json_as_the_store_writes_it(kind):
    valid, _ = CASES[kind]
    result = valid()
    out = result.to_dict()
    json.dumps(out, allow_nan=False)  # NaN and infinities are null
    assert json_ready(out) == out  # the store's serialiser writes it unchanged


@pytest.mark.parametrize("kind", CASES)
def test_a_result_that_breaks_its_invariant_is_refused(kind):
    _, invalid = CASES[kind]
    with pytest.raises(ValueError):
        invalid()


@pytest.mark.parametrize("kind", CASES)
def test_a_result_is_frozen(kind):
    valid, _ = CASES[kind]
    result = valid()
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(result, dataclasses.fields(result)[0].name, None)


def test_the_records_a_result_holds_are_tagged_as_the_store_tags_them():
    result = speed_tuning()
    out = result.to_dict()
    assert out["surge"] == to_json(result.surge) and out["design"] == to_json(result.design)
    assert out["original_steps"]["predicted"] is True and out["original_steps"]["settling_time_s"] is None


def test_the_square_json_holds_the_fit_figures_and_the_fits_own_sample_count():
    out = SquaresResult("completed", SquareConfig(), 5000, legs_fit(), 4000).to_dict()
    assert list(out)[:4] == ["behavior", "status", "config", "samples"]
    assert out["samples"] == 4 and out["samples_used"] == 4000 and out["surge_water"] == pytest.approx(1.6)


def test_a_turn_json_adds_the_mean_current_of_the_fitted_turns():
    out = turns().to_dict()
    assert out["current_north"] == pytest.approx(0.01) and out["current_east"] == pytest.approx(0.0)
    assert out["turns"][0]["sideslip_deg"] is None and out["turns"][1] == {
        "rudder_rad": -0.22, "rudder_deg": math.degrees(-0.22), "error": "too few samples"}
    assert "current_north" not in turns(status="failed", turns=(TurnOutcome(0.22, error="no fit"),)).to_dict()
