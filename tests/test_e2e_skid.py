"""End to end on our own simulator, no SITL: ``companion rehearse --preset boat-skid`` flies the
twin-thruster boat, whose autopilot reports SERVO1/3_FUNCTION 73/74 and the two motors on outputs 1
and 3. The companion must read that at connect, un-mix the motors into the equivalent rudder and
throttle (eq. S.1), and identify the boat against its stated truth; read as a rudder on output 1,
the left motor gave δ0 0.30 rad and failed validation at four of five thrusts."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.e2e


def test_a_skid_boat_rehearses_with_its_motors_un_mixed(tmp_path):
    command = [sys.executable, "-m", "companion", "rehearse", "--preset", "boat-skid", "--out", str(tmp_path),
               "--thrusts", "0.6", "--axes", "yaw", "--no-steps", "--speedup", "200", "--seed", "3", "--no-report",
               "--json"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads(done.stdout)
    assert summary["status"] == "completed"
    [run] = summary["runs"]
    assert run["delta0"] == pytest.approx(run["true_delta0"], abs=0.003)  # the steering trim, not a motor's output
    assert run["b2"] == pytest.approx(run["true_b2"], rel=0.05)  # the doublet-equivalent truth (eq. S.6)
    # a22 lies between that truth and the nonlinear hull's fit at the flown amplitude (eq. S.6, nonlinear)
    assert run["a22"] == pytest.approx(run["true_a22_amplitude"], rel=0.06)
    assert run["r2"] >= 0.95
    schedule = summary["design"]["heading"]["schedule"]
    assert schedule["b2_law"] == "u" and "differential thrust" in schedule["b2_law_reason"]
