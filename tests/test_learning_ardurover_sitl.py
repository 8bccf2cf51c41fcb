"""``companion run --learn`` beside the real ArduRover firmware flying an ordinary survey in AUTO:
ArduPilot SITL flies our first-order boat through its JSON backend on the frame's shipped steering
gains, a ground station of its own (SITL's serial1) uploads a lawnmower with the MAVLink mission
protocol and switches to AUTO, and the companion on serial0 only learns, writes and verifies.

Skipped unless ``ARDUPILOT_SITL_BIN`` names the folder with the ``ardurover`` SITL binary. One
survey at 10× speed-up (about 70 s of wall time).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from companion.rehearsal.launcher import SimulatorProcess
from companion.records.store import Store
from harness.rover_mission import ROVER_AUTO, MissionGroundStation, fly_survey_beside, lawnmower
from tests.sitl_limits import SITL_UNDER_LOAD

BIN = os.environ.get("ARDUPILOT_SITL_BIN")
pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.xdist_group("sitl"), SITL_UNDER_LOAD, pytest.mark.skipif(
    not (BIN and (Path(BIN) / "ardurover").is_file()),
    reason="ARDUPILOT_SITL_BIN is not set to a folder with ArduPilot's ardurover SITL binary")]

SPEEDUP = 10.0


def test_learning_in_auto_stops_the_weave_and_keeps_verified_gains(tmp_path):
    store_path = tmp_path / "store.sqlite"
    with SimulatorProcess("boat", SPEEDUP, 1, (0.0, 0.0), autopilot="ardurover", ardupilot_bin=BIN, lockstep=False,
                          ready_timeout_s=120.0) as sim:
        station = MissionGroundStation(f"tcp:127.0.0.1:{sim.port + 2}", lawnmower(),
                                       {"WP_SPEED": 2.0, "GCS_PID_MASK": 1})
        run = fly_survey_beside([sys.executable, "-m", "companion", "run", "--connect", sim.endpoint, "--learn",
                                 "--no-health", "--store", str(store_path), "--max-vehicle-time", "1500"],
                                station, 3000.0 / SPEEDUP)
    assert run.returncode == 0, run.output[-2000:]
    assert run.finished, "the survey did not finish"
    assert [mode for _, mode in station.track.modes] == [ROVER_AUTO]  # never left AUTO
    with Store(store_path) as store:
        (campaign,) = [c for c in store.campaigns() if c["kind"] == "learning"]
        (result,) = store.behavior_results(campaign["id"], "learning")
    learned = result["result"]
    assert learned["phase"] == "kept" and campaign["status"] == "completed", campaign["reason"]
    assert learned["verdict"]["metric"] == "turn-rate error deg/s"
    written_at = next(w["time_s"] for w in learned["writes"] if w["why"] == "design")
    lanes = station.track.legs()
    weaving = [lane["cross_track_rms_m"] for lane in lanes if lane["waypoint"] > 2 and lane["end_s"] < written_at]
    calm = [lane["cross_track_rms_m"] for lane in lanes if lane["start_s"] > written_at]
    assert weaving and calm
    assert max(calm) < 0.3 * min(weaving)  # the lanes after the write, against the lanes before it
