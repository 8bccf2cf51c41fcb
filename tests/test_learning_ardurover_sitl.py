"""``companion run --learn`` beside the real ArduRover firmware flying an ordinary survey in AUTO:
a ground station of its own (SITL's serial1) uploads a lawnmower with the MAVLink mission protocol
and switches to AUTO, and the companion on serial0 only learns, writes and verifies (the heading
gains from the survey's turns; on our boat the speed loop's from its speed changes too, eq. L.4). Two boats:
our first-order boat through SITL's JSON backend on the frame's shipped steering gains, and SITL's
own ``motorboat`` (physics this project did not write, ``harness.own_sitl``) tuned poorly by its
user.

Skipped unless ``ARDUPILOT_SITL_BIN`` names the folder with the ``ardurover`` SITL binary. Each
survey at 10× speed-up (about 70 s of wall time).
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from companion.rehearsal.launcher import SimulatorProcess
from harness.mavlink_clients import read_parameters
from harness.own_sitl import MOTORBOAT, OwnSitl
from harness.rover_mission import ROVER, ROVER_AUTO, MissionGroundStation, lawnmower
from tests.learning_rig import SPEEDUP, learn_beside, learning_record
from tests.sitl_limits import SITL_UNDER_LOAD

BIN = os.environ.get("ARDUPILOT_SITL_BIN")
pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.xdist_group("sitl"), SITL_UNDER_LOAD, pytest.mark.skipif(
    not (BIN and (Path(BIN) / "ardurover").is_file()),
    reason="ARDUPILOT_SITL_BIN is not set to a folder with ArduPilot's ardurover SITL binary")]


def test_learning_in_auto_stops_the_weave_and_keeps_verified_gains(tmp_path):
    store_path = tmp_path / "store.sqlite"
    with SimulatorProcess("boat", SPEEDUP, 1, (0.0, 0.0), autopilot="ardurover", ardupilot_bin=BIN, lockstep=False,
                          ready_timeout_s=120.0) as sim:
        station = MissionGroundStation(f"tcp:127.0.0.1:{sim.port + 2}", lawnmower(),
                                       {"WP_SPEED": 2.0, "GCS_PID_MASK": 3})  # steering and speed loops
        run = learn_beside(sim.endpoint, station, store_path)
    assert run.returncode == 0, run.output[-2000:]
    assert run.finished, "the survey did not finish"
    assert [mode for _, mode in station.track.modes] == [ROVER_AUTO]  # never left AUTO
    campaign, learned, _ = learning_record(store_path)
    assert learned["phase"] == "kept" and campaign["status"] == "completed", campaign["reason"]
    assert learned["verdict"]["metric"] == "turn-rate error deg/s"
    written_at = next(w["time_s"] for w in learned["writes"] if w["why"] == "design")
    lanes = station.track.legs()
    weaving = [lane["cross_track_rms_m"] for lane in lanes if lane["waypoint"] > 2 and lane["end_s"] < written_at]
    calm = [lane["cross_track_rms_m"] for lane in lanes if lane["start_s"] > written_at]
    assert weaving and calm
    assert max(calm) < 0.3 * min(weaving)  # the lanes after the write, against the lanes before it
    # the speed loop learned from the survey's speed changes (eq. L.4): written on a straight, verified
    # by the corners flown on it against the original gains replayed on the same asked-for speeds
    speed = learned["speed"]
    assert speed["phase"] == "kept", speed["reason"]
    (write,) = speed["writes"]
    assert write["loop"] == "speed" and set(write["gains"]) == {"cruise_speed", "cruise_thrust", "speed_p", "speed_i"}
    assert speed["verdict"]["metric"] == "speed error m/s"
    assert speed["verdict"]["after_error"] < speed["verdict"]["before_error"]


#: SITL's motorboat as a user who copied another boat's steering gains finds it: a third of the
#: feed-forward its rudder needs, weak P and I (the learned feed-forward is 0.73–0.86)
POORLY_TUNED = {"ATC_STR_RAT_FF": 0.3, "ATC_STR_RAT_P": 0.05, "ATC_STR_RAT_I": 0.02}
NATIVE = {"heading_rate_ff": "ATC_STR_RAT_FF", "heading_rate_p": "ATC_STR_RAT_P", "heading_rate_i": "ATC_STR_RAT_I",
          "heading_angle_p": "ATC_STR_ANG_P"}


def test_learning_on_sitls_own_motorboat_tuned_poorly_keeps_gains_that_hold_the_lanes(tmp_path):
    """Physics we did not write: SITL's motorboat, whose yaw rate follows the rudder with no lag of
    its own. The learned gains are verified on the turns, hold the lanes closer than the poor gains
    did before the write, and are what the vehicle holds once the companion has ended."""
    store_path = tmp_path / "store.sqlite"
    with OwnSitl(BIN, MOTORBOAT, SPEEDUP, params=POORLY_TUNED, workdir=tmp_path / "sitl") as sitl:
        sitl.wait_listening()
        station = MissionGroundStation(sitl.station_endpoint, lawnmower(),
                                       {"WP_SPEED": 2.0, "GCS_PID_MASK": float(ROVER.pid_mask)})
        run = learn_beside(sitl.endpoint, station, store_path)
        on_vehicle = read_parameters(sitl.endpoint, list(NATIVE.values()))  # after the companion's end
    assert run.returncode == 0, run.output[-2000:]
    assert run.finished, "the survey did not finish"
    assert [mode for _, mode in station.track.modes] == [ROVER_AUTO]  # never left AUTO
    campaign, learned, _ = learning_record(store_path)
    assert campaign["config"]["original"]["heading_rate_ff"] == pytest.approx(0.3)  # the user's gains were read
    assert learned["phase"] == "kept" and campaign["status"] == "completed", campaign["reason"]
    written = next(w for w in learned["writes"] if w["why"] == "design")
    lanes = station.track.legs()
    before = [lane["cross_track_rms_m"] for lane in lanes if lane["waypoint"] > 2 and lane["end_s"] < written["time_s"]]
    after = [lane["cross_track_rms_m"] for lane in lanes if lane["start_s"] > written["time_s"]]
    assert before and after
    assert max(after) < 0.4 * min(before), (before, after)  # measured: 0.11 against 0.67 m (bench)
    for neutral, native in NATIVE.items():  # the vehicle holds the verified gains
        assert on_vehicle[native] == pytest.approx(written["gains"][neutral], rel=1e-4, abs=1e-6), native
