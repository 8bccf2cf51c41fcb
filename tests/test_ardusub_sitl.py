"""The product against the real ArduSub firmware: ArduPilot SITL built from ArduPilot's sources flies
our STARFISH physics through its JSON backend (vectored frame, thrusters un-mixed into an equivalent
rudder, thrust and a heave force); the companion talks MAVLink to the firmware on loopback.

Skipped unless ``ARDUPILOT_SITL_BIN`` names the folder with the ``ardusub`` SITL binary (this
project never ships or builds ArduPilot). One ``companion rehearse --autopilot ardusub`` at 20×
(about 900 s of vehicle time, 80 s of wall clock on two cores), checked against the done-when
figures: yaw identified at three speeds with validation R² ≥ 0.9, a22 and b2 within 5 % of the
simulator's linearised truth, and native gains written only after their heading steps overshoot
at most 10 % without oscillating and beat ArduSub's defaults.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from companion.records.store import Store

BIN = os.environ.get("ARDUPILOT_SITL_BIN")
pytestmark = [pytest.mark.e2e, pytest.mark.skipif(
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


def test_native_gains_kept_after_heading_steps_pass_the_check(rehearsal):
    _, summary = rehearsal
    assert summary["status"] == "completed", summary.get("reason")
    assert summary["verification"] == "passed"
    steps = {(s["thrust"], s["label"]): s for s in summary["heading_steps"]}
    for thrust in (0.45, 0.55, 0.65):
        scheduled, original = steps[(thrust, "scheduled")], steps[(thrust, "original")]
        assert scheduled["max_overshoot_pct"] <= 10.0 and scheduled["oscillations"] <= 1
        assert scheduled["iae_s"] < original["iae_s"]
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
