"""Linearised truth of a 3-DOF surface vessel: Nomoto's 2nd-order model and its first-order approximation.

Linearise the nonlinear model (``sim/physics/hull3dof.py`` + ``propulsion3dof.py``) about the straight
run at water speed U (``sim/physics/straight_run.py``: r = 0, v = 0, control at its trim δ0). Surge
decouples to first order (X depends on v·r, r² and δ², all of second order), leaving the linear
maneuvering model of sway and yaw (Fossen, linear maneuvering model / Nomoto models):

    M·[v̇, ṙ]ᵀ = F·[v, r]ᵀ + f·(δ − δ0),   M = [[m − Y_v̇, m·x_g − Y_ṙ], [m·x_g − N_v̇, I_z − N_ṙ]]

where F = ∂(Y, N)/∂(v, r) and f = ∂(Y, N)/∂δ are taken by central differences of the same force
functions the vessel integrates (so this stays right when the model changes). With A = M⁻¹F,
b = M⁻¹f and C = [0, 1] the yaw-rate transfer function is, for a 2×2 system,

    r/δ(s) = (b_r·s + a_rv·b_v − a_vv·b_r) / (s² − (a_vv + a_rr)·s + det A)
           = K·(1 + T3·s) / ((1 + T1·s)(1 + T2·s))                              (Nomoto, 2nd order)

    K = (a_rv·b_v − a_vv·b_r)/det A,   T3 = b_r/(a_rv·b_v − a_vv·b_r),
    T1·T2 = 1/det A,   T1 + T2 = −tr A/det A   (T1, T2 = −1/poles, T1 ≥ T2).

The first-order Nomoto model r/δ = K/(1 + T·s) keeps K and matches the low-frequency phase
(the first moment of the impulse response): **T = T1 + T2 − T3** (Fossen, Nomoto's first-order
approximation). A twin-thruster vessel's steering acts through the propeller shafts' lag
T_lag = ``thruster.time_constant`` (the autopilot's outputs are motor demands), one more pole
1/(1 + T_lag·s) in series, which the same rule adds: T = T1 + T2 + T_lag − T3 (T_lag = 0 for a
rudder, whose SERVO_OUTPUT_RAW is its actual angle). The identification model ṙ = a22·r + b2·(δ − δ0)
is that first-order model: **a22 = −1/T, b2 = K/T**, δ0 the straight-run trim.

The input δ is the rudder angle (rad) for a rudder vessel and, for a twin-thruster vessel, the
equivalent rudder δ = s·``FULL_SCALE_RAD`` of the normalised steering s (±1) that ArduPilot's skid mix
turns into motor demands (``sim.skid_mixer``); ``b2_per_steering`` = b2·FULL_SCALE_RAD is per unit s.

**Skid authority law** (documented here, checked in tests/test_sim_skid.py). Around throttle t with
steering s the motors run at d = t ± s and, while both are ahead and above the dead zone, the yaw
moment is N = y_arm·(F(t + s) − η_R·F(t − s)); with matched motors

    N_s = ∂N/∂s = y_arm·(F′(t + s0) + η_R·F′(t − s0)) ≈ 2·y_arm·F′(t),   F(d) = a·d² + b·d + c
        = 2·y_arm·(2a·t + b)          — proportional to the mean throttle (b = 0 here),

whereas a rudder gives N_δ = −x_R·k_L·U² (∝ U²). With quadratic thrust and quadratic surge drag the
straight-run speed is U = t·√(2a/(−X_|u|u)) (X_u = 0), so t ∝ U and N_s ∝ U. The first-order
authority is b2 = N_s·κ(U)/δ_fs with κ(U) = K_N/T the hull's b2 per unit yaw moment (K_N its gain
for a pure yaw moment, T including T_lag); κ changes slowly with U, so b2_skid ≈ c·U whereas
b2_rudder ≈ c′·U².
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from sim.params import FULL_SCALE_RAD
from sim.physics.hull3dof import HullConstants, hull_forces
from sim.physics.propulsion3dof import RudderConstants, rudder_forces, twin_thruster_forces
from sim.physics.straight_run import StraightRun, straight_run_at_speed
from sim.preset import Preset

_STEP = 1e-6


@dataclass(frozen=True)
class Nomoto:
    """Nomoto's 2nd-order model K(1 + T3 s)/((1 + T1 s)(1 + T2 s)) of a 2×2 sway–yaw system.
    T1, T2 are None when the poles are complex (their sum is still real)."""

    K: float
    T1: float | None
    T2: float | None
    T3: float
    sum_T1_T2: float

    def first_order_T(self, input_lag: float = 0.0) -> float:
        """Nomoto's first-order time constant T = T1 + T2 (+ an input lag) − T3."""
        return self.sum_T1_T2 + input_lag - self.T3


