"""Our physics behind ArduPilot's JSON SITL backend (sim/ardupilot_json.py), driven by fabricated
servo frames over UDP on loopback exactly as SITL sends them (no ArduPilot needed here)."""
from __future__ import annotations

import json
import math
import socket
import struct

import pytest

from sim.ardupilot_json import (
    MAGIC_16,
    JsonBridge,
    JsonPhysics,
    RoverBoatDecoder,
    SubVectoredDecoder,
    parse_servo_frame,
)
from sim.linearize import linearized_yaw
from sim.preset import load_preset
from sim.vehicle import ActuatorDemand, Vehicle


def frame(pwm: list[int], count: int, rate: int = 200) -> bytes:
    return struct.pack("<HHI16H", MAGIC_16, rate, count, *(pwm + [0] * (16 - len(pwm))))


def test_servo_frames_are_parsed_and_garbage_is_ignored():
    parsed = parse_servo_frame(frame([1500, 0, 1750], 7))
    assert parsed.frame_rate == 200 and parsed.frame_count == 7 and parsed.pwm[:3] == (1500, 0, 1750)
    assert parse_servo_frame(b"\x00" * 40) is None
    assert parse_servo_frame(b"short") is None


def test_boat_decoder_maps_steering_and_throttle():
    decoder = RoverBoatDecoder()
    demand, heave = decoder.demand([2000, 0, 1750] + [0] * 13, ActuatorDemand())
    assert demand.rudder == pytest.approx(0.5236) and demand.thrust_ratio == pytest.approx(0.5) and heave == 0.0
    reverse, _ = decoder.demand([1000, 0, 1200] + [0] * 13, ActuatorDemand())
    assert reverse.rudder == pytest.approx(-0.5236) and reverse.thrust_ratio == 0.0  # reverse not simulated


def test_sub_decoder_unmixes_the_vectored_frame():
    decoder = SubVectoredDecoder()
    # pure yaw +0.5: motors 1 and 4 +, 2 and 3 − (AP_Motors6DOF vectored factors)
    yaw = [1700, 1300, 1300, 1700, 1500, 1500]
    demand, heave = decoder.demand(yaw + [0] * 10, ActuatorDemand())
    assert demand.rudder == pytest.approx(0.5 * 0.35) and demand.thrust_ratio == pytest.approx(0.0) and heave == 0.0
    forward = [1300, 1300, 1700, 1700, 1500, 1500]
    demand, _ = decoder.demand(forward + [0] * 10, ActuatorDemand())
    assert demand.thrust_ratio == pytest.approx(0.5) and demand.rudder == pytest.approx(0.0)


def test_bridge_answers_each_frame_with_the_state_over_udp():
    preset = load_preset("boat")
    bridge = JsonBridge(JsonPhysics(Vehicle(preset, speed=0.0), RoverBoatDecoder()))
    sitl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sitl.bind(("127.0.0.1", 0))
    sitl.settimeout(2.0)
    try:
        states = []
        for count in range(1, 2001):  # 10 s at 200 Hz: full throttle ahead, then hard to starboard
            steering = 2000 if count > 1600 else 1500
            sitl.sendto(frame([steering, 0, 2000], count), ("127.0.0.1", bridge.port))
            assert bridge.serve_once(1.0)
            states.append(json.loads(sitl.recvfrom(4096)[0]))
        # a repeated frame (SITL resends when it got no answer) is answered without stepping again
        sitl.sendto(frame([2000, 0, 2000], 2000), ("127.0.0.1", bridge.port))
        assert bridge.serve_once(1.0)
        again = json.loads(sitl.recvfrom(4096)[0])
        assert again["timestamp"] == states[-1]["timestamp"]
    finally:
        sitl.close()
        bridge.close()
    first, last = states[0], states[-1]
    assert first["timestamp"] == pytest.approx(0.005) and last["timestamp"] == pytest.approx(10.0)
    assert first["imu"]["accel_body"][2] == pytest.approx(-9.80665, abs=0.05)  # specific force at rest
    assert last["position"][2] == 0.0 and last["attitude"][1] == 0.0  # a boat stays at the surface, level
    speed = math.hypot(*last["velocity"][:2])
    assert 1.5 < speed < 2.6
    yaw_rate = last["imu"]["gyro"][2]
    assert yaw_rate > 0.1  # positive steering turns to starboard (clockwise)
    truth = linearized_yaw(preset, speed)
    # 2 s into the turn the rate is within the first-order response of the linearised model
    assert yaw_rate < truth["b2"] * (0.5236 - truth["delta0"]) / -truth["a22"] * 1.05
