"""The product against the real ArduSub firmware: ArduPilot SITL built from ArduPilot's sources flies
our STARFISH physics through its JSON backend (vectored frame, thrusters un-mixed into an equivalent
rudder, thrust and a heave force); the companion talks MAVLink to the firmware on loopback.

Skipped unless ``ARDUPILOT_SITL_BIN`` names the folder with the ``ardusub`` SITL binary (this
project never ships or builds ArduPilot). One ``companion rehearse --autopilot ardusub`` at 20×
(about 900 s of vehicle time, 80 s of wall clock on two cores), checked against the done-when
figures: yaw identified at three speeds with validation R² ≥ 0.9, a22 and b2 within 5 % of the
simulator's linearised truth, and native gains written only after their heading steps overshoot
at most 10 % without oscillating and beat ArduSub's defaults. Then, on one armed sub, Ctrl-C in the
doublet, a pilot's mode change and a 6.5 s link loss each leave every gain, the overrides and the mode
as found (the pilot's mode stands).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.sitl_limits import SITL_UNDER_LOAD

from companion.records.store import Store
from harness.ardupilot import assert_as_found, found_state, sitl_pid

BIN = os.environ.get("ARDUPILOT_SITL_BIN")
pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("sitl"), SITL_UNDER_LOAD, pytest.mark.skipif(
    not (BIN and (Path(BIN) / "ardusub").is_file()),
    reason="ARDUPILOT_SITL_BIN is not set to a folder with ArduPilot's ardusub SITL binary")]


@pytest.fixture(scope="module")
def rehearsal(tmp_path_factory):
    out = tmp_path_factory.mktemp("ardusub")
    command = [sys.executable, "-m", "companion", "rehearse", "--autopilot", "ardusub", "--ardupilot-bin", BIN,
               "--speedup", "20", "--json", "--out", str(out)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=420, check=False)
    assert done.stdout, done.stderr[-3000:]
    return out, json.loads(done.stdout)


def test_yaw_identified_at_three_speeds_within_5_percent_of_the_truth(rehearsal):
    _, summary = rehearsal
    runs = summary["runs"]
    assert [run["thrust"] for run in runs] == [0.45, 0.55, 0.65]
    speeds = [run["speed"] for run in runs]
    assert speeds == sorted(speeds) and speeds[0] > 0.6 and speeds[-1] - speeds[0] > 0.4  # three distinct speeds
    for run in runs:
        assert run["r2"] >= 0.9, run
        assert run["a22"] == pytest.approx(run["true_a22"], rel=0.05), run
        assert run["b2"] == pytest.approx(run["true_b2"], rel=0.05), run


def test_native_gains_kept_after_the_verification_steps_pass(rehearsal):
    _, summary = rehearsal
    assert summary["status"] == "completed", summary.get("reason")
    assert summary["verification"] == "passed" and summary["checks"] == "verify"
    flown = summary["verified"]["flown"]
    # the design by prediction needs every speed's model: the schedule is flown at both ends
    assert {(s["thrust"], s["label"]) for s in flown} >= {(0.45, "scheduled"), (0.65, "scheduled")}
    assert summary["heading_design"]["chosen"] in ("optimised", "rule", "quicktune")
    for step in flown:
        assert step["decided"] and step["max_overshoot_pct"] <= 10.0 and step["oscillations"] <= 1
    predicted = {(s["thrust"], s["label"]): s for s in summary["verified"]["predicted"]}
    for thrust in (0.45, 0.55, 0.65):  # the schedule predicted better than the vehicle's own gains everywhere
        assert predicted[(thrust, "scheduled")]["iae_s"] < predicted[(thrust, "original")]["iae_s"]
    gains = summary["final_gains"]
    assert set(gains) == {"heading_angle_p", "heading_rate_p", "heading_rate_i", "heading_rate_ff"}
    assert gains["heading_rate_ff"] == 0.0  # ArduSub never applies ATC_RAT_YAW_FF


def test_the_store_holds_the_models_and_the_written_gains(rehearsal):
    _, summary = rehearsal
    with Store(summary["store"]) as store:
        campaign = store.campaigns()[0]
        assert campaign["status"] == "completed"
        assert len(store.models(campaign["id"], axis="yaw")) == 3
        assert store.gains(campaign["id"])


# ---------------------------------------------------------------------- aborts on the firmware
@pytest.fixture(scope="module")
def sub():
    """ArduSub SITL + STARFISH physics, connected, holding its depth and armed (shared by the abort
    tests below; each leaves it as found)."""
    from companion.rehearsal.launcher import SimulatorProcess
    from companion.rehearsal.rehearsal import ARDUSUB_SIM_ARGS, ARDUSUB_VEHICLE, arm_ardusub_when_ready
    from companion.link.vehicle import VehicleLink

    with SimulatorProcess("starfish", 20.0, 1, (0.0, 0.0), autopilot="ardusub", ardupilot_bin=BIN, lockstep=False,
                          ready_timeout_s=120.0, extra_args=list(ARDUSUB_SIM_ARGS)) as sim:
        link = VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=60.0, vehicle=ARDUSUB_VEHICLE)
        try:
            arm_ardusub_when_ready(link, patience_s=120.0)
            yield sim, link
        finally:
            link.close()


def _short_campaign(link, abort, tmp_path):
    from dataclasses import replace

    from behaviors.identification import ManoeuvreConfig
    from companion.procedures.app import run_campaign
    from companion.procedures.campaign import CampaignConfig

    config = CampaignConfig(step_labels=("scheduled",)).with_profile_defaults(link.profile)
    config = replace(config, thrusts=(0.55,), yaw=replace(config.yaw, settle_s=20.0, resettle_s=10.0))
    assert isinstance(config.yaw, ManoeuvreConfig)
    with Store(tmp_path / "s.sqlite") as store:
        return run_campaign(link, store, config, vehicle_id=store.add_vehicle("sub"), abort=abort)


def test_ardusub_ctrl_c_during_the_doublet_leaves_the_sub_as_found(sub, tmp_path):
    _sim, link = sub
    found = found_state(link)
    start = link.vehicle_time_s

    def ctrl_c():  # what the signal handler does, at 23 s: inside the MANUAL excitation
        return "signal SIGINT" if link.vehicle_time_s - start > 23.0 else None

    _, outcome, _ = _short_campaign(link, ctrl_c, tmp_path)
    assert outcome.status == "aborted" and outcome.reason == "signal SIGINT"
    assert outcome.restore_problems == []
    assert_as_found(link, found)


def test_ardusub_pilot_mode_change_aborts_and_the_pilots_mode_stands(sub, tmp_path):
    _sim, link = sub
    found = found_state(link)
    start = link.vehicle_time_s
    state = {"done": False}

    def pilot():  # the pilot selects STABILIZE (custom mode 0), not through the companion's set_mode
        if not state["done"] and link.vehicle_time_s - start > 12.0:
            state["done"] = True
            link.commands.send(176, (1, 0))
        return None

    _, outcome, _ = _short_campaign(link, pilot, tmp_path)
    assert outcome.status == "aborted" and "by someone else" in outcome.reason
    assert_as_found(link, found, mode=False)
    assert link.mode == "stabilize"  # the pilot's choice stands
    link.set_mode(found[1])


def test_ardusub_link_loss_aborts_and_the_restore_completes_when_the_link_returns(sub, tmp_path):
    import signal
    import threading
    import time

    sim, link = sub
    found = found_state(link)
    pid = sitl_pid(sim, "ardusub")
    start = link.vehicle_time_s
    state = {"stopped": False}

    def freeze():  # SITL stops answering for 6.5 s of wall clock: longer than the 5 s link watchdog
        if not state["stopped"] and link.vehicle_time_s - start > 22.0:
            state["stopped"] = True
            os.kill(pid, signal.SIGSTOP)
            threading.Timer(6.5, os.kill, (pid, signal.SIGCONT)).start()
        return None

    _, outcome, _ = _short_campaign(link, freeze, tmp_path)
    assert outcome.status == "aborted" and "LinkLost" in outcome.reason
    time.sleep(1.0)
    assert_as_found(link, found)
    assert link.armed, "the sub must still be armed (its failsafes did not fire)"

