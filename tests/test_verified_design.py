"""The short campaign's verification: one heading step that ends when it has decided, the model's
prediction of it, and the rule that keeps or refuses the gains (companion.procedures.verified_design)."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest

from behaviors.base import Status
from behaviors.verification import VerificationConfig, VerificationStep
from companion.interface import SetHeading, Telemetry
from companion.numerics.angles import wrap_pi
from companion.numerics.step_figures import PredictedStep, StepFigures
from companion.procedures.verified_design import FlownStep, HeadingLimits, KeepRule, PredictedAtSpeed, predicted_step

RUDDER_MAX = math.radians(30.0)


@dataclass(frozen=True)
class YawModel:
    a22: float = -1.0
    b2: float = 0.7
    delta0: float = 0.0


def _fly(step: VerificationStep, model: YawModel, speed=lambda t: 1.2, seconds: float = 120.0, dt: float = 0.05,
         noise: float = 0.0, seed: int = 1) -> list[float]:
    """A vehicle whose autopilot holds the set heading with the step's PI gains (eq. A.1) on the
    first-order yaw model (eq. 3.6); returns the vehicle times at which a step began."""
    rng = np.random.default_rng(seed)
    kp, ki = step.gains["heading_p"], step.gains["heading_i"]
    heading = rate = integral = 0.0
    target, t, began = 0.0, 0.0, []
    while t < seconds and not step.status.finished:
        telemetry = Telemetry(time_s=t, yaw=wrap_pi(heading + noise * rng.standard_normal()), yaw_rate=rate,
                              speed_water=speed(t) + noise * rng.standard_normal(), rudder=0.0)
        error = wrap_pi(target - heading)
        rudder = min(max(kp * error + integral, -RUDDER_MAX), RUDDER_MAX)
        telemetry = Telemetry(**{**telemetry.__dict__, "rudder": rudder})
        flights = step.flights
        for command in step.tick(telemetry):
            if isinstance(command, SetHeading):
                target = command.heading
        if step.flights > flights:
            began.append(t)
        unsaturated = kp * error + integral  # eq. A.1: no integration into the rudder's limit
        if unsaturated == rudder or (ki * error) * unsaturated <= 0.0:
            integral = min(max(integral + ki * error * dt, -0.15), 0.15)
        rate += (model.a22 * rate + model.b2 * (rudder - model.delta0)) * dt
        heading += rate * dt
        t = round(t + dt, 6)
    return began


GAINS = {"heading_p": 0.8, "heading_i": 0.05}


def test_a_decided_step_is_flown_once_and_its_prediction_agrees_with_it():
    step = VerificationStep(0.6, GAINS, VerificationConfig(), rudder_max=RUDDER_MAX, label="own")
    _fly(step, YawModel())
    assert step.status is Status.SUCCESS and step.flights == 1
    flown = step.result()
    predicted = predicted_step("pi", YawModel(), GAINS, HeadingLimits(rudder_max=RUDDER_MAX),
                               VerificationConfig().step, step.metrics.duration_s)
    assert KeepRule().agree(flown, predicted) is None
    assert step.metrics.duration_s < VerificationConfig().max_s  # it ended on the band, not the clock


def test_a_step_waits_for_the_heading_hold_to_come_to_rest_and_is_then_flown_once():
    """After a doublet the autopilot's heading hold is re-engaged: a step flown before it is at rest
    overshoots more than its prediction (module docstring of behaviors.verification)."""
    bump = lambda t: 1.1 + 0.12 * math.exp(-t / 1.5)  # noqa: E731 - the speed still recovering
    step = VerificationStep(0.6, GAINS, VerificationConfig(), rudder_max=RUDDER_MAX)
    began = _fly(step, YawModel(), speed=bump, noise=0.005)
    assert step.status is Status.SUCCESS and step.flights == 1
    assert began[0] >= 6.0  # a full steadiness window (SteadinessRule.window_s), never on the recovery
    assert abs(bump(began[0]) - 1.1) < 0.01


def test_a_step_disturbed_twice_cannot_decide_and_says_why():
    drifting = lambda t: 1.2 + 0.03 * t  # noqa: E731 - a thrust change that never settles
    step = VerificationStep(0.6, GAINS, VerificationConfig(settle_max_s=5.0), rudder_max=RUDDER_MAX)
    _fly(step, YawModel(), speed=drifting)
    assert step.status is Status.FAILURE and step.flights == 2
    assert not step.decided and "disturbed" in step.why_undecided


def test_the_speed_lost_in_the_turn_itself_is_no_disturbance():
    # the settle ends at settle_max_s (5 s: before the steadiness window is full), and the step begins
    turning = lambda t: 1.2 * (1.0 - 0.15 * math.sin(math.pi * (t - 5.0) / 5.0)) if 5.0 <= t <= 10.0 else 1.2  # noqa: E731
    step = VerificationStep(0.6, GAINS, VerificationConfig(settle_max_s=5.0), rudder_max=RUDDER_MAX)
    began = _fly(step, YawModel(), speed=turning)
    assert began == [pytest.approx(5.0)]  # the dip falls inside the step: 15 % lost, regained
    assert step.status is Status.SUCCESS and step.flights == 1


def test_a_slow_recovery_of_the_speed_lost_in_the_turn_is_waited_for_not_taken_for_a_disturbance():
    # a skid boat at low throttle: 25 % lost in its own turn, regained over ~12 s by its speed loop,
    # long after the heading has settled
    def skid(t):
        return 1.2 if t < 5.0 else 1.2 * (1.0 - 0.25 * math.exp(-(t - 5.0) / 4.0) * min(1.0, (t - 5.0) / 2.0))
    step = VerificationStep(0.6, GAINS, VerificationConfig(settle_max_s=5.0), rudder_max=RUDDER_MAX)
    _fly(step, YawModel(), speed=skid)
    assert step.status is Status.SUCCESS and step.flights == 1
    assert step.metrics.ended == "settled" and step.metrics.duration_s < VerificationConfig().max_s


def _predicted(overshoot_pct: float, iae_s: float) -> PredictedStep:
    """A step predicted with this overshoot and step error, no reversal, the rudder never at its limit."""
    return PredictedStep(StepFigures(overshoot_pct, math.nan, math.nan, iae_s, 0), rudder_peak=0.1, saturated=False,
                         saturated_s=0.0)


def _at(thrust: float, label: str, overshoot_pct: float, iae_s: float) -> PredictedAtSpeed:
    """The ``label`` gains' step predicted at ``thrust``."""
    return PredictedAtSpeed(thrust, None, label, _predicted(overshoot_pct, iae_s))