def nomoto_from_state_space(a: tuple[tuple[float, float], tuple[float, float]], b: tuple[float, float]) -> Nomoto:
    """K, T1, T2, T3 of ẋ = A·x + b·δ, x = (v, r), output r (see the module docstring)."""
    (a_vv, a_vr), (a_rv, a_rr) = a
    b_v, b_r = b
    det = a_vv * a_rr - a_vr * a_rv
    trace = a_vv + a_rr
    if det <= 0.0 or trace >= 0.0:
        raise ValueError(f"the sway–yaw system is not stable on a straight course (det {det:.4g}, trace {trace:.4g})")
    numerator = a_rv * b_v - a_vv * b_r
    gain = numerator / det
    lead = b_r / numerator
    discriminant = trace * trace - 4.0 * det
    if discriminant >= 0.0:
        root = math.sqrt(discriminant)
        poles = (0.5 * (trace + root), 0.5 * (trace - root))  # slow pole first
        t1, t2 = -1.0 / poles[0], -1.0 / poles[1]
    else:
        t1 = t2 = None
    return Nomoto(K=gain, T1=t1, T2=t2, T3=lead, sum_T1_T2=-trace / det)


def _sway_yaw_forces(preset: Preset, hull: HullConstants, run: StraightRun, v: float, r: float,
                     delta: float) -> tuple[float, float]:
    """(Y, N) at surge = the run's speed, sway v, yaw rate r and input δ (rad, or equivalent rudder)."""
    _, y, n = hull_forces(hull, run.speed, v, r)
    if preset.is_skid:
        s = run.steering + delta / FULL_SCALE_RAD
        _, cy, cn = twin_thruster_forces(preset.twin_thrusters, preset.thruster, run.thrust_ratio + s, run.thrust_ratio - s)
    else:
        _, cy, cn = rudder_forces(RudderConstants.from_preset(preset.rudder), run.speed, run.steering + delta)
    return y + cy, n + cn


def sway_yaw_state_space(preset: Preset, run: StraightRun, unit_moment: bool = False):
    """(A, b) of the sway–yaw linearisation about ``run``; ``unit_moment`` replaces the control by a
    pure yaw moment of 1 N·m (the hull's own response, κ of the skid law)."""
    hull = HullConstants.from_preset(preset.hull)

    def partial(index: int) -> tuple[float, float]:
        plus = [0.0, 0.0, 0.0]
        minus = [0.0, 0.0, 0.0]
        plus[index], minus[index] = _STEP, -_STEP
        yp, np_ = _sway_yaw_forces(preset, hull, run, *plus)
        ym, nm = _sway_yaw_forces(preset, hull, run, *minus)
        return (yp - ym) / (2 * _STEP), (np_ - nm) / (2 * _STEP)

    (y_v, n_v), (y_r, n_r) = partial(0), partial(1)
    f = (0.0, 1.0) if unit_moment else partial(2)
    inv = ((hull.inv_vv, hull.inv_vr), (hull.inv_rv, hull.inv_rr))
    columns = ((y_v, n_v), (y_r, n_r))  # F = ∂(Y, N)/∂(v, r), column by column; A = M⁻¹·F
    a = tuple(tuple(inv[i][0] * col[0] + inv[i][1] * col[1] for col in columns) for i in range(2))
    b = tuple(inv[i][0] * f[0] + inv[i][1] * f[1] for i in range(2))
    return a, b


def input_lag(preset: Preset) -> float:
    """The lag between the autopilot's steering output and the control force: the propeller shafts'
    for a twin-thruster vessel, none for a rudder (its reported angle is the actual one)."""
    return preset.thruster.time_constant if preset.is_skid else 0.0


def linearized_3dof(preset: Preset, speed: float) -> dict:
    """The truth at water speed ``speed``: a22, b2, delta0, speed (the first-order model) plus
    K, T, T1, T2, T3, T_lag (Nomoto), the steady thrust ratio and the model's name."""
    run = straight_run_at_speed(preset, speed)
    a, b = sway_yaw_state_space(preset, run)
    nomoto = nomoto_from_state_space(a, b)
    lag = input_lag(preset)
    time_constant = nomoto.first_order_T(lag)
    delta0 = run.steering * FULL_SCALE_RAD if preset.is_skid else run.steering
    result = {
        "a22": -1.0 / time_constant,
        "b2": nomoto.K / time_constant,
        "delta0": delta0,
        "speed": speed,
        "K": nomoto.K,
        "T": time_constant,
        "T1": nomoto.T1,
        "T2": nomoto.T2,
        "T3": nomoto.T3,
        "T_lag": lag,
        "thrust_ratio": run.thrust_ratio,
        "model": "3dof-skid" if preset.is_skid else "3dof-rudder",
        "input": "equivalent rudder s*0.5236 rad (s: normalised steering)" if preset.is_skid else "rudder rad",
    }
    if preset.is_skid:
        result["b2_per_steering"] = result["b2"] * FULL_SCALE_RAD
    return result
