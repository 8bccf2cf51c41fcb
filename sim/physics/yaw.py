"""Yaw-rate and sway dynamics (SPEC C2/C3; thesis ch. 3 model made nonlinear).

ṙ = a22(V)·r + N_rr·r·|r| + b2(V)·(δr − δ0): its linearisation at r = 0 is the identification
model ṙ = a22·r + b2·(δr − δ0) (SPEC C3); b2 grows with V² as in Fig. 3.8.
"""
from __future__ import annotations

from dataclasses import dataclass

from sim.preset import Sway, Yaw


@dataclass(frozen=True)
class YawConstants:
    """The yaw and sway laws of a preset (see :class:`sim.preset.Yaw`, :class:`sim.preset.Sway`)."""

    a22_constant: float
    a22_per_speed: float
    b2_constant: float
    b2_per_speed_squared: float
    rudder_offset: float
    yaw_damping_quadratic: float
    authority_fade_speed: float
    sway_time_constant: float
    sway_bias: float
    sway_per_turn: float

    @classmethod
    def from_preset(cls, yaw: Yaw, sway: Sway) -> "YawConstants":
        return cls(
            yaw.a22_constant, yaw.a22_per_speed, yaw.b2_constant, yaw.b2_per_speed_squared,
            yaw.rudder_offset, yaw.yaw_damping_quadratic, yaw.authority_fade_speed,
            sway.time_constant, sway.bias, sway.per_turn,
        )


def yaw_damping(c: YawConstants, speed: float) -> float:
    """a22(V) = a22_constant + a22_per_speed·V (1/s)."""
    return c.a22_constant + c.a22_per_speed * speed


def rudder_authority(c: YawConstants, speed: float) -> float:
    """b2(V) = (b2_constant + b2_per_speed_squared·V²)·min(1, V/V_fade) (1/s²), Fig. 3.8 law."""
    fade = 1.0 if speed >= c.authority_fade_speed else max(speed, 0.0) / c.authority_fade_speed
    return (c.b2_constant + c.b2_per_speed_squared * speed * speed) * fade


def yaw_acceleration(c: YawConstants, speed: float, yaw_rate: float, rudder: float) -> float:
    """ṙ = a22(V)·r + N_rr·r|r| + b2(V)·(δr − δ0)."""
    return (
        yaw_damping(c, speed) * yaw_rate
        + c.yaw_damping_quadratic * yaw_rate * abs(yaw_rate)
        + rudder_authority(c, speed) * (rudder - c.rudder_offset)
    )


def sway_acceleration(c: YawConstants, speed: float, yaw_rate: float, sway: float) -> float:
    """v̇ = (v_ss − v)/T_v with v_ss = bias·min(1, V/0.3) + per_turn·V·r (no feedback into yaw)."""
    steady = c.sway_bias * min(1.0, speed / 0.3) + c.sway_per_turn * speed * yaw_rate
    return (steady - sway) / c.sway_time_constant
