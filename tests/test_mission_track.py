"""The ground station's record of a survey (harness.rover_mission.MissionTrack): lanes and the
lane-end corners between them, the figures the learning benches compare."""
from __future__ import annotations

import math

import pytest

from harness.rover_mission import MissionTrack


def _track() -> MissionTrack:
    """Waypoints 2 (a lane, 0–60 s), 3 (a crossing, 60–70 s), 4 (a lane, 70–130 s), 5 (130–140 s);
    the rate loop tracks within 0.5 deg/s on the lanes and misses by 3 deg/s in the corners."""
    track = MissionTrack(waypoints=[(0.0, 2), (60.0, 3), (70.0, 4), (130.0, 5)])
    for k in range(1400):
        t = 0.1 * k
        lane = 15.0 <= t <= 45.0 or 85.0 <= t <= 115.0
        track.turn_rates.append((t, 10.0, 10.0 - (0.5 if lane else 3.0)))
        track.cross_track.append((t, 0.2))
    return track


def test_lanes_are_their_middle_half():
    lanes = _track().legs()
    assert [lane["waypoint"] for lane in lanes] == [2, 4]
    assert all(lane["turn_rate_error_rms_deg_s"] == pytest.approx(0.5) for lane in lanes)
    assert all(lane["cross_track_rms_m"] == pytest.approx(0.2) for lane in lanes)


def test_a_corner_runs_from_a_lanes_middle_to_the_next_ones():
    (corner,) = _track().corners()
    assert corner["waypoint"] == 4
    assert (corner["start_s"], corner["end_s"]) == pytest.approx((45.0, 85.0))
    # 40 s: 0.5 deg/s at its two end samples, 3 deg/s in between
    assert 2.9 < corner["turn_rate_error_rms_deg_s"] < 3.0


def test_a_corner_without_turn_rates_has_no_figure():
    track = MissionTrack(waypoints=[(0.0, 2), (60.0, 3), (70.0, 4), (130.0, 5)])
    (corner,) = track.corners()
    assert math.isnan(corner["turn_rate_error_rms_deg_s"])
