"""Identification from an ArduPilot DataFlash log recorded by the real firmware: ArduRover
SITL flies our boat physics through ordinary course changes at three speeds (no doublet) and writes
its own .bin; ``identify --log`` must give yaw models within 5 % of the physics' linearised truth.

Skipped unless ``ARDUPILOT_SITL_BIN`` names the folder with the ``ardurover`` SITL binary (run it
without a network: ``unshare -n bash -c 'ip link set lo up; pytest tests/test_log_identification_sitl.py'``).
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.sitl_limits import SITL_UNDER_LOAD

BIN = os.environ.get("ARDUPILOT_SITL_BIN")
pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("sitl"), SITL_UNDER_LOAD, pytest.mark.skipif(
    not (BIN and (Path(BIN) / "ardurover").is_file()),
    reason="ARDUPILOT_SITL_BIN is not set to a folder with ArduPilot's ardurover SITL binary")]


def test_ardurover_bin_gives_the_boat_models(tmp_path):
    from companion.link.profiles import ARDUROVER
    from companion.procedures.log_identification import identify_log
    from companion.records.flight_logs import read_steering_log
    from harness.record_sitl_bin import record_sitl_bin
    from sim.linearize import linearized_yaw
    from sim.preset import load_preset

    path = record_sitl_bin(tmp_path / "rover.bin", bin_dir=BIN, speedup=10.0)
    record = read_steering_log(str(path), ARDUROVER)
    assert record.kind == "bin" and "SERVO1 GroundSteering" in record.rudder_source
    result = identify_log(record, profile=ARDUROVER)
    preset = load_preset("boat")
    speeds = set()
    for attempt in result.accepted:
        truth = linearized_yaw(preset, attempt.speed)  # the EKF's ground speed stands in for the water speed
        assert attempt.model.a22 == pytest.approx(truth["a22"], rel=0.05)
        assert attempt.model.b2 == pytest.approx(truth["b2"], rel=0.05)
        speeds.add(round(attempt.speed, 1))
    assert len(speeds) >= 2 and result.status == "completed", result.reason
