"""Steady-state manoeuvring under unknown current (SPEC C8): numerics, transient cutting, behaviours.

Synthetic data come from a small kinematic vehicle (first-order heading response, speed loss and
sway coupling in turns) with a known current and seeded noise; the last tests run the behaviours on
the simulator's ``hugin`` preset in-process (tests may import ``sim``).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from behaviors.steady_state import SquareConfig, SquarePattern, SteadyTurns, TurnConfig
from companion.interface import OverrideActuator, ReleaseActuator, SetHeading, SetMode, SetThrust, Telemetry
from companion.numerics.steady_state import (
    body_to_ned_matrices,
    current_direction_deg,
    fit_steady_turn,
    fit_straight_legs,
    heading_rate,
    ned_to_body,
    steady_straight_mask,
    steady_turn_mask,
)
from harness.datasets import angle_error_deg, current_vector, synth_square, synth_turn
from harness.inprocess import HuginLoop


# --------------------------------------------------------------------------- helpers
def test_current_direction_is_towards_clockwise_from_north():
    assert current_direction_deg(0.0, 0.01) == pytest.approx(90.0)
    assert current_direction_deg(0.01, 0.0) == pytest.approx(0.0)
    assert current_direction_deg(-0.01, 0.0) == pytest.approx(180.0)
    assert current_direction_deg(0.0, -0.01) == pytest.approx(270.0)


def test_ned_to_body_inverts_the_rotation():
    rng = np.random.default_rng(3)
    roll, pitch, yaw = rng.uniform(-0.3, 0.3, 50), rng.uniform(-0.3, 0.3, 50), rng.uniform(-3, 3, 50)
    v_body = rng.normal(size=(50, 3))
    v_ned = np.einsum("nij,nj->ni", body_to_ned_matrices(roll, pitch, yaw), v_body)
    np.testing.assert_allclose(ned_to_body(roll, pitch, yaw, v_ned), v_body, atol=1e-12)
    # heading 90°: body x points east
    np.testing.assert_allclose(ned_to_body([0.0], [0.0], [math.pi / 2], [[0.0, 1.0, 0.0]]), [[1.0, 0.0, 0.0]], atol=1e-12)


# --------------------------------------------------------------------------- squares
@pytest.mark.parametrize(
    "speed,direction,seed",
    [(0.002, 30.0, 1), (0.012, 140.0, 2), (0.020, 250.0, 3), (0.007, 345.0, 4), (0.015, 90.0, 5)],
)
def test_square_recovers_current_and_water_velocity(speed, direction, seed):
    cur = current_vector(speed, direction)
    data = synth_square(cur, seed)
    mask = steady_straight_mask(data["t"], data["yaw"], data["vel_body"])
    fit = fit_straight_legs(data["roll"][mask], data["pitch"][mask], data["yaw"][mask], data["vel_body"][mask])
    assert np.hypot(*(fit.current - cur)) < 0.003
    if speed >= 0.005:
        assert angle_error_deg(fit.current_dir_deg, direction) < 15.0
    assert fit.surge == pytest.approx(1.8, abs=0.003)
    assert fit.sway == pytest.approx(-0.012, abs=0.002)
    assert fit.heave == pytest.approx(0.05, abs=0.002)
    assert fit.condition_number < 1.3  # a square: columns of H nearly orthogonal (paper §III-B; legs cut unequally)
    assert fit.residual_std == pytest.approx(0.005, rel=0.2)  # the velocity noise, transients cut


def test_square_sigma_matches_monte_carlo_spread():
    cur = current_vector(0.01, 60.0)
    estimates, sigmas = [], []
    for seed in range(40):
        data = synth_square(cur, 100 + seed, leg_s=100.0, dt=1.0)
        mask = steady_straight_mask(data["t"], data["yaw"], data["vel_body"])
        fit = fit_straight_legs(data["roll"][mask], data["pitch"][mask], data["yaw"][mask], data["vel_body"][mask])
        estimates.append(np.r_[fit.velocity_water, fit.current])
        sigmas.append(fit.sigma)
    spread = np.std(estimates, axis=0, ddof=1)
    predicted = np.sqrt(np.mean(np.square(sigmas), axis=0))
    np.testing.assert_allclose(predicted, spread, rtol=0.35)  # 40 runs: the spread itself is ±11 %


def test_transient_cutting_removes_turns_and_speed_recovery():
    data = synth_square(current_vector(0.01, 10.0), 7)
    mask = steady_straight_mask(data["t"], data["yaw"], data["vel_body"])
    assert not np.any(mask & (np.abs(data["true_rate"]) > math.radians(0.5)))
    assert 0.5 < mask.mean() < 0.95
    # keeping the transients biases the surge (the dip after each turn): cutting must help
    all_fit = fit_straight_legs(data["roll"], data["pitch"], data["yaw"], data["vel_body"])
    cut_fit = fit_straight_legs(data["roll"][mask], data["pitch"][mask], data["yaw"][mask], data["vel_body"][mask])
    assert abs(cut_fit.surge - 1.8) < abs(all_fit.surge - 1.8)


def test_single_leg_is_unobservable():
    data = synth_square(current_vector(0.01, 10.0), 8, leg_s=150.0)
    leg = (data["t"] > 60) & (data["t"] < 150)
    fit = fit_straight_legs(data["roll"][leg], data["pitch"][leg], data["yaw"][leg], data["vel_body"][leg])
    assert fit.condition_number > 30.0


def test_straight_fit_rejects_bad_shapes():
    with pytest.raises(ValueError):
        fit_straight_legs([0.0], [0.0], [0.0], [[1.0, 0.0, 0.0]])
    with pytest.raises(ValueError):
        fit_straight_legs(np.zeros(5), np.zeros(5), np.zeros(5), np.zeros((5, 2)))


# --------------------------------------------------------------------------- turns
@pytest.mark.parametrize("use_yaw", [True, False])
@pytest.mark.parametrize(
    "speed,direction,rate,seed", [(0.009, 107.8, 4.8, 11), (0.018, 0.5, -4.6, 12), (0.014, 200.0, 5.4, 13)]
)
def test_turn_recovers_radius_rate_and_current(speed, direction, rate, seed, use_yaw):
    cur = current_vector(speed, direction)
    data = synth_turn(cur, seed, rate_deg_s=rate)
    mask = steady_turn_mask(data["t"], data["yaw"])
    assert data["t"][mask][0] > 20.0  # the spin-up (lag 10 s) is cut
    fit = fit_steady_turn(data["t"][mask], data["north"][mask], data["east"][mask],
                          data["yaw"][mask] if use_yaw else None)
    assert fit.radius == pytest.approx(data["radius"], rel=0.01)
    assert math.degrees(fit.rate) == pytest.approx(rate, rel=0.01)
    assert np.hypot(*(fit.current - cur)) < 0.003
    assert angle_error_deg(fit.current_dir_deg, direction) < 15.0
    assert fit.residual_std == pytest.approx(0.1, rel=0.15)  # ≈ the position noise σ


def test_turn_fit_robust_to_large_current_and_sparse_fixes():
    """Current 0.3 m/s (a quarter of the speed) and positions every 3 s (HUGIN's USBL rate)."""
    cur = current_vector(0.3, 300.0)
    data = synth_turn(cur, 21, rate_deg_s=-5.0, dt=3.0, duration_s=400.0, pos_noise=0.2)
    mask = steady_turn_mask(data["t"], data["yaw"])
    for yaw in (data["yaw"][mask], None):
        fit = fit_steady_turn(data["t"][mask], data["north"][mask], data["east"][mask], yaw)
        assert fit.radius == pytest.approx(data["radius"], rel=0.01)
        assert np.hypot(*(fit.current - cur)) < 0.005


def test_turn_fit_rejects_straight_line():
    t = np.arange(0.0, 100.0)
    with pytest.raises(ValueError):
        fit_steady_turn(t, 1.5 * t, 0.0 * t, np.zeros_like(t))


def test_heading_rate_of_a_ramp():
    t = np.arange(0.0, 60.0, 0.1)
    yaw = np.arctan2(np.sin(0.1 * t), np.cos(0.1 * t))  # wraps several times
    np.testing.assert_allclose(heading_rate(t, yaw), 0.1, atol=1e-9)


# --------------------------------------------------------------------------- behaviours (kinematic vehicle)
class KinematicVehicle:
    """A minimal closed loop for the behaviours: heading hold with rate limit, rudder override →
    constant turn rate ∝ rudder, current; telemetry at 10 Hz with small noise."""

    def __init__(self, current: np.ndarray, seed: int = 0, speed: float = 1.6) -> None:
        self.rng = np.random.default_rng(seed)
        self.current = current
        self.speed = speed
        self.t = 0.0
        self.yaw = 0.3
        self.north = self.east = 0.0
        self.heading_sp = self.yaw
        self.rudder_override: float | None = None
        self.mode = "manual"
        self.thrust = 0.5

    def apply(self, commands) -> None:
        for c in commands:
            if isinstance(c, SetHeading):
                self.heading_sp = c.heading
            elif isinstance(c, OverrideActuator) and c.actuator == "rudder":
                self.rudder_override = c.value
            elif isinstance(c, ReleaseActuator) and c.actuator == "rudder":
                self.rudder_override = None
            elif isinstance(c, SetMode):
                self.mode = c.mode
            elif isinstance(c, SetThrust):
                self.thrust = c.thrust_level

    def step(self, dt: float) -> Telemetry:
        if self.rudder_override is not None:
            rate = 0.4 * self.rudder_override
        else:
            err = math.atan2(math.sin(self.heading_sp - self.yaw), math.cos(self.heading_sp - self.yaw))
            rate = float(np.clip(0.2 * err, -0.05, 0.05))
        self.yaw += rate * dt
        vn = self.speed * math.cos(self.yaw) + self.current[0]
        ve = self.speed * math.sin(self.yaw) + self.current[1]
        self.north += vn * dt
        self.east += ve * dt
        self.t += dt
        n = self.rng.normal(0, 1, 6)
        return Telemetry(
            time_s=round(self.t, 6), roll=0.0, pitch=0.0, yaw=math.atan2(math.sin(self.yaw), math.cos(self.yaw)) + 0.001 * n[0],
            yaw_rate=rate, north=self.north + 0.05 * n[1], east=self.east + 0.05 * n[2], down=10.0,
            vel_north=vn + 0.003 * n[3], vel_east=ve + 0.003 * n[4], vel_down=0.003 * n[5],
            rudder=self.rudder_override or 0.0, thrust_ratio=self.thrust, mode=self.mode,
        )


def run_behavior(behavior, vehicle, max_s: float, dt: float = 0.1):
    log = []
    while not behavior.done and vehicle.t < max_s:
        commands = list(behavior.step(vehicle.step(dt)))
        log.extend(commands)
        vehicle.apply(commands)
    return log


def test_square_behavior_recovers_current_and_restores():
    cur = current_vector(0.015, 220.0)
    vehicle = KinematicVehicle(cur, seed=1)
    behavior = SquarePattern(SquareConfig(thrust_ratio=0.8, leg_s=90.0))
    commands = run_behavior(behavior, vehicle, 500.0)
    assert behavior.done
    res = behavior.result()
    assert res.status == "completed"
    json.dumps(res.to_dict())  # the store keeps it as JSON
    fit = res.fit
    assert np.hypot(fit.current[0] - cur[0], fit.current[1] - cur[1]) < 0.003
    assert fit.surge == pytest.approx(1.6, abs=0.003)
    assert fit.condition_number < 1.2
    headings = [c.heading for c in commands if isinstance(c, SetHeading)]
    assert len(headings) == 4  # four legs; the procedure's restore point puts the found heading back
    assert SetThrust(0.8) in commands
    # what it may change is declared, so a procedure's restore point covers it
    assert {"mode", "thrust", "heading"} <= behavior.footprint.setpoints


def test_turn_behavior_fits_each_rudder_angle_and_releases():
    cur = current_vector(0.01, 45.0)
    vehicle = KinematicVehicle(cur, seed=2)
    behavior = SteadyTurns(TurnConfig(rudder_angles=(0.2, -0.2), turn_s=120.0, recover_s=20.0))
    commands = run_behavior(behavior, vehicle, 400.0)
    res = behavior.result()
    assert res.status == "completed", res
    json.dumps(res.to_dict())
    for turn, angle in zip(res.turns, (0.2, -0.2)):
        omega = 0.4 * angle
        assert turn.fit.radius == pytest.approx(1.6 / abs(omega), rel=0.01)
        assert turn.fit.rate == pytest.approx(omega, rel=0.01)
        assert np.hypot(turn.fit.current[0] - cur[0], turn.fit.current[1] - cur[1]) < 0.003
    assert commands.count(ReleaseActuator("rudder")) == 2
    assert vehicle.rudder_override is None


def test_turn_behavior_abort_releases_rudder_and_declares_what_it_touched():
    vehicle = KinematicVehicle(current_vector(0.01, 45.0), seed=3)
    behavior = SteadyTurns(TurnConfig())
    for _ in range(50):
        vehicle.apply(behavior.step(vehicle.step(0.1)))
    assert vehicle.rudder_override is not None
    commands = list(behavior.abort("operator"))
    vehicle.apply(commands)
    assert behavior.done and vehicle.rudder_override is None
    assert {"rudder", "heading", "mode"} <= behavior.footprint.setpoints  # restored by the procedure
    assert behavior.result().status == "aborted"
    assert behavior.step(vehicle.step(0.1)) == []


# --------------------------------------------------------------------------- the simulator's hugin preset
def test_hugin_square_recovers_current():
    cur = current_vector(0.012, 150.0)
    loop = HuginLoop(cur, seed=5)
    behavior = SquarePattern(SquareConfig(thrust_ratio=0.7, leg_s=150.0))
    loop.run(behavior, 700.0)
    res = behavior.result()
    assert res.status == "completed", res
    fit = res.fit
    assert np.hypot(fit.current[0] - cur[0], fit.current[1] - cur[1]) < 0.003
    assert angle_error_deg(fit.current_dir_deg, 150.0) < 15.0
    assert fit.sway == pytest.approx(-0.012, abs=0.003)  # the preset's straight-leg sway
    assert fit.condition_number < 1.3


def test_hugin_turns_recover_current_and_radius():
    cur = current_vector(0.015, 20.0)
    loop = HuginLoop(cur, seed=6)
    behavior = SteadyTurns(TurnConfig(thrust_ratio=0.54, rudder_angles=(0.218, -0.218), turn_s=150.0, recover_s=10.0))
    loop.run(behavior, 400.0)
    res = behavior.result()
    assert res.status == "completed", res
    for turn in res.turns:
        assert np.hypot(turn.fit.current[0] - cur[0], turn.fit.current[1] - cur[1]) < 0.003
        assert 12.0 < turn.fit.radius < 20.0  # the preset is tuned for ≈ 15.5 m at 0.218 rad
        assert turn.fit.residual_std < 0.15
