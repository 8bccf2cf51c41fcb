"""The skid-steered (twin-thruster) boat: ArduRover's mixing rules, the steering-authority law
(b2 ∝ throttle ∝ U, unlike a rudder's U²), the ArduRover JSON frame decoder and launcher wiring, and
the built-in autopilot's outputs and SERVOn_FUNCTION parameters (unit level and over MAVLink)."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from sim.ardupilot_json import JsonPhysics, RoverBoatDecoder, RoverSkidDecoder, ServoFrame
from sim.ardupilot_sitl import SitlConfig, frame_of, parameter_file
from sim.autopilot import MODE_ALT_HOLD, MODE_MANUAL, Autopilot
from sim.build import build_vehicle
from sim.linearize import linearized_yaw, steady_speed
from sim.nomoto import input_lag, nomoto_from_state_space, sway_yaw_state_space
from sim.params import FULL_SCALE_RAD, ParamTable
from sim.physics.straight_run import straight_run_at_speed
from sim.preset import load_preset
from sim.skid_mixer import motor_from_pwm, pilot_skid_limit, pwm_from_motor, skid_mix, skid_unmix
from sim.vehicle import ActuatorDemand

DT = 0.01
THRUSTS = (0.6, 0.8, 1.0)


@pytest.fixture(scope="module")
def skid():
    return load_preset("boat-skid")


# ------------------------------------------------------------------ ArduRover's mixing rules
def test_mix_follows_ardurover_output_skid_steering():
    assert skid_mix(0.0, 0.6) == (0.6, 0.6)
    assert skid_mix(0.2, 0.6) == pytest.approx((0.8, 0.4))  # left = t + s, right = t − s
    assert skid_mix(0.5, 0.0) == pytest.approx((0.5, -0.5))  # a pivot
    # saturation, MOT_STR_THR_MIX 0.5: steering scaled by 1/σ, throttle = 1 − |s| (t ≥ best = 0 for
    # symmetric motors: lower limit −1)
    s = 0.5 / 1.3
    assert skid_mix(0.5, 0.8) == pytest.approx((1.0, 1.0 - 2 * s))
    # throttle first (mix 0): the throttle is kept, the steering gets what is left
    assert skid_mix(0.5, 0.8, steering_throttle_mix=0.0) == pytest.approx((1.0, 0.6))
    # thrust asymmetry 2: lower limit −0.5, negative outputs doubled
    assert skid_mix(0.4, 0.0, thrust_asymmetry=2.0) == pytest.approx((0.4, -0.8))
    assert skid_mix(0.9, 0.0, thrust_asymmetry=2.0) == pytest.approx((0.5, -1.0))  # steering range 0.5
    assert skid_mix(-2.0, 0.3) == pytest.approx((0.3 / 1.3 - 1 / 1.3, 1.0))  # steering range 1 − best = 1, σ 1.3
    # astern (t < best): σ = (t − |s|)/lower = 1.1, the throttle becomes |s| + lower
    assert skid_mix(0.5, -0.6) == pytest.approx((0.5 / 1.1 + 0.5 / 1.1 - 1.0, -1.0))
    for steering, throttle in ((0.3, 0.5), (-0.7, 0.2), (0.5, 0.8), (0.1, -0.4)):
        left, right = skid_mix(steering, throttle)
        assert -1.0 <= left <= 1.0 and -1.0 <= right <= 1.0
        assert skid_mix(*skid_unmix(left, right)) == pytest.approx((left, right))


def test_pilot_sticks_shrink_in_proportion_as_in_rover_manual():
    assert pilot_skid_limit(0.6, 0.8) == pytest.approx((0.6 / 1.4, 0.8 / 1.4))
    assert pilot_skid_limit(0.3, 0.5) == (0.3, 0.5)


def test_motor_pwm_is_ardupilot_pwm_from_angle():
    assert [pwm_from_motor(d) for d in (0.0, 0.5, -0.5, 1.0, -1.0, 1.5)] == [1500, 1750, 1250, 2000, 1000, 2000]
    assert pwm_from_motor(0.0019) == 1500 and pwm_from_motor(-0.0019) == 1500  # uint16_t truncation
    assert pwm_from_motor(0.7391) == 1869 and pwm_from_motor(-0.7391) == 1131
    assert motor_from_pwm(1250) == -0.5 and motor_from_pwm(2100) == 1.0


def test_positive_steering_turns_clockwise_and_reverse_is_weaker(skid):
    vehicle = build_vehicle(skid, speed=0.0)
    left, right = skid_mix(0.5, 0.0)
    for _ in range(2000):
        vehicle.step(DT, ActuatorDemand(motor_left=left, motor_right=right))
    assert vehicle.yaw_rate > 0.1  # a pivot to starboard, like a positive rudder
    assert vehicle.surge > 0.0  # the astern motor pushes only 58 % of the ahead one


# ------------------------------------------------------------------ the steering-authority law
def _hull_kappa(preset, run) -> float:
    """κ(U): the hull's first-order b2 per unit yaw moment (1/(s²·N·m)), the input lag included."""
    a, b = sway_yaw_state_space(preset, run, unit_moment=True)
    nomoto = nomoto_from_state_space(a, b)
    return nomoto.K / nomoto.first_order_T(input_lag(preset))


