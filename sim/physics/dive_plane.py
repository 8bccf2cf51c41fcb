"""Surge, heave and pitch of the dive plane: thesis eq. 5.3–5.13 (SPEC C2, §3.4).

The thesis writes E·T(x)·ẋ = R(x) + F(x, u) in the states (V, α, q, θ). Since T(x)·[V̇, α̇] is
just [u̇, ẇ] with u = V cos α, w = V sin α (eq. 5.2), we integrate the equivalent body-velocity
form E·[u̇, ẇ, q̇] = R + F, which has no 1/V singularity when the vehicle is at rest. All terms are
rewritten with V cos α = u and V sin α = w; hand-written in plain floats for step speed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.preset import DivePlane


@dataclass(frozen=True)
class DivePlaneConstants:
    """Precomputed products of :class:`sim.preset.DivePlane` used by every step."""

    mass: float
    mass_surge: float
    mass_heave: float
    x_cg: float
    z_cg: float
    weight: float
    excess_weight: float  # F_W − F_B
    half_rho_ab: float  # ½ρA_b
    half_rho_af: float  # ½ρA_f
    drag_coefficient: float
    lift_alpha: float
    lift_elevator: float
    length: float
    fin_arm: float
    moment_alpha: float
    moment_pitch_rate: float
    pitch_damping_linear: float
    inverse_inertia: tuple[tuple[float, float, float], ...]  # E⁻¹ (3×3 block of eq. 5.5)

    @classmethod
    def from_preset(cls, dp: DivePlane) -> "DivePlaneConstants":
        inertia = np.array(
            [
                [dp.mass_surge, 0.0, dp.mass * dp.z_cg],
                [0.0, dp.mass_heave, -dp.mass * dp.x_cg],
                [dp.mass * dp.z_cg, -dp.mass * dp.x_cg, dp.inertia_pitch],
            ]
        )
        inverse = np.linalg.inv(inertia)
        return cls(
            mass=dp.mass,
            mass_surge=dp.mass_surge,
            mass_heave=dp.mass_heave,
            x_cg=dp.x_cg,
            z_cg=dp.z_cg,
            weight=dp.weight,
            excess_weight=dp.weight - dp.buoyancy,
            half_rho_ab=0.5 * dp.rho * dp.area_body,
            half_rho_af=0.5 * dp.rho * dp.area_fin,
            drag_coefficient=dp.drag_coefficient,
            lift_alpha=dp.lift_alpha,
            lift_elevator=dp.lift_elevator,
            length=dp.length,
            fin_arm=dp.fin_arm,
            moment_alpha=dp.moment_alpha,
            moment_pitch_rate=dp.moment_pitch_rate,
            pitch_damping_linear=dp.pitch_damping_linear,
            inverse_inertia=tuple(tuple(float(x) for x in row) for row in inverse),
        )


def dive_plane_forces(
    c: DivePlaneConstants, surge: float, heave: float, pitch_rate: float, pitch: float,
    elevator: float, thrust: float,
) -> tuple[float, float, float]:
    """R(x) + F(x, u) of eq. 5.6–5.13 in body-velocity form: (X, Z, M) in N, N, N·m."""
    speed_sq = surge * surge + heave * heave
    speed = math.sqrt(speed_sq)
    alpha = math.atan2(heave, surge) if speed > 1e-9 else 0.0
    q = pitch_rate
    sin_t = math.sin(pitch)
    cos_t = math.cos(pitch)
    # eq. 5.11: F_D = ½ρV²A_b·C_D0 → cos α·F_D = ½ρA_b·C_D0·V·u, sin α·F_D = ½ρA_b·C_D0·V·w
    drag_per_velocity = c.half_rho_ab * c.drag_coefficient * speed
    # eq. 5.12: F_L = ½ρV²(A_b C_Lα α + A_f C_Lδ δ) → cos α·F_L = lift_per_velocity·u, etc.
    lift_per_velocity = speed * (c.half_rho_ab * c.lift_alpha * alpha + c.half_rho_af * c.lift_elevator * elevator)
    # eq. 5.8, 5.9
    force_x = drag_per_velocity * surge - lift_per_velocity * heave - c.excess_weight * sin_t + thrust
    force_z = drag_per_velocity * heave + lift_per_velocity * surge + c.excess_weight * cos_t
    # eq. 5.13 and 5.10
    moment = (
        speed_sq * (c.half_rho_ab * c.length * (c.moment_alpha * alpha + c.moment_pitch_rate * q)
                    + c.half_rho_af * c.fin_arm * c.lift_elevator * elevator)
        - (c.x_cg * cos_t + c.z_cg * sin_t) * c.weight
        + c.pitch_damping_linear * q
    )
    # eq. 5.6 with V cos α = u, V sin α = w
    m = c.mass
    r_x = -c.mass_heave * q * heave - m * c.x_cg * q * q
    r_z = c.mass_surge * q * surge + m * c.z_cg * q * q
    r_m = (c.mass_heave - c.mass_surge) * surge * heave - m * (c.x_cg * surge + c.z_cg * heave) * q
    return r_x + force_x, r_z + force_z, r_m + moment


def dive_plane_accelerations(
    c: DivePlaneConstants, surge: float, heave: float, pitch_rate: float, pitch: float,
    elevator: float, thrust: float,
) -> tuple[float, float, float]:
    """(u̇, ẇ, q̇) = E⁻¹·(R + F), eq. 5.3 with T(x)·[V̇, α̇] = [u̇, ẇ]."""
    fx, fz, my = dive_plane_forces(c, surge, heave, pitch_rate, pitch, elevator, thrust)
    (a11, a12, a13), (a21, a22, a23), (a31, a32, a33) = c.inverse_inertia
    return (
        a11 * fx + a12 * fz + a13 * my,
        a21 * fx + a22 * fz + a23 * my,
        a31 * fx + a32 * fz + a33 * my,
    )


def depth_rate(surge: float, heave: float, pitch: float) -> float:
    """ż = V(−cos α sin θ + sin α cos θ) = −u sin θ + w cos θ (eq. 5.1), depth positive down."""
    return -surge * math.sin(pitch) + heave * math.cos(pitch)
