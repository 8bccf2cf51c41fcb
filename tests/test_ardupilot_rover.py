"""The product against the real ArduRover firmware: ArduPilot SITL built from ArduPilot's
sources flies our boat physics through its JSON backend; the companion talks MAVLink to the
firmware on loopback exactly as it would to a boat.

Skipped unless ``ARDUPILOT_SITL_BIN`` names the folder with the ``ardurover`` SITL binary (this
project never ships or builds ArduPilot). Each test is one short campaign at 20× speed-up.
"""
from __future__ import annotations

import math
import os
import signal
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from tests.sitl_limits import SITL_UNDER_LOAD

from behaviors.identification import ManoeuvreConfig
from companion.rehearsal.launcher import SimulatorProcess
from companion.rehearsal.rehearsal import arm_when_ready, preset_vehicle, simulator_truth, true_speed
from companion.procedures.app import AbortFlag, run_campaign
from companion.procedures.campaign import CampaignConfig
from companion.records.store import Store
from harness.ardupilot import assert_as_found, found_state, sitl_pid

BIN = os.environ.get("ARDUPILOT_SITL_BIN")
pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("sitl"), SITL_UNDER_LOAD, pytest.mark.skipif(
    not (BIN and (Path(BIN) / "ardurover").is_file()),
    reason="ARDUPILOT_SITL_BIN is not set to a folder with ArduPilot's ardurover SITL binary")]

#: one thrust, short settles: the abort tests only need the campaign to be under way
SHORT = CampaignConfig(thrusts=(0.8,), axes=("yaw",), step_labels=("scheduled",),
                       yaw=ManoeuvreConfig(settle_s=20.0, resettle_s=10.0))


@pytest.fixture(scope="module")
def truth_log(tmp_path_factory):
    return tmp_path_factory.mktemp("rover") / "truth.csv"


@pytest.fixture(scope="module")
def rover(truth_log):
    """ArduRover SITL + boat physics, connected and armed (shared by the tests, each leaves it as found)."""
    from companion.link.vehicle import VehicleLink

    with SimulatorProcess("boat", 20.0, 1, (0.0, 0.0), autopilot="ardurover", ardupilot_bin=BIN, lockstep=False,
                          ready_timeout_s=120.0, extra_args=["--truth-log", str(truth_log)]) as sim:
        link = VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=60.0, vehicle=preset_vehicle("boat"))
        try:
            arm_when_ready(link, patience_s=120.0)
            yield sim, link
        finally:
            link.close()


def test_campaign_identifies_designs_verifies_and_keeps_native_gains(rover, truth_log, tmp_path):
    _sim, link = rover
    found = found_state(link)
    with Store(tmp_path / "s.sqlite") as store:
        config = replace(CampaignConfig(), thrusts=(0.6, 0.8, 1.0), axes=("yaw",))
        campaign, outcome, _ = run_campaign(link, store, config, vehicle_id=store.add_vehicle("rover"),
                                            abort=AbortFlag())
    assert outcome.status == "completed", outcome.reason
    yaw = [a for a in campaign.accepted if a.axis == "yaw"]
    assert len({round(a.speed, 1) for a in yaw}) >= 3
    for attempt in yaw:
        speed = true_speed(truth_log, attempt)  # the physics' own speed: the EKF's reads 0.02 m/s low
        assert speed == pytest.approx(attempt.speed, abs=0.05)
        truth = simulator_truth("boat", speed)
        assert attempt.r2 >= 0.9
        assert attempt.model.a22 == pytest.approx(truth["a22"], rel=0.05)
        assert attempt.model.b2 == pytest.approx(truth["b2"], rel=0.05)
    steps = {(s.thrust, s.label): s for s in campaign.step_results}
    for thrust in (0.6, 0.8, 1.0):
        scheduled, original = steps[(thrust, "scheduled")], steps[(thrust, "original")]
        assert scheduled.max_overshoot_pct <= 10.0 and scheduled.oscillations <= 1
        assert scheduled.iae_s < original.iae_s  # better than ArduRover's boat defaults
    # the verified gains stay on the vehicle, every one inside ArduPilot's documented range
    kept = link.get_params(campaign.final_gains)
    assert kept == pytest.approx(campaign.final_gains, rel=1e-6)
    assert 1.0 <= kept["heading_angle_p"] <= 10.0 and 0.0 <= kept["heading_rate_ff"] <= 3.0
    assert 0.0 <= kept["heading_rate_p"] <= 2.0 and 0.0 <= kept["heading_rate_i"] <= 2.0
    assert link.mode == found[1] and not link.overrides.active
    link.set_params({k: v for k, v in found[0].items() if k in kept})  # back to the defaults for the next tests


