"""Simulator physics: presets, vehicle dynamics, control laws and linearised truth (SPEC C2, §3)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import curve_fit

from sim.controllers import DepthPitchCascade, HeadingPI
from sim.linearize import linearized_yaw, steady_speed
from sim.physics.roll import RollConstants, steady_roll
from sim.preset import load_preset, preset_names
from sim.vehicle import ActuatorDemand, Vehicle, wrap_angle

DT = 0.01


@pytest.fixture(scope="module")
def starfish():
    return load_preset("starfish")


def fly_level(vehicle: Vehicle, thrust_ratio: float, seconds: float, depth: float = 5.0,
              rudder: float = 0.0, mass_angle: float = 0.0) -> DepthPitchCascade:
    """Fly under the Table 5.1 depth/pitch cascade with a fixed thrust and rudder."""
    cascade = DepthPitchCascade()
    demand = ActuatorDemand(rudder=rudder, thrust_ratio=thrust_ratio, mass_angle=mass_angle)
    for _ in range(round(seconds / DT)):
        demand.elevator = cascade.update(DT, depth, vehicle.depth, vehicle.pitch)
        vehicle.step(DT, demand)
    return cascade


# ------------------------------------------------------------------ presets
def test_presets_load_and_unknown_name_lists_available():
    assert {"starfish", "starfish-tla", "hugin"} <= set(preset_names())
    for name in preset_names():
        assert load_preset(name).name == name
    with pytest.raises(ValueError, match="starfish-tla"):
        load_preset("no-such-vehicle")


# ------------------------------------------------------------------ surge / speed
def test_thrust_070_gives_1_39_m_s_in_simulation(starfish):
    vehicle = Vehicle(starfish, speed=1.0)
    fly_level(vehicle, 0.70, 60.0)
    assert vehicle.state.speed_water == pytest.approx(1.39, abs=0.05)


def test_steady_speeds_follow_table_3_1_roughly(starfish):
    table = {0.6: 1.07, 0.7: 1.36, 0.8: 1.63, 0.9: 1.92, 1.0: 2.19}
    for thrust, speed in table.items():
        assert steady_speed(starfish, thrust) == pytest.approx(speed, abs=0.08)
    assert steady_speed(starfish, 0.25) == 0.0  # thruster dead zone


def test_steady_speed_is_consistent_with_simulation(starfish):
    vehicle = Vehicle(starfish, speed=1.2)
    fly_level(vehicle, 0.85, 60.0)
    assert vehicle.state.speed_water == pytest.approx(steady_speed(starfish, 0.85), rel=0.005)


# ------------------------------------------------------------------ yaw
def test_linearized_yaw_matches_preset_laws(starfish):
    y = starfish.yaw
    for speed in (1.0, 1.4, 2.0):
        lin = linearized_yaw(starfish, speed)
        assert lin["a22"] == pytest.approx(y.a22_constant + y.a22_per_speed * speed, rel=1e-6)
        assert lin["b2"] == pytest.approx(y.b2_constant + y.b2_per_speed_squared * speed**2, rel=1e-6)
        assert lin["delta0"] == pytest.approx(y.rudder_offset, abs=1e-9)
    # Fig. 3.8: b2 = 0.31 u² + 0.26; Table 3.1 a22 in −0.95..−1.21 over the speed range
    assert linearized_yaw(starfish, 1.36)["b2"] == pytest.approx(0.31 * 1.36**2 + 0.26, abs=0.02)
    assert -1.25 < linearized_yaw(starfish, 2.19)["a22"] < linearized_yaw(starfish, 1.07)["a22"] < -0.9


def test_tla_preset_yaw_is_in_table_3_4_range():
    tla = load_preset("starfish-tla")
    for speed, a22, b2 in [(1.05, -1.28, 0.65), (1.60, -1.62, 1.35), (2.13, -1.48, 2.02)]:
        lin = linearized_yaw(tla, speed)
        assert lin["a22"] == pytest.approx(a22, abs=0.2)
        assert lin["b2"] == pytest.approx(b2, abs=0.15)


def test_open_loop_rudder_step_matches_linearized_yaw(starfish):
    """Small rudder step at the TR 0.70 steady speed: time constant −1/a22, gain b2/(−a22)·step."""
    speed = steady_speed(starfish, 0.70)
    lin = linearized_yaw(starfish, speed)
    vehicle = Vehicle(starfish, speed=speed)
    vehicle.limits.rudder_rate = 1e3  # an ideal step, to compare with the linear model
    step = 0.05
    demand = ActuatorDemand(rudder=lin["delta0"], thrust_ratio=0.70, elevator=vehicle.elevator)
    for _ in range(200):  # settle at δ0: no yaw rate
        vehicle.step(DT, demand)
    assert abs(vehicle.yaw_rate) < 1e-6
    demand.rudder = lin["delta0"] + step
    times, rates = [], []
    for k in range(1, 801):
        vehicle.step(DT, demand)
        times.append(k * DT)
        rates.append(vehicle.yaw_rate)

    def first_order(t, gain, tau):
        return gain * (1.0 - np.exp(-(t - DT) / tau))

    (gain, tau), _ = curve_fit(first_order, np.array(times), np.array(rates), p0=(0.05, 1.0))
    assert tau == pytest.approx(-1.0 / lin["a22"], rel=0.05)
    assert gain == pytest.approx(lin["b2"] / -lin["a22"] * step, rel=0.05)


def test_rudder_is_rate_and_position_limited(starfish):
    vehicle = Vehicle(starfish)
    vehicle.step(DT, ActuatorDemand(rudder=1.0, thrust_ratio=0.7))
    assert vehicle.rudder == pytest.approx(starfish.actuators.rudder_rate * DT)
    for _ in range(200):
        vehicle.step(DT, ActuatorDemand(rudder=1.0, thrust_ratio=0.7))
    assert vehicle.rudder == pytest.approx(vehicle.limits.rudder_max)


def test_hugin_turns_and_straight_leg_sway():
    """SPEC §3.7: δ = 12.5° turns give R ≈ 15–16 m at 4.5–5.5 °/s; sway ≈ −0.012 m/s straight."""
    hugin = load_preset("hugin")
    assert steady_speed(hugin, 0.5) == pytest.approx(1.3, abs=0.05)
    assert steady_speed(hugin, 0.8) == pytest.approx(2.0, abs=0.1)
    vehicle = Vehicle(hugin, speed=steady_speed(hugin, 0.5))
    fly_level(vehicle, 0.5, 30.0)
    assert vehicle.state.sway == pytest.approx(-0.012, abs=0.001)
    fly_level(vehicle, 0.5, 60.0, rudder=math.radians(12.5))
    state = vehicle.state
    assert 15.0 < state.speed_water / state.yaw_rate < 16.5
    assert 4.5 < math.degrees(state.yaw_rate) < 5.5


# ------------------------------------------------------------------ dive plane
def test_depth_held_at_thrust_050(starfish):
    vehicle = Vehicle(starfish)  # starts trimmed at the TR 0.70 speed, then slows down
    cascade = fly_level(vehicle, 0.50, 120.0)
    depths = []
    demand = ActuatorDemand(thrust_ratio=0.50)
    for _ in range(3000):
        demand.elevator = cascade.update(DT, 5.0, vehicle.depth, vehicle.pitch)
        vehicle.step(DT, demand)
        depths.append(vehicle.depth)
    assert max(abs(d - 5.0) for d in depths[-1000:]) < 0.3
    assert abs(vehicle.elevator) < starfish.actuators.elevator_max - 0.05


def test_depth_lost_below_minimum_speed_with_elevator_saturated(starfish):
    vehicle = Vehicle(starfish)
    cascade = fly_level(vehicle, 0.38, 60.0)
    assert vehicle.elevator == pytest.approx(starfish.actuators.elevator_max)
    assert vehicle.depth < 5.0 - 1.0  # positively buoyant: it rises
    assert vehicle.pitch - cascade.pitch_setpoint > 0.05  # pitch control lost (θe grows)


def test_minimum_speed_equilibrium_near_analytic_value(starfish):
    """With the elevator at δmax = 0.26 the level equilibrium is V ≈ 0.68, TR ≈ 0.43–0.44 (SPEC §3.4)."""
    from sim.physics.equilibrium import level_trim_at_speed

    trim = level_trim_at_speed(starfish, 0.676)
    assert trim.elevator == pytest.approx(0.26, abs=0.03)
    assert trim.thrust_ratio == pytest.approx(0.435, abs=0.01)
    assert math.degrees(trim.pitch) == pytest.approx(-7.9, abs=0.6)


# ------------------------------------------------------------------ roll
def test_twenty_degrees_of_mass_angle_gives_five_to_six_degrees_of_roll(starfish):
    constants = RollConstants.from_preset(starfish.roll)
    assert 5.0 < -math.degrees(steady_roll(constants, math.radians(20.0))) < 6.0
    vehicle = Vehicle(starfish, speed=0.0)  # at rest in the tank: no propeller torque
    for _ in range(3000):
        vehicle.step(DT, ActuatorDemand(mass_angle=math.radians(20.0)))
    assert vehicle.mass_angle == pytest.approx(vehicle.limits.mass_max, abs=1e-6)  # 0.349 rad = 20°
    assert 5.0 < -math.degrees(vehicle.roll) < 6.0


def test_mass_servo_lag_and_limit(starfish):
    vehicle = Vehicle(starfish, speed=0.0)
    for _ in range(50):  # 0.5 s = one time constant
        vehicle.step(DT, ActuatorDemand(mass_angle=1.0))  # beyond the ±20° limit
    assert vehicle.mass_angle == pytest.approx(vehicle.limits.mass_max * (1 - math.exp(-1)), rel=1e-3)


def test_propeller_torque_heels_a_little_at_cruise(starfish):
    vehicle = Vehicle(starfish)
    fly_level(vehicle, 0.70, 20.0)
    assert 1.0 < math.degrees(vehicle.roll) < 2.0


def test_roll_kick_and_disturbance(starfish):
    vehicle = Vehicle(starfish, speed=0.0, seed=2)
    vehicle.kick_roll(math.radians(25.0))
    assert vehicle.state.roll == pytest.approx(math.radians(25.0)) and vehicle.roll_rate == 0.0
    for _ in range(1500):
        vehicle.step(DT, ActuatorDemand())
    assert abs(math.degrees(vehicle.roll)) < 3.0  # decays (lightly damped)
    vehicle.roll_disturbance_amplitude = 0.03
    rolls = []
    for _ in range(20000):
        vehicle.step(DT, ActuatorDemand())
        rolls.append(vehicle.roll)
    assert 0.3 < math.degrees(np.std(rolls)) < 3.0


# ------------------------------------------------------------------ current, sensors, determinism
def test_current_adds_to_velocity_over_ground(starfish):
    vehicle = Vehicle(starfish, heading=math.pi / 2, current_north=0.2)
    fly_level(vehicle, 0.70, 10.0, rudder=starfish.yaw.rudder_offset)  # δ0: straight course
    state = vehicle.state
    assert state.vel_north == pytest.approx(0.2, abs=0.01)
    assert state.vel_east == pytest.approx(state.speed_water, abs=0.02)
    assert state.north == pytest.approx(2.0, abs=0.1)
    vehicle.set_current(0.0, -0.3)
    assert vehicle.state.vel_east == pytest.approx(state.vel_east - 0.3, abs=0.01)


def _measurements(seed: int, n: int = 50):
    vehicle = Vehicle(load_preset("starfish"), seed=seed)
    vehicle.roll_disturbance_amplitude = 0.05
    out = []
    for _ in range(n):
        vehicle.step(DT, ActuatorDemand(thrust_ratio=0.7, rudder=0.05))
        out.append(vehicle.measure())
    return out


def test_same_seed_same_measurements_different_seed_different():
    assert _measurements(7) == _measurements(7)
    assert _measurements(7) != _measurements(8)


def test_sensor_noise_levels_match_preset(starfish):
    vehicle = Vehicle(starfish, seed=3)
    truth = vehicle.state
    samples = [vehicle.measure() for _ in range(2000)]
    yaw_error = np.array([wrap_angle(m.yaw - truth.yaw) for m in samples])
    assert np.std(yaw_error) == pytest.approx(math.radians(starfish.sensors.attitude_deg), rel=0.1)
    assert np.std([m.depth for m in samples]) == pytest.approx(starfish.sensors.depth_m, rel=0.1)
    assert np.std([m.vel_north for m in samples]) == pytest.approx(starfish.sensors.velocity_m_s, rel=0.1)
    assert np.std([m.north for m in samples]) == pytest.approx(starfish.sensors.position_m, rel=0.1)
    assert all(m.rudder == truth.rudder and -math.pi < m.yaw <= math.pi for m in samples)


# ------------------------------------------------------------------ controllers
def test_heading_pi_wraps_error_and_winds_up_no_further_than_imax():
    pi_law = HeadingPI(kp=1.0, ki=0.5, imax=0.1, trim=0.01)
    # set-point 179°, heading −179°: the short way is −2°, not +358°
    rudder = pi_law.update(0.01, math.radians(179), math.radians(-179))
    assert rudder == pytest.approx(0.01 + math.radians(-2) * (1 + 0.5 * 0.01), rel=1e-6)
    for _ in range(10_000):
        pi_law.update(0.01, 1.0, 0.0)
    assert pi_law.integral == pytest.approx(0.1)
    pi_law.reset()
    assert pi_law.integral == 0.0


def test_heading_pi_holds_heading_on_the_vehicle(starfish):
    vehicle = Vehicle(starfish, heading=0.0)
    heading = HeadingPI(kp=starfish.autopilot.heading_p, ki=starfish.autopilot.heading_i, imax=0.15)
    cascade = DepthPitchCascade()
    demand = ActuatorDemand(thrust_ratio=0.7)
    for _ in range(6000):
        demand.rudder = heading.update(DT, math.radians(30), wrap_angle(vehicle.yaw))
        demand.elevator = cascade.update(DT, 5.0, vehicle.depth, vehicle.pitch)
        vehicle.step(DT, demand)
    assert math.degrees(vehicle.state.yaw) == pytest.approx(30.0, abs=0.5)
    assert heading.integral == pytest.approx(starfish.yaw.rudder_offset, abs=0.003)  # learns δ0


def test_depth_cascade_signs_follow_table_5_1():
    cascade = DepthPitchCascade()
    cascade.update(0.01, depth_setpoint=6.0, depth=5.0, pitch=0.0)
    assert cascade.pitch_setpoint < 0.0  # too shallow → nose down
    elevator = DepthPitchCascade().update(0.01, depth_setpoint=5.0, depth=5.0, pitch=0.1)
    assert elevator > 0.0  # nose too high → positive elevator = nose-down moment


def test_cascade_initialize_gives_bumpless_start(starfish):
    vehicle = Vehicle(starfish)  # trimmed: pitch −1.36°, elevator ≈ 0.005
    cascade = DepthPitchCascade()
    cascade.initialize(vehicle.pitch, vehicle.elevator)
    demand = ActuatorDemand(thrust_ratio=0.70)
    worst = 0.0
    for _ in range(1000):
        demand.elevator = cascade.update(DT, 5.0, vehicle.depth, vehicle.pitch)
        vehicle.step(DT, demand)
        worst = max(worst, abs(vehicle.elevator))
    assert worst < 0.02 and abs(vehicle.depth - 5.0) < 0.01
    heading = HeadingPI(kp=1.0, ki=0.1, imax=0.15, trim=0.0)
    heading.initialize(0.01)
    assert heading.update(DT, 0.3, 0.3) == pytest.approx(0.01)


def test_slow_thrust_ramp_saturates_elevator_near_analytic_minimum(starfish):
    """Lowering thrust slowly under the cascade: the elevator saturates near TR* ≈ 0.433–0.44."""
    vehicle = Vehicle(starfish)
    cascade = DepthPitchCascade()
    cascade.initialize(vehicle.pitch, vehicle.elevator)
    demand = ActuatorDemand(thrust_ratio=0.70)
    for k in range(1, 40_000):
        if k % 500 == 0:
            demand.thrust_ratio -= 0.005  # 0.001/s: quasi-static
        demand.elevator = cascade.update(DT, 5.0, vehicle.depth, vehicle.pitch)
        vehicle.step(DT, demand)
        if vehicle.elevator >= starfish.actuators.elevator_max - 1e-6:
            break
    assert 0.42 < demand.thrust_ratio < 0.45
    assert vehicle.state.speed_water == pytest.approx(0.68, abs=0.03)


def test_doublet_stays_near_linear_enough_for_identification(starfish):
    """Noise-free least squares on a 0.26 rad doublet recovers the linearised a22, b2 within 5 %:
    the quadratic yaw damping is small enough for SPEC C3's identification target."""
    speed = steady_speed(starfish, 0.70)
    lin = linearized_yaw(starfish, speed)
    vehicle = Vehicle(starfish, speed=speed)
    demand = ActuatorDemand(thrust_ratio=0.70, elevator=vehicle.elevator)
    rates, rudders = [], []
    for k in range(1600):
        t = k * DT
        demand.rudder = lin["delta0"] + (0.26 if 2 <= t < 4 else -0.26 if 4 <= t < 6 else 0.0)
        vehicle.step(DT, demand)
        rates.append(vehicle.yaw_rate)
        rudders.append(vehicle.rudder)
    rates = np.array(rates)
    regressors = np.c_[rates, rudders, -np.ones_like(rates)]
    a22, b2, c0 = np.linalg.lstsq(regressors, np.gradient(rates, DT), rcond=None)[0]
    assert a22 == pytest.approx(lin["a22"], rel=0.05)
    assert b2 == pytest.approx(lin["b2"], rel=0.05)
    assert c0 / b2 == pytest.approx(lin["delta0"], abs=0.003)
    assert abs(a22 / lin["a22"] - 1) > 0.005  # and the physics is genuinely nonlinear