def _flown(thrust: float, label: str, overshoot_pct: float, iae_s: float,
           predicted: PredictedStep | None = None) -> FlownStep:
    """A verification step flown once, decided, with these figures and this prediction."""
    return FlownStep(label=label, thrust=thrust, gains={}, decided=True, why_undecided=None, flights=1, undecided=(),
                     max_overshoot_pct=overshoot_pct, iae_s=iae_s, oscillations=0, steps=(),
                     config=VerificationConfig(), series={}, stage_times={}, aborted=False, predicted=predicted)


def test_the_keep_rule_refuses_what_overshoots_what_was_not_predicted_and_what_is_worse_than_the_original():
    rule = KeepRule()
    good = _flown(0.6, "own", 5.0, 2.6, _predicted(4.4, 2.7))
    predicted = [_at(0.6, "scheduled", 4.4, 2.9), _at(0.6, "original", 19.0, 4.5)]
    assert rule.verdict([good], predicted) is None
    assert "no verification step" in rule.verdict([], predicted)
    overshooting = replace(good, max_overshoot_pct=12.0)
    assert "overshoot 12.0 %" in rule.verdict([overshooting], predicted)
    undecided = replace(good, decided=False, why_undecided="the step was saturated")
    assert "saturated" in rule.verdict([undecided], predicted)
    surprising = replace(good, iae_s=4.0)  # the model did not predict it: its predictions cannot stand in
    assert "original gains were not flown" in rule.verdict([surprising], predicted)
    flown_original = _flown(0.6, "original", 18.0, 3.5)
    assert "not better than the original" in rule.verdict([surprising, flown_original], predicted)
    assert rule.verdict([surprising, replace(flown_original, iae_s=5.0)], predicted) is None
    worse_predicted = [predicted[0], _at(0.6, "original", 19.0, 2.0)]
    assert "(predicted): not better" in rule.verdict([good], worse_predicted)
    # a schedule flown at a speed whose model mispredicted it (ArduPilot's own motorboat: 7.8 % flown,
    # 62.8 % predicted): the flight, better than the original gains flown there, decides that speed
    flown_schedule = replace(good, label="scheduled", max_overshoot_pct=7.8, iae_s=1.2,
                             predicted=_predicted(62.8, 3.0))
    mispredicted = [_at(0.6, "scheduled", 62.8, 2.9), predicted[1]]
    assert rule.verdict([flown_schedule, replace(flown_original, iae_s=2.0)], mispredicted) is None
    assert "(predicted): overshoot 62.8" in rule.verdict([good], mispredicted)  # only predicted: it counts