def test_skid_b2_follows_the_differential_thrust_law(skid):
    """b2 = N_s·κ(U)/δfs with N_s = y_arm·(F′(t + s0) + η_R·F′(t − s0)) ∝ t ∝ U (sim/nomoto.py),
    checked against the numerical linearisation at three speeds."""
    q, y, eta = skid.thruster.quadratic, skid.twin_thrusters.y_arm, skid.twin_thrusters.right_efficiency
    speeds, b2s, per_speed = [], [], []
    for thrust in THRUSTS:
        speed = steady_speed(skid, thrust)
        lin = linearized_yaw(skid, speed)
        run = straight_run_at_speed(skid, speed)
        assert lin["model"] == "3dof-skid" and lin["thrust_ratio"] == pytest.approx(thrust, rel=1e-9)
        assert lin["T"] == pytest.approx(lin["T1"] + lin["T2"] + lin["T_lag"] - lin["T3"], rel=1e-12)
        assert lin["T_lag"] == skid.thruster.time_constant == 0.3
        moment_per_steering = y * (2 * q * (thrust + run.steering) + eta * 2 * q * (thrust - run.steering))
        assert lin["b2"] == pytest.approx(moment_per_steering * _hull_kappa(skid, run) / FULL_SCALE_RAD, rel=1e-6)
        assert lin["b2_per_steering"] == pytest.approx(lin["b2"] * FULL_SCALE_RAD, rel=1e-12)
        assert lin["delta0"] == pytest.approx(run.steering * FULL_SCALE_RAD) and lin["delta0"] < 0.0  # weak right motor
        speeds.append(speed)
        b2s.append(lin["b2"])
        per_speed.append(moment_per_steering / speed)
    # quadratic thrust and quadratic drag: N_s ∝ t ∝ U exactly
    assert np.ptp(per_speed) < 1e-9 * per_speed[0]
    # b2/κ grows as U¹ for the skid boat, as U² for the same hull with a rudder
    rudder = load_preset("boat-3dof")
    skid_slope = np.polyfit(np.log(speeds), np.log([b * FULL_SCALE_RAD / _hull_kappa(skid, straight_run_at_speed(skid, s))
                                                    for b, s in zip(b2s, speeds)]), 1)[0]
    rudder_speeds = [steady_speed(rudder, t) for t in THRUSTS]
    rudder_b2 = [linearized_yaw(rudder, s)["b2"] for s in rudder_speeds]
    rudder_per_u2 = []
    for speed, b2 in zip(rudder_speeds, rudder_b2):
        a, b = sway_yaw_state_space(rudder, straight_run_at_speed(rudder, speed))
        nomoto = nomoto_from_state_space(a, tuple(x / speed ** 2 for x in b))  # the rudder's force per U²
        rudder_per_u2.append(b2 / (nomoto.K / nomoto.first_order_T()))
    assert skid_slope == pytest.approx(1.0, abs=1e-6)
    assert np.polyfit(np.log(rudder_speeds), np.log(rudder_per_u2), 1)[0] == pytest.approx(2.0, abs=1e-6)
    # and the raw b2: well below U² for the skid boat, close to it for the rudder
    assert np.polyfit(np.log(speeds), np.log(b2s), 1)[0] < 0.8
    assert np.polyfit(np.log(rudder_speeds), np.log(rudder_b2), 1)[0] > 1.8


