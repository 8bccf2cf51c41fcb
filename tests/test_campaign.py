"""The identification campaign state machine on the in-process simulator: results and abort paths.

Every abort path must leave the autopilot as it was found: overrides released, the original mode
and the original heading gains (SPEC C4).
"""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from behaviors.schedules import kind_of

from behaviors.identification import IdentificationManoeuvre, ManoeuvreConfig, doublet
from companion.procedures.app import AbortFlag, drain_campaign_events
from companion.procedures.campaign import AttemptRecorded, CampaignConfig, IdentificationCampaign
from companion.interface import OverrideActuator
from companion.procedures.runner import RestorePoint, SafetyLimits, run_behavior, run_procedure
from companion.records.store import Store
from sim.linearize import linearized_yaw
from sim.preset import load_preset
from harness.inprocess import InProcessLink

FAST = CampaignConfig(thrusts=(0.7, 1.0), axes=("yaw",), step_labels=("scheduled",),
                      yaw=ManoeuvreConfig(settle_s=15.0, resettle_s=12.0))


def run_campaign(link: InProcessLink, config: CampaignConfig = FAST, **kwargs):
    campaign = IdentificationCampaign(config)
    restore = RestorePoint.capture(link, campaign.footprint)
    campaign.original_gains = dict(restore.parameters)
    outcome = run_procedure(link, campaign, **kwargs)
    return campaign, outcome, restore


@pytest.fixture(scope="module")
def completed():
    link = InProcessLink(seed=5)
    campaign, outcome, restore = run_campaign(link)
    return link, campaign, outcome, restore


def test_doublet_shape():
    values = [doublet(t / 10, 2.0, 4.0, 0.26) for t in range(0, 70)]
    assert values[:20] == [None] * 20
    assert set(values[20:40]) == {0.26} and set(values[40:60]) == {-0.26}
    assert values[60:] == [None] * 10


def test_campaign_identifies_each_thrust_close_to_the_simulator_truth(completed):
    link, campaign, outcome, _ = completed
    assert outcome.status == "completed", outcome.reason
    preset = load_preset("starfish")
    yaw = [a for a in campaign.accepted if a.axis == "yaw"]
    assert [a.thrust for a in yaw] == [0.7, 1.0]
    for attempt in yaw:
        truth = linearized_yaw(preset, attempt.speed)
        model = attempt.model
        assert model.a22 == pytest.approx(truth["a22"], rel=0.08)
        assert model.b2 == pytest.approx(truth["b2"], rel=0.08)
        assert model.delta0 == pytest.approx(truth["delta0"], abs=0.004)
        assert attempt.r2 >= 0.9
        assert attempt.converged_s is not None and attempt.converged_s <= 16.5


def test_campaign_writes_scheduled_gains_and_keeps_them(completed):
    link, campaign, _, restore = completed
    design = campaign.heading_design
    assert design is not None and design.schedule.b2_slope > 0
    final = campaign.final_gains
    assert final is not None
    assert link.param("heading_p") == pytest.approx(final["heading_p"], rel=1e-6)
    # the design carries the rules it was made with: they give back every designed point exactly
    rebuilt = kind_of(design)
    assert rebuilt is not None and design.rules is not None
    for point in design.points:
        assert rebuilt.gains(design.schedule, point.speed) == pytest.approx(point.scheduled, rel=1e-12)
    assert link.param("heading_p") != pytest.approx(restore.parameters["heading_p"], rel=1e-3)
    assert not link.overrides, "no override may outlive the campaign"
    steps = campaign.step_results
    assert {s.label for s in steps} == {"scheduled"} and len(steps) == 2
    assert all(len(s.steps) == 2 for s in steps)


def test_campaign_events_reach_the_store(completed, tmp_path):
    _, campaign, _, _ = completed
    campaign.events = [AttemptRecorded(a) for a in campaign.accepted]
    with Store(tmp_path / "s.sqlite") as store:
        vehicle = store.add_vehicle("v")
        cid = store.start_campaign(vehicle, "identification")
        drain_campaign_events(store, cid, campaign)
        assert len(store.models(cid, axis="yaw")) == len(campaign.accepted)


def _assert_restored(link: InProcessLink, restore: RestorePoint) -> None:
    assert not link.overrides
    assert link.mode == restore.mode
    for name, value in restore.parameters.items():
        assert link.param(name) == pytest.approx(value, abs=1e-9), name
    assert not link.simulated.overridden(1)


