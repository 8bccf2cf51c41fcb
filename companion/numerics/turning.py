"""Turning performance predicted from the identified yaw model (SPEC C5; thesis 002 §3.6.1, eq. 3.40–3.50).

Trapezoidal yaw-rate profile for a U-turn (Fig. 3.12): the rate rises to ψ̇max in t1, is held for
t2, and falls in t1, so that ψ̇max·(t1 + t2) = π (eq. 3.43):

    ψ̇max = b2·(δmax − δ0)/(−a22)                 (eq. 3.47, the first-order step response limit)
    t1   = 4/(−a22)                               (eq. 3.48, four time constants)
    Tπ   = −π·(a22/(b2·(δmax − δ0)) + 4/(a22·π))  (eq. 3.49)  = t1 + π/ψ̇max
    R    = V·Tπ/π                                 (eq. 3.40, 3.50)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .identification import YawModel

#: rudder limit of the thesis (stall), rad
DEFAULT_DELTA_MAX = 0.26


@dataclass
class TurningPerformance:
    yaw_rate_max: float  # rad/s
    yaw_rate_max_deg_s: float
    settle_time_s: float  # t1
    u_turn_time_s: float  # Tπ
    turning_radius_m: float  # R


def turning_performance(model: YawModel, speed: float, delta_max: float = DEFAULT_DELTA_MAX) -> TurningPerformance:
    """Eq. 3.47–3.50 for a turn at full rudder ``delta_max`` (rad) towards the side away from δ0.

    Requires a22 < 0, b2 > 0, speed ≥ 0 and δmax > δ0 (otherwise the rudder cannot hold a turn:
    ValueError).
    """
    a22, b2, delta0 = float(model.a22), float(model.b2), float(model.delta0)
    if not all(math.isfinite(v) for v in (a22, b2, delta0, speed, delta_max)):
        raise ValueError("inputs must be finite")
    if a22 >= 0.0:
        raise ValueError(f"a22 must be negative, got {a22}")
    if b2 <= 0.0:
        raise ValueError(f"b2 must be positive, got {b2}")
    if speed < 0.0:
        raise ValueError(f"speed must be non-negative, got {speed}")
    effective = delta_max - delta0
    if effective <= 0.0:
        raise ValueError(f"delta_max ({delta_max}) must exceed delta0 ({delta0})")
    yaw_rate_max = b2 * effective / (-a22)
    settle = 4.0 / (-a22)
    u_turn = -math.pi * (a22 / (b2 * effective) + 4.0 / (a22 * math.pi))
    return TurningPerformance(
        yaw_rate_max=yaw_rate_max,
        yaw_rate_max_deg_s=math.degrees(yaw_rate_max),
        settle_time_s=settle,
        u_turn_time_s=u_turn,
        turning_radius_m=speed * u_turn / math.pi,
    )
