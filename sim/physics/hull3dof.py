"""Surge–sway–yaw (3 DOF) manoeuvring model of a surface vessel, after Fossen's handbook.

Source: T. I. Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control*, Wiley 2011 /
2nd ed. 2021 — the 3-DOF horizontal-plane model of the maneuvering-theory and ship-model chapters
(ch. 6–7): rigid-body kinetics with added mass, the Coriolis–centripetal matrices of the rigid body
and of the added mass, and linear plus nonlinear damping. The matrix forms below were checked
against Fossen's own code (``cybergalactic/PythonVehicleSimulator``: ``lib/gnc.py`` ``m2c`` for
C_A, ``vehicles/otter.py`` for M_RB, C_RB and the damping, ``lib/models.py`` ``clarke83`` for
speed-proportional linear derivatives). Equation numbers differ between the two editions, so the
forms are written out here in full:

    M·ν̇ + C_RB(ν)·ν + C_A(ν)·ν + D(ν)·ν = τ,      ν = [u, v, r]ᵀ (water-relative)

    M = M_RB + M_A,
    M_RB = [[m, 0, 0], [0, m, m·x_g], [0, m·x_g, I_z]]
    M_A  = −[[X_u̇, 0, 0], [0, Y_v̇, Y_ṙ], [0, N_v̇, N_ṙ]]

    C_RB(ν) = [[0, 0, −m(x_g·r + v)], [0, 0, m·u], [m(x_g·r + v), −m·u, 0]]
    C_A(ν)  = [[0, 0, Y_v̇·v + Y_ṙ·r], [0, 0, −X_u̇·u], [−Y_v̇·v − Y_ṙ·r, X_u̇·u, 0]]

(C_A from the symmetrised M_A, as ``m2c`` does: Y_ṙ here is ½(Y_ṙ + N_v̇).) Written out, the
Coriolis–centripetal forces −(C_RB + C_A)·ν are

    X_C = (m − Y_v̇)·v·r + (m·x_g − Y_ṙ)·r²
    Y_C = −(m − X_u̇)·u·r
    N_C = (Y_v̇ − X_u̇)·u·v − (m·x_g − Y_ṙ)·u·r

X_C is the speed loss in a turn (v·r < 0 in a steady turn: the vessel drifts outward), Y_C the
centripetal force, and the first term of N_C the **Munk moment**, which turns a hull broadside to
the flow (destabilising; Y_v̇ < X_u̇ < 0).

Damping −D(ν)·ν, linear derivatives made speed dependent as in the linear maneuvering model, where
they are proportional to U (Clarke et al. 1983 via Fossen, ``clarke83``: Y_v = ½ρL²U·Y_v′ …), plus a
speed-independent part (the Otter's constant linear damping, dominant at low speed) and quadratic
terms (surge drag, the cross-flow drag of strip theory lumped into Y_|v|v and N_|r|r):

    X_D = X_u·u + X_|u|u·|u|·u
    Y_D = (Y_v + Y_vU·U)·v + (Y_r + Y_rU·U)·r + Y_|v|v·|v|·v
    N_D = (N_v + N_vU·U)·v + (N_r + N_rU·U)·r + N_|r|r·|r|·r,        U = √(u² + v²)

The origin of the body frame is the centre of gravity unless ``x_g`` says otherwise. A constant,
irrotational current enters only the kinematics (ν is water-relative), as in the rest of the
simulator. Plain floats, no numpy, for step speed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from sim.preset import Hull


@dataclass(frozen=True)
class HullConstants:
    """Products of a :class:`sim.preset.Hull` used every step: masses and the inverse sway–yaw block."""

    mass: float
    mass_x_g: float  # m·x_g
    surge_mass: float  # m − X_u̇
    sway_mass: float  # m − Y_v̇
    added_sway_yaw: float  # ½(Y_ṙ + N_v̇), the symmetrised off-diagonal added mass
    munk: float  # Y_v̇ − X_u̇ (N·s²/m², negative: destabilising)
    x_u: float
    x_uu: float
    y_v: float
    y_v_speed: float
    y_r: float
    y_r_speed: float
    y_vv: float
    n_v: float
    n_v_speed: float
    n_r: float
    n_r_speed: float
    n_rr: float
    # inverse of the sway–yaw block [[m − Y_v̇, m·x_g − Y_ṙ], [m·x_g − N_v̇, I_z − N_ṙ]]
    inv_vv: float
    inv_vr: float
    inv_rv: float
    inv_rr: float

    @classmethod
    def from_preset(cls, hull: Hull) -> "HullConstants":
        m22 = hull.mass - hull.y_vdot
        m23 = hull.mass * hull.x_g - hull.y_rdot
        m32 = hull.mass * hull.x_g - hull.n_vdot
        m33 = hull.inertia_yaw - hull.n_rdot
        det = m22 * m33 - m23 * m32
        if det <= 0.0 or hull.mass - hull.x_udot <= 0.0:
            raise ValueError("hull: the mass matrix M = M_RB + M_A must be positive definite")
        return cls(
            mass=hull.mass,
            mass_x_g=hull.mass * hull.x_g,
            surge_mass=hull.mass - hull.x_udot,
            sway_mass=m22,
            added_sway_yaw=0.5 * (hull.y_rdot + hull.n_vdot),
            munk=hull.y_vdot - hull.x_udot,
            x_u=hull.x_u, x_uu=hull.x_uu,
            y_v=hull.y_v, y_v_speed=hull.y_v_speed, y_r=hull.y_r, y_r_speed=hull.y_r_speed, y_vv=hull.y_vv,
            n_v=hull.n_v, n_v_speed=hull.n_v_speed, n_r=hull.n_r, n_r_speed=hull.n_r_speed, n_rr=hull.n_rr,
            inv_vv=m33 / det, inv_vr=-m23 / det, inv_rv=-m32 / det, inv_rr=m22 / det,
        )

    def scaled_yaw_damping(self, factor: float) -> "HullConstants":
        """The same hull with its yaw damping N_r, N_rU and N_|r|r scaled (a ``damping`` fault)."""
        from dataclasses import replace

        return replace(self, n_r=self.n_r * factor, n_r_speed=self.n_r_speed * factor, n_rr=self.n_rr * factor)


def hull_forces(c: HullConstants, u: float, v: float, r: float) -> tuple[float, float, float]:
    """(X, Y, N) = −C_RB(ν)ν − C_A(ν)ν − D(ν)ν in N, N, N·m (see the module docstring)."""
    speed = math.sqrt(u * u + v * v)
    mixed = c.mass_x_g - c.added_sway_yaw  # m·x_g − Y_ṙ
    x = c.sway_mass * v * r + mixed * r * r + c.x_u * u + c.x_uu * abs(u) * u
    y = (-c.surge_mass * u * r
         + (c.y_v + c.y_v_speed * speed) * v + (c.y_r + c.y_r_speed * speed) * r + c.y_vv * abs(v) * v)
    n = (c.munk * u * v - mixed * u * r
         + (c.n_v + c.n_v_speed * speed) * v + (c.n_r + c.n_r_speed * speed) * r + c.n_rr * abs(r) * r)
    return x, y, n


def accelerations(c: HullConstants, force_x: float, force_y: float, moment_n: float) -> tuple[float, float, float]:
    """ν̇ = M⁻¹·(X, Y, N): surge decouples (M_RB and M_A have no surge–sway/yaw terms)."""
    return (
        force_x / c.surge_mass,
        c.inv_vv * force_y + c.inv_vr * moment_n,
        c.inv_rv * force_y + c.inv_rr * moment_n,
    )