def _abort_when(condition):
    flag = AbortFlag()
    return flag, condition


@pytest.mark.parametrize("stage_time", [5.0, 18.0, 21.0, 40.0])
def test_abort_request_at_any_stage_restores_the_autopilot(stage_time):
    """A signal or ground-station abort while settling, in the doublet, after it, in validation."""
    link = InProcessLink(seed=2)
    link.execute([])  # nothing pending
    start = link.vehicle.time_s

    def abort_requested():
        return "operator abort" if link.vehicle.time_s - start >= stage_time else None

    campaign, outcome, restore = run_campaign(link, abort_requested=abort_requested)
    assert outcome.status == "aborted" and outcome.reason == "operator abort"
    _assert_restored(link, restore)
    assert any("aborted" in text for text in link.status_texts)


def test_abort_after_gains_were_written_restores_the_original_gains():
    link = InProcessLink(seed=2)
    config = replace(FAST, thrusts=(0.8,), step_labels=("scheduled", "constant"))
    state = {}

    def abort_requested():
        if link.param_writes and "t" not in state:
            state["t"] = link.vehicle.time_s
        return "operator abort" if "t" in state and link.vehicle.time_s - state["t"] > 5.0 else None

    campaign, outcome, restore = run_campaign(link, config, abort_requested=abort_requested)
    assert outcome.status == "aborted"
    assert link.param_writes, "the test must abort after a gain write"
    _assert_restored(link, restore)


def test_link_loss_aborts_and_restores():
    link = InProcessLink(seed=2, lose_link_at_s=22.0)
    campaign, outcome, restore = run_campaign(link)
    assert outcome.status == "aborted" and "LinkLost" in outcome.reason
    link.lose_link_at_s = None  # the link is back: the restore must have gone through it
    _assert_restored(link, restore)


def test_attitude_limit_aborts_during_the_doublet():
    link = InProcessLink(seed=2)
    tight = SafetyLimits(max_roll=math.radians(0.2))
    campaign, outcome, restore = run_campaign(link, limits=tight)
    assert outcome.status == "aborted" and "roll" in outcome.reason
    _assert_restored(link, restore)


def test_depth_limit_aborts():
    link = InProcessLink(seed=2)
    campaign, outcome, restore = run_campaign(link, limits=SafetyLimits(max_depth=1.0))
    assert outcome.status == "aborted" and "depth" in outcome.reason
    _assert_restored(link, restore)


def test_nan_telemetry_aborts_after_a_bounded_number_of_samples():
    link = InProcessLink(seed=2, nan_from_s=20.0)
    campaign, outcome, restore = run_campaign(link)
    assert outcome.status == "aborted" and "no valid attitude" in outcome.reason
    _assert_restored(link, restore)


def test_refused_gain_write_aborts_and_restores():
    link = InProcessLink(seed=2, refuse={"HDG_P"})
    config = replace(FAST, thrusts=(0.8,), step_labels=("scheduled",))  # the step check writes HDG_P
    campaign, outcome, restore = run_campaign(link, config)
    assert outcome.status == "aborted" and "refused" in outcome.reason
    link.refuse.clear()
    _assert_restored(link, restore)


def test_rejected_validation_is_repeated_then_given_up():
    """An impossible threshold: every attempt is rejected, the manoeuvre gives up after max_attempts."""
    link = InProcessLink(seed=4)
    config = ManoeuvreConfig(settle_s=10.0, resettle_s=8.0, r2_threshold=1.0, max_attempts=2)
    manoeuvre = IdentificationManoeuvre(config, thrust=0.7)
    outcome = run_behavior(link, manoeuvre)
    result = manoeuvre.result()
    assert outcome.status == "failed" and "no model passed validation" in outcome.reason
    assert result.outcome == "rejected" and len(result.attempts) == 2
    assert not any(a.accepted for a in result.attempts)
    assert not link.overrides


