"""Native gains of PX4's rover and UUV heading controllers from the identified yaw model (SPEC C5).

The plant is the identified ṙ = a22·r + b2·δ (δ the rudder in rad). The design targets are those
of the ArduPilot cascade (``CascadeRules``: a rate bandwidth ωr, an integral a decade slower, the
heading loop at ζ = 0.7071), written in each controller's own structure (docs/method.md §6).

**Ackermann rover** (``rover_ackermann``; eq. P.1–P.4): the heading P gives r_d = RO_YAW_P·(ψd − ψ),
the rate loop steers δ = atan(r_d·L/û)·RO_YAW_RATE_CORR + P·(r_d − r) + I·∫(r_d − r), in radians of
PX4's steering angle (= the rudder: the profile checks RA_MAX_STR_ANG equals the rudder full scale)
with û = throttle·RO_MAX_THR_SPEED, PX4's speed estimate. The steady turn needs δ/r = −a22/b2, so
the feed-forward is exact with CORR = 1 and the **equivalent wheel base** L = (−a22/b2)·u (P.1): the
bicycle model's L/u is the boat's steady-turn ratio. The same L makes PX4's feasible-yaw-rate limit
u·tan(δmax)/L the boat's steady turn rate at full rudder. P = (ωr + a22)/b2 (P.2), I = ωr_a/(N·b2)
(P.3), RO_YAW_P = ρ·ωr_a (P.4, ρ = 0.5), as the cascade rule. b2 ∝ u² makes L ∝ 1/u: the schedule
supplies it. The cascade's feed-forward scale κ (``CascadeRules.ff_scale``, 1 by default) is PX4's own
correction factor of that feed-forward, RO_YAW_RATE_CORR = κ: L stays the boat's, and so does the
feasible-yaw-rate limit it sets.

**UUV** (``uuv_att_control``; eq. P.5–P.6): the yaw torque τ ∈ [−1, 1] is −UUV_YAW_P·sin(ψ − ψd)
− UUV_YAW_D·(r − r_d), and δ = τ·δfs (δfs the equivalent rudder of full torque), so with b = b2·δfs
the heading loop is s² + (−a22 + b·D)·s + b·P. D = (ωr + a22)/b places the rate pole at −ωr (P.5),
P = ρ·ωr_a²/b puts the heading loop at ζ = 1/(2√ρ) (P.6; ρ = 0.5: ζ = 0.7071). PX4's UUV loop has
no integrator: a rudder offset δ0 leaves a heading error b2·δ0/(b·P) (0.3° at P = 4 on our AUV,
0.05° at the design).

Every gain is kept inside the profile's ranges (``CascadeRules`` fields: RO_YAW_P, RO_YAW_RATE_P/I
and RA_WHEEL_BASE 0–100 as PX4 documents them; UUV_YAW_P ≤ 40 and UUV_YAW_D ≤ 20, ten times the
defaults, where PX4 documents none). A clamped gain is listed in ``clamped`` with the damping the
clamped gains give, so a check can refuse them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .cascade_gains import CascadeRules, _clamp
from .identification import YawModel


@dataclass
class AckermannGains:
    angle_p: float  # RO_YAW_P
    rate_p: float  # RO_YAW_RATE_P, rad of steering per rad/s
    rate_i: float  # RO_YAW_RATE_I
    ff_length: float  # RA_WHEEL_BASE, m (equivalent wheel base)
    rate_bandwidth: float  # ωr_a, rad/s
    heading_damping: float
    ff_correction: float = 1.0  # RO_YAW_RATE_CORR
    speed: float | None = None
    clamped: tuple[str, ...] = ()

    def params(self) -> dict[str, float]:
        """Neutral parameter names (companion.link.autopilots.px4_rover)."""
        return {"heading_ff_length": self.ff_length, "heading_ff_correction": self.ff_correction,
                "heading_rate_p": self.rate_p, "heading_rate_i": self.rate_i, "heading_angle_p": self.angle_p}


@dataclass
class UuvGains:
    angle_p: float  # UUV_YAW_P, torque per rad of heading error
    rate_d: float  # UUV_YAW_D, torque per rad/s
    rate_bandwidth: float  # ωr_a, rad/s
    heading_damping: float
    speed: float | None = None
    clamped: tuple[str, ...] = ()

    def params(self) -> dict[str, float]:
        """Neutral parameter names (companion.link.autopilots.px4_uuv)."""
        return {"heading_angle_p": self.angle_p, "heading_rate_d": self.rate_d}


def _plant(model: YawModel) -> tuple[float, float]:
    a22, b2 = float(model.a22), float(model.b2)
    if not (math.isfinite(a22) and math.isfinite(b2)) or a22 >= 0.0 or b2 <= 0.0:
        raise ValueError(f"the model needs finite a22 < 0 and b2 > 0, got a22={a22}, b2={b2}")
    return a22, b2


def design_ackermann_gains(model: YawModel, speed: float, rules: CascadeRules = CascadeRules()) -> AckermannGains:
    """Eq. P.1–P.4 at water speed ``speed`` (m/s, > 0), RO_YAW_P = ``rules.angle_ratio``·ωr_a and
    RO_YAW_RATE_CORR = ``rules.ff_scale``; ValueError for a model without a22 < 0 and b2 > 0."""
    a22, b2 = _plant(model)
    if not (math.isfinite(speed) and speed > 0.0):
        raise ValueError(f"the Ackermann feed-forward needs a speed > 0, got {speed!r}")
    clamped: list[str] = []
    ff_length = _clamp("ff_length", -a22 / b2 * speed, rules.rate_ff_range, clamped)
    rate_p = _clamp("rate_p", max(0.0, (rules.rate_bandwidth + a22) / b2), rules.rate_p_range, clamped)
    achieved = -a22 + b2 * rate_p
    rate_i = _clamp("rate_i", achieved / (rules.integral_ratio * b2), rules.rate_i_range, clamped)
    angle_p = _clamp("angle_p", rules.angle_ratio * achieved, rules.angle_p_range, clamped)
    damping = achieved / (2.0 * math.sqrt(achieved * angle_p)) if angle_p > 0.0 else math.inf
    return AckermannGains(angle_p=angle_p, rate_p=rate_p, rate_i=rate_i, ff_length=ff_length,
                          rate_bandwidth=achieved, heading_damping=damping, ff_correction=rules.ff_scale,
                          speed=float(speed), clamped=tuple(clamped))


def design_uuv_gains(model: YawModel, rules: CascadeRules = CascadeRules(), speed: float | None = None) -> UuvGains:
    """Eq. P.5–P.6 with ``rules.full_scale`` the equivalent rudder of full yaw torque and
    UUV_YAW_P = ``rules.angle_ratio``·ωr_a²/b; ValueError for a model without a22 < 0 and b2 > 0."""
    a22, b2 = _plant(model)
    b = b2 * rules.full_scale
    clamped: list[str] = []
    rate_d = _clamp("rate_d", max(0.0, (rules.rate_bandwidth + a22) / b), rules.rate_p_range, clamped)
    achieved = -a22 + b * rate_d
    angle_p = _clamp("angle_p", rules.angle_ratio * achieved ** 2 / b, rules.angle_p_range, clamped)
    damping = achieved / (2.0 * math.sqrt(b * angle_p)) if angle_p > 0.0 else math.inf
    return UuvGains(angle_p=angle_p, rate_d=rate_d, rate_bandwidth=achieved, heading_damping=damping,
                    speed=speed, clamped=tuple(clamped))