def test_the_vehicles_own_gains_stand_when_the_design_only_fails_to_beat_them_and_they_pass_themselves():
    rule = KeepRule()
    design = _flown(0.65, "scheduled", 0.5, 0.46, _predicted(0.2, 0.34))  # ArduSub's vectored model
    own = _flown(0.65, "original", 1.0, 0.46)
    predicted = [_at(0.45, "original", 1.5, 0.44), _at(0.45, "scheduled", 0.2, 0.33)]
    assert "not better than the original" in rule.verdict([design, own], predicted)
    assert rule.originals_stand([design, own], predicted)
    assert not rule.originals_stand([design, replace(own, max_overshoot_pct=15.0)], predicted)  # they fail themselves
    assert not rule.originals_stand([replace(design, max_overshoot_pct=12.0), own], predicted)  # another reason
    assert not rule.originals_stand([design, replace(own, iae_s=0.9)], predicted)  # the design passes: nothing to keep


def test_a_prediction_sees_the_rudder_limit_and_the_schedule_covered_by_a_nearby_design():
    limits = HeadingLimits(rudder_max=math.radians(5.0))
    saturated = predicted_step("pi", YawModel(), {"heading_p": 3.0, "heading_i": 0.1}, limits, math.radians(20.0), 25.0)
    assert saturated.saturated
    free = predicted_step("pi", YawModel(), GAINS, HeadingLimits(rudder_max=RUDDER_MAX), math.radians(20.0), 25.0)
    assert not free.saturated
    nearby = predicted_step("pi", YawModel(), {"heading_p": 0.82, "heading_i": 0.05}, HeadingLimits(rudder_max=RUDDER_MAX),
                            math.radians(20.0), 25.0)
    far = predicted_step("pi", YawModel(), {"heading_p": 0.3, "heading_i": 0.05}, HeadingLimits(rudder_max=RUDDER_MAX),
                         math.radians(20.0), 25.0)
    assert KeepRule().covers(free, nearby) and not KeepRule().covers(free, far)


@pytest.mark.parametrize("bad", [{"max_oscillations": -1}, {"overshoot_tolerance_pct": 0.0}])
def test_a_keep_rule_with_impossible_numbers_is_refused(bad):
    with pytest.raises(ValueError):
        KeepRule(**bad)


# ---------------------------------------------------------------------------- the campaign
def _quick_campaign(seed: int, **changes):
    from dataclasses import replace

    from companion.procedures.campaign import CampaignConfig, IdentificationCampaign
    from companion.procedures.runner import RestorePoint, run_procedure
    from harness.inprocess import InProcessLink

    link = InProcessLink(seed=seed)
    config = replace(CampaignConfig(thrusts=(0.7, 0.85, 1.0), axes=("yaw",)).quick(), **changes)
    campaign = IdentificationCampaign(config)
    restore = RestorePoint.capture(link, campaign.footprint)
    campaign.original_gains = dict(restore.parameters)
    return link, campaign, run_procedure(link, campaign), restore


def test_the_quick_campaign_flies_the_ends_predicts_the_middle_and_writes_what_it_verified():
    link, campaign, outcome, _ = _quick_campaign(3)
    assert outcome.status == "completed" and campaign.config.checked == "verify"
    flown = campaign.verifier.flown
    # an optimised design is chosen over every speed's model, so its schedule is flown at both ends
    assert [(s.thrust, s.label) for s in flown] == [(1.0, "scheduled"), (0.7, "scheduled")]
    assert campaign.heading_choice is not None and not campaign.heading_choice.keeps_original
    assert all(s.decided and s.flights == 1 for s in flown)
    assert all(KeepRule().agree(s, s.predicted) is None for s in flown)
    assert {s.thrust for s in campaign.verifier.predicted} == {0.7, 0.85, 1.0}
    phases = campaign.phases_in_order()
    assert "verification" in phases and "heading_steps" not in phases
    assert list(phases)[:3] == ["settle", "excitation", "validation"]
    written = {name: link.param(name) for name in campaign.final_gains}
    assert written == pytest.approx(campaign.final_gains, rel=1e-6)


def test_the_rule_design_flies_the_lowest_speeds_own_design_right_after_its_model():
    link, campaign, outcome, _ = _quick_campaign(3, design="rule")
    assert outcome.status == "completed" and campaign.heading_choice is None
    assert [(s.thrust, s.label) for s in campaign.verifier.flown][0] == (0.7, "own")


def test_a_verification_that_cannot_pass_leaves_the_original_gains():
    link, campaign, outcome, restore = _quick_campaign(3, keep=KeepRule(max_overshoot_pct=0.5))
    assert outcome.status == "failed" and "overshoot" in outcome.reason
    assert campaign.final_gains is None
    for name, value in restore.parameters.items():
        assert link.param(name) == pytest.approx(value)


