"""Our physics behind the real PX4 firmware: ``python -m sim run --autopilot px4-rover|px4-uuv``
starts PX4 SITL as the MAVLink HIL client of our boat/AUV, and a MAVLink client arms it in MANUAL,
streams MANUAL_CONTROL with a steering (rover) or yaw (UUV) input and sees the vehicle turn the
right way, in PX4's ATTITUDE and in the physics' own truth log.

Skipped unless ``PX4_SITL_BIN`` names a PX4 SITL build folder (``build/px4_sitl_default`` with
``bin/px4`` and ``etc/``; this project never ships or builds PX4).
"""
from __future__ import annotations

import csv
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.sitl_limits import SITL_UNDER_LOAD

from sim.px4_sitl import ENV_BIN

BIN = os.environ.get(ENV_BIN)
pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("sitl"), SITL_UNDER_LOAD, pytest.mark.skipif(
    not (BIN and ((Path(BIN) / "bin" / "px4").is_file() or (Path(BIN) / "px4").is_file())),
    reason=f"{ENV_BIN} is not set to a PX4 SITL build folder (with bin/px4)")]

MANUAL = 1 << 16  # PX4 custom_mode: main mode MANUAL in bits 16-23 (px4_custom_mode.h)
REPO = Path(__file__).resolve().parents[1]


class Px4Run:
    """``python -m sim run --autopilot …`` as a subprocess and a pymavlink client on its onboard link."""

    def __init__(self, autopilot: str, truth_log: Path, speedup: float = 5.0) -> None:
        os.environ.setdefault("MAVLINK20", "1")
        from pymavlink import mavutil

        self.mavutil = mavutil
        env = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "sim", "run", "--autopilot", autopilot, "--px4-bin", BIN, "--speedup", str(speedup),
             "--truth-log", str(truth_log)], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True)
        line = self.process.stdout.readline()
        if not line.startswith("READY udpin:"):
            self.close()
            pytest.fail(f"no READY line from the simulator: {line!r} {self.process.stderr.read()[-2000:]}")
        port = int(line.strip().rsplit(":", 1)[1])
        self.link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
        self.heartbeat()
        self.link.wait_heartbeat(timeout=30)
        self.target = self.link.target_system
        self.time_ms = 0
        self.last: dict = {}
        self.yaw_rates: list[tuple[float, float]] = []  # (vehicle s, ATTITUDE.yawspeed)

    def heartbeat(self) -> None:
        self.link.mav.heartbeat_send(6, 8, 0, 0, 0)  # GCS, autopilot invalid

    def fly(self, seconds: float, x: int = 0, y: int = 0, z: int = 500, r: int = 0, timeout_s: float = 120.0) -> None:
        """Stream MANUAL_CONTROL at 20 Hz of vehicle time (``z`` 500 = throttle 0) for ``seconds``."""
        end_ms = self.time_ms + seconds * 1000.0
        next_ms = 0.0
        deadline = time.monotonic() + timeout_s
        while self.time_ms < end_ms:
            assert time.monotonic() < deadline, "vehicle time stopped"
            if self.time_ms >= next_ms:
                self.link.mav.manual_control_send(self.target, x, y, z, r, 0)
                if int(self.time_ms) // 1000 != int(next_ms) // 1000:
                    self.heartbeat()
                next_ms = self.time_ms + 50.0
            message = self.link.recv_match(blocking=True, timeout=0.05)
            if message is None:
                continue
            kind = message.get_type()
            self.last[kind] = message
            if hasattr(message, "time_boot_ms"):
                self.time_ms = max(self.time_ms, message.time_boot_ms)
            if kind == "ATTITUDE":
                self.yaw_rates.append((message.time_boot_ms / 1000.0, message.yawspeed))

    def command(self, command: int, *params: float) -> None:
        params = (list(params) + [0.0] * 7)[:7]
        self.link.mav.command_long_send(self.target, 1, command, 0, *params)

    def arm_in_manual(self, arm_throttle: int) -> None:
        self.fly(3.0)
        self.command(self.mavutil.mavlink.MAV_CMD_DO_SET_MODE, 1, MANUAL >> 16)
        for _ in range(30):
            self.command(self.mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            self.fly(1.0, z=arm_throttle)
            heartbeat = self.last.get("HEARTBEAT")
            if heartbeat and heartbeat.base_mode & 128 and heartbeat.custom_mode == MANUAL:
                return
        pytest.fail(f"PX4 did not arm in MANUAL: {self.last.get('STATUSTEXT')} {self.last.get('HEARTBEAT')}")

    def mean_yaw_rate(self, since_s: float) -> float:
        rates = [r for t, r in self.yaw_rates if t >= since_s]
        return sum(rates) / len(rates)

    def close(self) -> None:
        if getattr(self, "link", None) is not None:
            self.link.close()
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def _truth(path: Path, since_s: float) -> list[dict]:
    with open(path, newline="") as handle:
        return [row for row in csv.DictReader(handle) if float(row["time_s"]) >= since_s]


@pytest.mark.parametrize("autopilot", ["px4-rover", "px4-uuv"])
def test_steering_input_turns_the_vehicle_the_right_way(autopilot, tmp_path):
    truth_log = tmp_path / "truth.csv"
    run = Px4Run(autopilot, truth_log)
    try:
        rover = autopilot == "px4-rover"
        # a rover arms with the throttle centred; PX4 wants a UUV's throttle low (its manual surge
        # then reads full reverse, which our physics ignore)
        run.arm_in_manual(arm_throttle=500 if rover else 0)
        throttle = 800  # 0.6
        run.fly(15.0, z=throttle)
        straight_end = run.time_ms / 1000.0
        turn = dict(y=600) if rover else dict(r=600)  # roll stick steers a rover, yaw stick a UUV
        run.fly(8.0, z=throttle, **turn)
        turning = straight_end + 3.0
        right = run.mean_yaw_rate(turning)
        truth = _truth(truth_log, turning)
        true_rate = sum(float(row["yaw_rate_rad_s"]) for row in truth) / len(truth)
        assert math.degrees(true_rate) > 2.0, f"physics yaw rate {math.degrees(true_rate):.2f} deg/s"
        assert math.degrees(right) > 2.0 and right == pytest.approx(true_rate, rel=0.2, abs=0.01)
        assert float(truth[-1]["model_speed_m_s"]) > 0.8  # under way on its thruster(s)
        assert all(float(row["rudder_rad"]) > 0.05 for row in truth)  # right turn = positive rudder
        servo = run.last.get("SERVO_OUTPUT_RAW")
        assert servo is not None and servo.servo1_raw > 1500  # the thruster(s) running

        run.fly(8.0, z=throttle, **{k: -v for k, v in turn.items()})
        left = run.mean_yaw_rate(run.time_ms / 1000.0 - 4.0)
        assert math.degrees(left) < -2.0
    finally:
        run.close()