def test_manoeuvre_overrides_only_during_the_doublets():
    link = InProcessLink(seed=4)
    manoeuvre = IdentificationManoeuvre(ManoeuvreConfig(settle_s=5.0, resettle_s=5.0), thrust=0.7)
    overridden_at = []
    while not manoeuvre.done:
        telemetry = link.next_telemetry()
        commands = manoeuvre.step(telemetry)
        link.execute(commands)
        if any(isinstance(c, OverrideActuator) for c in commands):
            overridden_at.append(telemetry.time_s)
    assert not link.overrides
    # two doublets of 4 s (training, validation), each overriding for 4 s at 20 Hz
    assert 150 <= len(overridden_at) <= 170
    assert manoeuvre.result().outcome == "accepted"


def test_pitch_axis_identifies_a_stable_model():
    link = InProcessLink(seed=4)
    manoeuvre = IdentificationManoeuvre(ManoeuvreConfig(axis="pitch", settle_s=15.0, resettle_s=10.0,
                                                        training_amplitude=0.1, validation_amplitude=0.06),
                                        thrust=0.7)
    run_behavior(link, manoeuvre)
    best = manoeuvre.result().best
    assert best is not None and best.r2 > 0.6
    model = best.model
    assert model.c22 > 0 and model.c23 > 0  # damped, statically stable pitch
    assert model.d2 < 0  # elevator sign of the sim: positive elevator pitches down


def test_new_trim_is_not_counted_twice_by_a_charged_integrator():
    """The autopilot's integrator has learned the rudder offset under its original gains; writing the
    identified δ0 as trim must re-engage the hold (integrator reset), or the heading is biased ~1°
    and the +20° and −20° steps come out asymmetric (9 % vs 0 % measured before the fix)."""
    from behaviors.heading_steps import HeadingStepTest
    from behaviors.observe import Observe
    from behaviors.sequence import SequenceBehavior

    link = InProcessLink(seed=1)
    gains = {"heading_p": 0.547, "heading_i": 0.0, "rudder_trim": 0.01}  # P only: 4.3 % by design
    steps = HeadingStepTest(0.8, gains, label="P")
    run_behavior(link, SequenceBehavior([Observe(30.0), steps]))
    up, down = (step.figures.overshoot_pct for step in steps.result().steps)
    assert abs(up - down) < 1.5, (up, down)
    assert up < 5.5 and down < 5.5
    assert "guided" in link.mode_changes and link.mode == "hold"


def test_without_step_checks_no_gain_is_written(completed):
    """Nothing unverified is left on a vehicle: a campaign whose gains were not checked writes none."""
    link = InProcessLink(seed=2)
    campaign, outcome, restore = run_campaign(link, replace(FAST, thrusts=(0.8,), step_labels=()))
    assert outcome.status == "completed" and campaign.final_gains is None
    assert "not verified" in campaign.verification
    _assert_restored(link, restore)


def test_gains_that_fail_their_check_are_reverted():
    """An impossible overshoot limit: the check fails, the campaign fails, the original gains stay."""
    from companion.procedures.campaign import GainCheck

    link = InProcessLink(seed=2)
    config = replace(FAST, thrusts=(0.8,), verify=GainCheck(max_overshoot_pct=0.0))
    campaign, outcome, restore = run_campaign(link, config)
    assert outcome.status == "failed" and "gains rejected" in outcome.reason and "overshoot" in outcome.reason
    assert campaign.final_gains is None
    _assert_restored(link, restore)


def test_a_campaign_whose_every_estimate_is_unstable_says_so_and_what_to_change():
    """ArduPilot's own motorboat yaws within two telemetry samples at 3-5 m/s: its estimates came out
    with a22 > 0 and b2 < 0, and the campaign said only "no model passed validation"."""
    from behaviors.identification import IdentificationAttempt
    from companion.numerics.identification import YawEstimate
    from companion.procedures.campaign import unstable_estimates

    def attempt(a22: float, b2: float) -> IdentificationAttempt:
        return IdentificationAttempt(attempt=1, axis="yaw", thrust=0.6, speed=3.0, model=YawEstimate(a22, b2, 0.0),
                                     r2=-1e9, accepted=False, converged=True, converged_s=8.0,
                                     criterion_met_from_s=None, training_s=12.0, samples=300)

    reason = unstable_estimates([attempt(15.4, -100.8), attempt(-0.0, 40.0), attempt(7.3, -49.3)])
    assert "unstable or inverted" in reason and "one every 0.040 s" in reason and "lower --thrusts" in reason
    assert unstable_estimates([attempt(15.4, -100.8), attempt(-11.3, 126.6)]) == ""  # one physical estimate
    assert unstable_estimates([]) == ""