def test_a_vehicle_already_on_the_best_gains_keeps_them_and_the_campaign_completes_without_writing():
    from dataclasses import replace

    from companion.procedures.campaign import CampaignConfig, IdentificationCampaign
    from companion.procedures.runner import RestorePoint, run_procedure
    from harness.inprocess import InProcessLink

    def campaign_on(link):
        config = replace(CampaignConfig(thrusts=(0.85,), axes=("yaw",)).quick())
        campaign = IdentificationCampaign(config)
        restore = RestorePoint.capture(link, campaign.footprint)
        campaign.original_gains = dict(restore.parameters)
        return campaign, run_procedure(link, campaign)

    first, outcome = campaign_on(InProcessLink(seed=4))
    assert outcome.status == "completed" and first.loop_outcomes()["heading"].outcome == "written"
    # the same vehicle, already flying what the first campaign wrote
    link = InProcessLink(seed=4)
    link.set_params({name: first.final_gains[name] for name in ("heading_p", "heading_i", "rudder_trim")})
    before = link.get_params(("heading_p", "heading_i", "rudder_trim"))
    second, outcome = campaign_on(link)
    assert outcome.status == "completed", outcome.reason
    assert second.keeps_original_heading and second.loop_outcomes()["heading"].outcome == "original kept"
    assert second.final_gains is None and (second.verifier is None or not second.verifier.flown)  # nothing flown
    assert link.get_params(before) == pytest.approx(before)


def _two_loop_procedure(fail: bool = True):
    """A procedure that writes one loop's verified gain (heading_p), changes another (heading_i) and
    then fails (or runs on until aborted): what it verified is its ``kept_parameters``."""
    from behaviors.base import Behaviour, Footprint, Status
    from companion.interface import SetParameters

    class TwoLoops(Behaviour):
        footprint = Footprint.of(parameters=("heading_p", "heading_i"))

        def __init__(self) -> None:
            super().__init__("two loops")
            self.kept_parameters = frozenset({"heading_p"})
            self.ticks = 0

        def update(self, telemetry):
            self.ticks += 1
            if self.ticks == 1:
                return [SetParameters({"heading_p": 0.42, "heading_i": 0.0123})]
            if self.ticks == 5 and fail:
                self.finish(Status.FAILURE, "the other loop was refused")
            return []

    return TwoLoops()


def test_what_one_loop_verified_stays_when_another_fails_and_nothing_stays_after_an_abort():
    from companion.procedures.runner import run_procedure
    from harness.inprocess import InProcessLink

    link = InProcessLink(seed=1)
    before = link.get_params(("heading_p", "heading_i"))
    outcome = run_procedure(link, _two_loop_procedure())
    assert outcome.status == "failed"
    assert link.param("heading_p") == pytest.approx(0.42)  # verified: kept
    assert link.param("heading_i") == pytest.approx(before["heading_i"])  # not verified: restored

    link = InProcessLink(seed=1)
    ticks = iter(range(1000))
    outcome = run_procedure(link, _two_loop_procedure(fail=False),
                            abort_requested=lambda: "operator" if next(ticks) > 10 else None)
    assert outcome.status == "aborted"
    assert link.get_params(before) == pytest.approx(before)


def test_a_step_its_model_predicts_saturated_decides_where_unpredicted_saturation_cannot():
    """A slow boat's large step turns at the rudder's limit for seconds (PX4's rover at 1.3 m/s, ±40°):
    predicted so on its model, the step is compared with that prediction; the same saturation that
    the prediction does not show makes it undecided (the model does not stand for the step)."""
    slow, gains = YawModel(a22=-0.9, b2=0.3), {"heading_p": 2.0, "heading_i": 0.05}
    config = VerificationConfig(step=math.radians(40.0))
    predicted = predicted_step("pi", slow, gains, HeadingLimits(rudder_max=RUDDER_MAX), config.step, config.max_s)
    assert predicted.saturated_s > config.max_saturated_s  # the premise: a long saturated turn
    unpredicted = VerificationStep(0.6, gains, config, rudder_max=RUDDER_MAX)
    _fly(unpredicted, slow)
    assert unpredicted.status is Status.FAILURE and "saturated" in unpredicted.why_undecided
    allowed = VerificationStep(0.6, gains, config, rudder_max=RUDDER_MAX, predicted_saturated_s=predicted.saturated_s)
    _fly(allowed, slow)
    assert allowed.status is Status.SUCCESS and allowed.flights == 1
    assert KeepRule().agree(allowed.result(), predicted_step("pi", slow, gains, HeadingLimits(rudder_max=RUDDER_MAX),
                                                             config.step, allowed.metrics.duration_s)) is None
    with pytest.raises(ValueError, match="predicted_saturated_s"):
        VerificationStep(0.6, gains, config, predicted_saturated_s=math.nan)