def test_small_steering_step_matches_the_nomoto_response_with_the_propeller_lag(skid):
    from scipy import signal

    thrust = 0.6
    speed = steady_speed(skid, thrust)
    lin = linearized_yaw(skid, speed)
    trim = lin["delta0"] / FULL_SCALE_RAD
    step = math.radians(0.1) / FULL_SCALE_RAD
    vehicle = build_vehicle(skid, speed=speed)
    rates = np.empty(2000)
    for k in range(rates.size):
        vehicle.step(DT, ActuatorDemand(motor_left=thrust + trim + step, motor_right=thrust - trim - step))
        rates[k] = vehicle.yaw_rate
    rates /= math.radians(0.1)
    t = DT * np.arange(rates.size + 1)
    den = np.polymul(np.polymul([lin["T1"], 1.0], [lin["T2"], 1.0]), [lin["T_lag"], 1.0])
    third = signal.step(signal.lti([lin["K"] * lin["T3"], lin["K"]], den), T=t)[1][1:]
    assert rates[-1] == pytest.approx(lin["K"], rel=3e-3)
    assert np.max(np.abs(rates - third)) < 5e-3 * lin["K"]


# ------------------------------------------------------------------ ArduRover SITL: frames and launcher
def test_skid_frames_decode_to_motor_demands():
    decoder = RoverSkidDecoder()
    pwm = [1750, 1500, 1250] + [1500] * 13
    demand, heave = decoder.demand(pwm, ActuatorDemand(mass_angle=0.1))
    assert (demand.motor_left, demand.motor_right, heave, demand.mass_angle) == (0.5, -0.5, 0.0, 0.1)
    demand, _ = decoder.demand([0, 1500, 0] + [0] * 13, demand)
    assert (demand.motor_left, demand.motor_right) == (0.0, 0.0)  # disabled outputs stop the motors


def test_json_physics_flies_the_skid_boat_from_sitl_frames(skid):
    physics = JsonPhysics(build_vehicle(skid, speed=0.0), RoverSkidDecoder())
    frame = ServoFrame(frame_rate=200, frame_count=0, pwm=tuple([1800, 1500, 1600] + [1500] * 13))
    for count in range(2000):
        physics.step(ServoFrame(200, count, frame.pwm))
    state = physics.vehicle.state
    assert state.yaw_rate > 0.05 and state.surge > 0.5  # left ahead harder: a starboard turn under way
    assert (state.motor_left, state.motor_right) == pytest.approx((0.6, 0.2))
    assert state.rudder == pytest.approx(0.2 * FULL_SCALE_RAD) and state.thrust_ratio == pytest.approx(0.4)


def test_launcher_picks_the_skid_parameters_and_decoder(skid, tmp_path):
    assert frame_of("ardurover", skid) == ("ardurover-skid.parm", RoverSkidDecoder)
    assert frame_of("ardurover", load_preset("boat")) == ("ardurover-boat.parm", RoverBoatDecoder)
    assert frame_of("ardurover", load_preset("boat-3dof"))[1] is RoverBoatDecoder
    with pytest.raises(ValueError, match="skid"):
        frame_of("ardusub", skid)
    text = parameter_file(SitlConfig("ardurover", tmp_path, preset="boat-skid", params={"ATC_STR_RAT_FF": 1.5}),
                          tmp_path).read_text()
    lines = {line.split()[0]: line.split()[1] for line in text.splitlines() if line and not line.startswith("#")}
    assert lines["SERVO1_FUNCTION"] == "73" and lines["SERVO3_FUNCTION"] == "74"
    assert lines["SERVO1_TRIM"] == lines["SERVO3_TRIM"] == "1500" and lines["FRAME_CLASS"] == "2"
    assert text.rstrip().endswith("ATC_STR_RAT_FF 1.5")


