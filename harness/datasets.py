"""Synthetic data sets shared by the tests and the bench scripts (no pytest needed).

* ROMEO regime points and surge experiment (SPEC §3.8, the seed's lumped-parameter chapter):
  :func:`romeo_points`, :func:`surge_experiment` and the seed's numbers ``K_R``, ``ETA``, ``J_LS``.
* Steady-state manoeuvres under a known current (SPEC C8): a small kinematic vehicle flying a square
  (:func:`synth_square`) or a turn (:func:`synth_turn`), :func:`current_vector` and
  :func:`angle_error_deg` to score a current direction.

Every generator is deterministic for its ``seed``.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from companion.numerics import lumped
from companion.numerics.steady_state import body_to_ned_matrices, ned_to_body

# SPEC §3.8, Watson data, experiment B: ηLNB k_r 36.11, η 0.89, J_LS 6.13, ν 12 (14 regime points)
K_R, ETA, J_LS, DOF = 36.11, 0.89, 6.13, 12
NOISE = math.sqrt(J_LS / DOF)  # the residual σ (N·m) that gives the seed's J_LS/ν


def romeo_points(seed: int, k: float = K_R, kq: float = 0.0, eta: float = ETA, noise: float = NOISE):
    """14 yaw regime points: 7 positive torques with the reference (unit-efficiency) mapping, 7
    negative torques with the mapping of efficiency η; steady state k·r + k_q·r|r| = η_i·τ + ε."""
    rng = np.random.default_rng(seed)
    force = np.concatenate([np.linspace(1.0, 6.5, 7), -np.linspace(1.0, 6.5, 7)])
    second = np.r_[np.zeros(7, bool), np.ones(7, bool)]
    effective = np.where(second, eta, 1.0) * force + rng.normal(0.0, noise, force.size)
    if kq == 0.0:
        velocity = effective / k
    else:  # solve k·r + kq·r|r| = effective for r
        velocity = np.sign(effective) * (-k + np.sqrt(k * k + 4 * kq * np.abs(effective))) / (2 * kq)
    return velocity, force, second


def surge_experiment(mass=675.0, k=38.0, kq=333.0, f0=35.0, df=20.0, periods=4, dt=0.1):
    """ROMEO surge (seed §4.2.9): force f0 + df·sin(ω_opt·t) at the D-optimal frequency, exact
    integration of m·u̇ = f − k·u − k_q·u|u|; returns ``(t, x, u, force)`` sampled every ``dt``."""
    u0 = (-k + math.sqrt(k * k + 4 * kq * f0)) / (2 * kq)
    omega = lumped.d_optimal_frequency(mass, k, kq, u0)
    t = np.arange(0.0, periods * 2 * math.pi / omega, dt)

    def rhs(time, s):
        return [s[1], (lumped.sine_excitation(time, f0, df, omega) - k * s[1] - kq * s[1] * abs(s[1])) / mass]

    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, u0], t_eval=t, rtol=1e-10, atol=1e-12)
    return t, sol.y[0], sol.y[1], lumped.sine_excitation(t, f0, df, omega)


# --------------------------------------------------------------------------- steady state
def current_vector(speed: float, direction_deg: float) -> np.ndarray:
    """(north, east) of a current flowing towards ``direction_deg``."""
    a = math.radians(direction_deg)
    return np.array([speed * math.cos(a), speed * math.sin(a)])


def synth_square(
    current: np.ndarray,
    seed: int,
    surge: float = 1.8,
    sway: float = -0.012,
    heave: float = 0.05,
    leg_s: float = 150.0,
    first_heading_deg: float = 20.0,
    dt: float = 0.5,
    vel_noise: float = 0.005,
    pos_noise: float = 0.2,
    yaw_noise_deg: float = 0.1,
    max_rate_deg_s: float = 3.0,
) -> dict[str, np.ndarray]:
    """Square pattern with turns (rate-limited heading response), a surge dip and sway spikes in
    the turns, over a constant current. Body velocity over ground (u, v, w) and positions noisy."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 4 * leg_s, dt)
    setpoint = np.radians(first_heading_deg + 90.0 * np.floor(t / leg_s))
    yaw = np.empty_like(t)
    psi = setpoint[0]
    max_step = math.radians(max_rate_deg_s) * dt
    for i, sp in enumerate(setpoint):
        psi += float(np.clip(0.1 * (sp - psi), -max_step, max_step))
        yaw[i] = psi
    rate = np.gradient(yaw, t)
    turning = np.abs(rate) / math.radians(max_rate_deg_s)
    # slow recovery of the surge after each turn (first-order, 10 s)
    dip = np.zeros_like(t)
    for i in range(1, t.size):
        dip[i] = dip[i - 1] + dt / 10.0 * (0.15 * turning[i] - dip[i - 1])
    v_wb = np.column_stack([surge * (1 - dip), sway + 0.3 * rate, np.full_like(t, heave)])
    roll = rng.normal(0.0, math.radians(0.2), t.size)
    pitch = np.full_like(t, math.radians(2.0))
    r_mb = body_to_ned_matrices(roll, pitch, yaw)
    vel_ned = np.einsum("nij,nj->ni", r_mb, v_wb) + np.array([current[0], current[1], 0.0])
    pos = np.cumsum(vel_ned * dt, axis=0)
    yaw_meas = np.arctan2(np.sin(yaw), np.cos(yaw)) + rng.normal(0, math.radians(yaw_noise_deg), t.size)
    vel_body = ned_to_body(roll, pitch, yaw_meas, vel_ned) + rng.normal(0, vel_noise, (t.size, 3))
    return {
        "t": t, "north": pos[:, 0] + rng.normal(0, pos_noise, t.size), "east": pos[:, 1] + rng.normal(0, pos_noise, t.size),
        "down": pos[:, 2], "roll": roll, "pitch": pitch, "yaw": yaw_meas, "vel_body": vel_body,
        "vel_ned": vel_ned, "true_rate": rate,
    }