def _campaign_with(link, abort, tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        return run_campaign(link, store, SHORT, vehicle_id=store.add_vehicle("rover"), abort=abort)


def test_ctrl_c_during_the_doublet_leaves_the_boat_as_found(rover, tmp_path):
    _sim, link = rover
    found = found_state(link)
    start = link.vehicle_time_s

    def ctrl_c():  # what the signal handler does, at 23 s: inside the MANUAL excitation
        return "signal SIGINT" if link.vehicle_time_s - start > 23.0 else None

    _, outcome, _ = _campaign_with(link, ctrl_c, tmp_path)
    assert outcome.status == "aborted" and outcome.reason == "signal SIGINT"
    assert outcome.restore_problems == []
    assert_as_found(link, found)


def test_a_pilot_mode_change_aborts_and_the_companion_does_not_fight_back(rover, tmp_path):
    _sim, link = rover
    found = found_state(link)
    start = link.vehicle_time_s
    state = {"done": False}

    def pilot():  # the pilot selects ACRO (another MAVLink client would; here the same link, by number)
        if not state["done"] and link.vehicle_time_s - start > 12.0:
            state["done"] = True
            link.commands.send(176, (1, 1))  # MAV_CMD_DO_SET_MODE custom 1 = ACRO, not via set_mode
        return None

    _, outcome, _ = _campaign_with(link, pilot, tmp_path)
    assert outcome.status == "aborted" and "by someone else" in outcome.reason
    assert_as_found(link, found, mode=False)
    assert link.mode == "acro"  # the pilot's choice stands
    link.set_mode(found[1])


def test_link_loss_aborts_and_the_restore_completes_when_the_link_returns(rover, tmp_path):
    sim, link = rover
    found = found_state(link)
    pid = sitl_pid(sim, "ardurover")
    start = link.vehicle_time_s
    state = {"stopped": False}

    def freeze():  # SITL stops answering for 6 s of wall clock: longer than the 5 s link watchdog
        if not state["stopped"] and link.vehicle_time_s - start > 22.0:
            state["stopped"] = True
            os.kill(pid, signal.SIGSTOP)
            threading.Timer(6.5, os.kill, (pid, signal.SIGCONT)).start()
        return None

    _, outcome, _ = _campaign_with(link, freeze, tmp_path)
    assert outcome.status == "aborted" and "LinkLost" in outcome.reason
    time.sleep(1.0)  # let the last timer fire before the next test
    assert_as_found(link, found)


def test_rehearse_exits_zero_only_with_verified_gains_and_reports_math_free_json(tmp_path):
    """The command a user runs: JSON on stdout is one strict object, exit 0 means completed."""
    import json
    import subprocess
    import sys

    out = tmp_path / "r"
    done = subprocess.run([sys.executable, "-m", "companion", "rehearse", "--autopilot", "ardurover", "--ardupilot-bin",
                           BIN, "--speedup", "20", "--thrusts", "0.8", "--out", str(out), "--json"],
                          capture_output=True, text=True, timeout=600)
    summary = json.loads(done.stdout, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    assert (done.returncode == 0) == (summary["status"] == "completed" and summary["final_gains"] is not None)
    assert all(math.isfinite(r["r2"]) for r in summary["runs"])


def test_steady_state_squares_and_turns_against_the_connected_firmware(tmp_path):
    """``companion run-behavior steady-state --connect`` on ArduRover: the turns (rudder and
    throttle held in MANUAL) find a known current; the squares fly GUIDED, whose speed loop holds the
    speed over ground, so their current estimate is only reported (README: a known limitation)."""
    import json
    import subprocess
    import sys

    from companion.link.vehicle import VehicleLink

    current = (0.03, -0.025)  # 39 mm/s towards 320°
    with SimulatorProcess("boat", 20.0, 2, current, autopilot="ardurover", ardupilot_bin=BIN, lockstep=False,
                          ready_timeout_s=120.0) as sim:
        link = VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=60.0, vehicle=preset_vehicle("boat"))
        try:
            arm_when_ready(link, patience_s=120.0)  # a user arms the boat; the procedure never does
            found = found_state(link)
        finally:
            link.close()
        done = subprocess.run([sys.executable, "-m", "companion", "run-behavior", "steady-state", "--connect",
                               sim.endpoint, "--profile", "ardurover", "--rudder-rate", "5", "--duration", "60",
                               "--thrust", "0.6", "--store", str(tmp_path / "s.sqlite"), "--json"],
                              capture_output=True, text=True, timeout=300, check=False)
        assert done.stdout.strip(), done.stderr[-2000:]
        summary = json.loads(done.stdout)
        assert done.returncode == 0 and summary["status"] == "completed", done.stderr[-2000:]
        assert len(summary["turns"]) == 2
        for turn in summary["turns"]:
            assert abs(turn["rudder_deg"]) == pytest.approx(12.5, abs=0.2)
            assert 5.0 < turn["radius_m"] < 20.0
            assert math.hypot(turn["current_speed"] * math.cos(math.radians(turn["current_dir_deg"])) - current[0],
                              turn["current_speed"] * math.sin(math.radians(turn["current_dir_deg"])) - current[1]) < 0.005
        assert summary["squares"]["surge_water"] == pytest.approx(1.5, abs=0.1)
        link = VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=60.0, vehicle=preset_vehicle("boat"))
        try:
            assert_as_found(link, found)
        finally:
            link.close()
