"""Boats as people own them, on the real ArduRover firmware: our 3-DOF hull (not first order) with a
stern rudder and with twin thrusters (skid steering: SERVO1/3_FUNCTION 73/74), behind ArduPilot SITL's
JSON backend. The companion reads the actuation at connect, identifies, designs the heading gains
with the speed law the actuation and the models support, verifies them by steps and keeps them; the
speed loop's design from the settles is scored against the speed estimate's drift and, on these
hulls, keeps the vehicle's own speed gains; an abort of a skid boat's campaign leaves it as found.

Skipped unless ``ARDUPILOT_SITL_BIN`` names the folder with the ``ardurover`` SITL binary. Each
campaign takes about a minute and a half of wall time at 20x.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.sitl_limits import SITL_UNDER_LOAD

from companion.procedures.app import AbortFlag, run_campaign
from companion.procedures.campaign import CampaignConfig
from companion.records.store import Store
from companion.rehearsal.launcher import SimulatorProcess
from companion.rehearsal.rehearsal import arm_when_ready, preset_vehicle, simulator_truth, training_doublet, true_speed
from harness.ardupilot import HEADING_GAINS, assert_as_found, found_state

BIN = os.environ.get("ARDUPILOT_SITL_BIN")
pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("sitl"), SITL_UNDER_LOAD, pytest.mark.skipif(
    not (BIN and (Path(BIN) / "ardurover").is_file()),
    reason="ARDUPILOT_SITL_BIN is not set to a folder with ArduPilot's ardurover SITL binary")]

SPEED_GAINS = ("cruise_speed", "cruise_thrust", "speed_p", "speed_i")


@pytest.fixture(params=["boat-skid", "boat-3dof"])
def boat(request, tmp_path):
    """ArduRover SITL flying one of our 3-DOF boats, connected and armed (a user arms it)."""
    from companion.link.vehicle import VehicleLink

    truth = tmp_path / "truth.csv"
    with SimulatorProcess(request.param, 20.0, 1, (0.0, 0.0), autopilot="ardurover", ardupilot_bin=BIN,
                          lockstep=False, ready_timeout_s=120.0, extra_args=["--truth-log", str(truth)]) as sim:
        link = VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=60.0, vehicle=preset_vehicle(request.param))
        try:
            arm_when_ready(link, patience_s=120.0)
            yield request.param, link, truth
        finally:
            link.close()


def test_a_3dof_boat_is_identified_tuned_verified_and_keeps_its_gains(boat, tmp_path):
    preset, link, truth_log = boat
    skid = preset == "boat-skid"
    actuation = link.profile.actuation
    assert actuation.kind == ("skid" if skid else "steering")
    assert actuation.outputs() == ({"left": 1, "right": 3} if skid else {"steering": 1, "throttle": 3})
    found = found_state(link, HEADING_GAINS + SPEED_GAINS)
    with Store(tmp_path / "s.sqlite") as store:
        campaign, outcome, _ = run_campaign(link, store, CampaignConfig(axes=("yaw",)),
                                            vehicle_id=store.add_vehicle(preset), abort=AbortFlag())
    assert outcome.status == "completed", outcome.reason
    # the speed law: the actuation's (three speeds cannot overrule it), and the models' residuals agree
    schedule = campaign.heading_design.schedule
    assert schedule.b2_law == ("u" if skid else "u2") and "the models agree" in schedule.b2_law_reason
    errors = []
    for attempt in campaign.accepted:
        speed = true_speed(truth_log, attempt)
        truth = simulator_truth(preset, speed, training_doublet(attempt, campaign.config.yaw))
        # skid: the stated truth (eq. S.6); rudder: the nonlinear hull's fit at the flown amplitude, which the
        # stated truth misses by 10-28 % on this hull (docs/limitations.md: the goal of 5 % is not met)
        reference = ("a22", "b2") if skid else ("a22_amplitude", "b2_amplitude")
        errors.append((attempt.model.a22 / truth[reference[0]] - 1.0, attempt.model.b2 / truth[reference[1]] - 1.0))
        assert attempt.r2 >= 0.9
    assert len(errors) == 3
    # measured over 9 models each (bench_ardupilot.py): skid worst 7.7 % (a22) and 7.4 % (b2); rudder against
    # the amplitude fit worst 10 % (a22) and 5 % (b2); a regression guard, not the goal
    assert all(abs(a) <= 0.12 and abs(b) <= 0.10 for a, b in errors), errors
    # heading steps: the design overshoots at most 10 % and settles in less step error than the defaults
    # at every speed; than QuickTune's rule too on the skid boat (the rudder boat's design is not better
    # than QuickTune's at 2.0 and 2.5 m/s: docs/limitations.md)
    steps = {(s.thrust, s.label): s for s in campaign.step_results}
    for thrust in campaign.config.thrusts:
        scheduled = steps[(thrust, "scheduled")]
        assert scheduled.max_overshoot_pct <= 10.0 and scheduled.oscillations <= 1
        assert scheduled.iae_s < steps[(thrust, "original")].iae_s
        if skid:
            assert scheduled.iae_s < steps[(thrust, "quicktune")].iae_s
    # the speed loop: the surge model from the settles; on these hulls (a surge lag of 0.4 s) no design
    # within 5 % overshoot removes the speed estimate's drift within a step (eq. S.5r), so the vehicle's
    # own speed gains stay: nothing flown, nothing written, the loop says why
    speed = campaign.speed
    assert speed.surge.r2 > 0.95
    assert speed.keeps_original and speed.kept is None and not speed.step_results, speed.verdict
    assert campaign.loop_outcomes()["speed"].outcome == "original kept"
    assert "no speed design is predicted better" in campaign.loop_outcomes()["speed"].why
    kept = link.get_params(campaign.final_gains)
    assert kept == pytest.approx(campaign.final_gains, rel=1e-5)
    assert not set(SPEED_GAINS) & set(kept)
    assert link.get_params(SPEED_GAINS) == pytest.approx({k: found[0][k] for k in SPEED_GAINS}, rel=1e-5)
    assert link.mode == found[1] and not link.overrides.active
    link.set_params({k: v for k, v in found[0].items() if k in kept})  # the defaults back for the next test


def test_an_abort_of_a_skid_boats_doublet_leaves_it_as_found(boat, tmp_path):
    preset, link, _ = boat
    if preset != "boat-skid":
        pytest.skip("the abort is the skid boat's: the rudder boat's is tests/test_ardupilot_rover.py's")
    found = found_state(link, HEADING_GAINS + SPEED_GAINS)
    start = link.vehicle_time_s

    def ctrl_c():  # 40 s in: settling from rest, or in the first record (MANUAL, overrides held)
        return "signal SIGINT" if link.vehicle_time_s - start > 40.0 else None

    with Store(tmp_path / "s.sqlite") as store:
        _, outcome, _ = run_campaign(link, store, CampaignConfig(axes=("yaw",), thrusts=(0.6,), user_set=("thrusts",)),
                                     vehicle_id=store.add_vehicle(preset), abort=ctrl_c)
    assert outcome.status == "aborted" and outcome.restore_problems == []
    assert_as_found(link, found)