def synth_turn(
    current: np.ndarray,
    seed: int,
    rate_deg_s: float = 5.0,
    speed: float = 1.4,
    duration_s: float = 240.0,
    dt: float = 1.0,
    pos_noise: float = 0.1,
    lag_s: float = 10.0,
    heading0_deg: float = 35.0,
) -> dict[str, np.ndarray]:
    """A turn from a straight course: heading rate → ω with a first-order lag, speed loss 10 %;
    water-relative path integrated finely (10 ms) then sampled every ``dt`` with position noise."""
    rng = np.random.default_rng(seed)
    fine = 0.01
    tf = np.arange(0.0, duration_s + fine / 2, fine)
    omega = math.radians(rate_deg_s)
    rate = omega * (1 - np.exp(-tf / lag_s))
    yaw = math.radians(heading0_deg) + np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * fine)])
    u = speed * (1.0 - 0.1 * (1 - np.exp(-tf / lag_s)))  # water-relative speed along the heading
    vn = u * np.cos(yaw) + current[0]
    ve = u * np.sin(yaw) + current[1]
    north = np.concatenate([[0.0], np.cumsum(0.5 * (vn[1:] + vn[:-1]) * fine)])
    east = np.concatenate([[0.0], np.cumsum(0.5 * (ve[1:] + ve[:-1]) * fine)])
    step = int(round(dt / fine))
    sl = slice(0, None, step)
    n = tf[sl].size
    return {
        "t": tf[sl], "north": north[sl] + rng.normal(0, pos_noise, n), "east": east[sl] + rng.normal(0, pos_noise, n),
        "yaw": np.arctan2(np.sin(yaw[sl]), np.cos(yaw[sl])) + rng.normal(0, math.radians(0.1), n),
        "radius": 0.9 * speed / abs(omega), "rate": omega,
    }


def angle_error_deg(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)