# ------------------------------------------------------------------ the built-in autopilot
def test_servo_functions_describe_the_actuation():
    skid_params = ParamTable.for_preset(load_preset("boat-skid"))
    assert (skid_params["SERVO1_FUNCTION"], skid_params["SERVO3_FUNCTION"]) == (73, 74)
    for rudder_boat in ("boat", "boat-3dof"):
        params = ParamTable.for_preset(load_preset(rudder_boat))
        assert (params["SERVO1_FUNCTION"], params["SERVO3_FUNCTION"]) == (26, 70)
    assert "SERVO1_FUNCTION" not in ParamTable.for_preset(load_preset("starfish"))  # an AUV: unchanged table
    assert not skid_params.set("SERVO1_FUNCTION", 26).accepted and skid_params["SERVO1_FUNCTION"] == 73
    assert skid_params.is_integer("SERVO3_FUNCTION")
    assert skid_params.names[-2:] == ["SERVO1_FUNCTION", "SERVO3_FUNCTION"]  # the others keep their index


def test_autopilot_mixes_its_heading_pi_and_rc_sticks(skid):
    vehicle = build_vehicle(skid)
    autopilot = Autopilot(vehicle, ParamTable.for_preset(skid))
    assert autopilot.skid
    autopilot.arm(True)
    autopilot.set_mode(MODE_ALT_HOLD)
    autopilot.set_heading(math.radians(20.0), relative=True)
    autopilot.step(DT)
    d = autopilot.demand
    steering = d.rudder / FULL_SCALE_RAD
    assert steering > 0.0 and (d.motor_left, d.motor_right) == pytest.approx(skid_mix(steering, d.thrust_ratio))
    for _ in range(3000):
        autopilot.step(DT)
    assert math.degrees(vehicle.state.yaw) == pytest.approx(20.0, abs=1.0)  # the PI holds the new heading
    # RC channel 1 in the holding mode: a steering stick, shrunk with the throttle, then mixed
    assert autopilot.rc_override(255, [1500 + 400, 65535, 65535])
    autopilot.step(DT)
    s, t = pilot_skid_limit(0.8, autopilot.thrust_setpoint)
    assert (autopilot.demand.motor_left, autopilot.demand.motor_right) == pytest.approx(skid_mix(s, t))
    # MANUAL: both sticks
    autopilot.set_mode(MODE_MANUAL)
    autopilot.rc_override(255, [1250, 65535, 1700])
    autopilot.step(DT)
    assert (autopilot.demand.motor_left, autopilot.demand.motor_right) == pytest.approx(skid_mix(-0.5, 0.7))
    autopilot.arm(False)
    autopilot.step(DT)
    assert (vehicle.motor_left, vehicle.motor_right) == (0.0, 0.0)


def test_servo_output_raw_and_functions_over_mavlink(sim_factory, mav_client):
    from pymavlink import mavutil

    mav = mavutil.mavlink
    sim = sim_factory(speedup=20, preset="boat-skid")
    conn = mav_client(sim.endpoint)

    def wait(predicate, timeout=20.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = conn.recv_match(blocking=True, timeout=0.2)
            if msg is not None and predicate(msg):
                return msg
        raise AssertionError("no such message")

    for name, value in (("SERVO1_FUNCTION", 73), ("SERVO3_FUNCTION", 74)):
        conn.mav.param_request_read_send(1, 1, name.encode(), -1)
        assert wait(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name).param_value == value
    disarmed = wait(lambda m: m.get_type() == "SERVO_OUTPUT_RAW")
    assert (disarmed.servo1_raw, disarmed.servo3_raw) == (1500, 1500)  # stopped, as ArduPilot's trim
    for command, params in ((mav.MAV_CMD_COMPONENT_ARM_DISARM, (1,)), (mav.MAV_CMD_DO_SET_MODE, (1, 2))):
        conn.mav.command_long_send(1, 1, command, 0, *params, *([0.0] * (7 - len(params))))
        assert wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command).result == 0
    conn.mav.rc_channels_override_send(1, 1, 1500 + 200, 65535, 65535, *([65535] * 5))  # steering 0.4
    msg = wait(lambda m: m.get_type() == "SERVO_OUTPUT_RAW" and m.servo1_raw > m.servo3_raw + 100)
    left, right = skid_mix(*pilot_skid_limit(0.4, load_preset("boat-skid").autopilot.cruise_thrust))
    assert msg.servo1_raw == pytest.approx(pwm_from_motor(left), abs=1)  # ±1 µs: δ → s in floating point
    assert msg.servo3_raw == pytest.approx(pwm_from_motor(right), abs=1)
    turning = wait(lambda m: m.get_type() == "ATTITUDE" and m.yawspeed > 0.05)
    assert turning is not None
