"""Nonlinear roll with an internal rolling mass: thesis eq. 4.11 (SPEC C6, Table 4.1)."""
from __future__ import annotations

import math
from dataclasses import dataclass

from sim.preset import Roll


@dataclass(frozen=True)
class RollConstants:
    """Precomputed products of :class:`sim.preset.Roll`."""

    inverse_inertia: float  # 1/(I_xx − K_ṗ)
    y_g_weight: float  # y_g·W
    z_g_weight: float  # z_g·W
    mass_moment: float  # (m/M)·l·W
    damping_quadratic: float
    damping_linear: float
    propeller_torque_coefficient: float

    @classmethod
    def from_preset(cls, roll: Roll) -> "RollConstants":
        return cls(
            inverse_inertia=1.0 / (roll.inertia - roll.added_inertia),
            y_g_weight=roll.y_g * roll.weight,
            z_g_weight=roll.z_g * roll.weight,
            mass_moment=roll.moving_mass / roll.total_mass * roll.mass_arm * roll.weight,
            damping_quadratic=roll.damping_quadratic,
            damping_linear=roll.damping_linear,
            propeller_torque_coefficient=roll.propeller_torque_coefficient,
        )


def propeller_torque(c: RollConstants, thrust_ratio: float) -> float:
    """τ_prop ∝ ω² with ω ∝ TR (thesis eq. 4.8, Fig. 4.3)."""
    return c.propeller_torque_coefficient * thrust_ratio * thrust_ratio


def roll_acceleration(
    c: RollConstants, roll: float, roll_rate: float, mass_angle: float, external_moment: float
) -> float:
    """ṗ from eq. 4.11: (I_xx − K_ṗ)φ̈ = −(y_g + (m/M)l sin α)W cos φ + (z_g − (m/M)l cos α)W sin φ
    + K_pp p|p| + K_p p + τ (τ = propeller torque + disturbance, passed as ``external_moment``)."""
    moment = (
        -(c.y_g_weight + c.mass_moment * math.sin(mass_angle)) * math.cos(roll)
        + (c.z_g_weight - c.mass_moment * math.cos(mass_angle)) * math.sin(roll)
        + c.damping_quadratic * roll_rate * abs(roll_rate)
        + c.damping_linear * roll_rate
        + external_moment
    )
    return moment * c.inverse_inertia


def steady_roll(c: RollConstants, mass_angle: float, external_moment: float = 0.0) -> float:
    """Equilibrium roll angle for a mass angle (solves eq. 4.11 with p = ṗ = 0; scipy brentq)."""
    from scipy.optimize import brentq

    return brentq(lambda phi: roll_acceleration(c, phi, 0.0, mass_angle, external_moment), -1.5, 1.5)
