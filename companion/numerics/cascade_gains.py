"""Native gains of a cascaded heading controller (ArduPilot) from the identified yaw model (SPEC C5).

ArduPilot steers with an angle P feeding a rate PID with feed-forward, on a normalised output
s ∈ [−1, 1] with rudder δ = s·δfs: s = FF·r_d + P·(r_d − r) + I·∫(r_d − r), r_d = ANG_P·(ψd − ψ).
The plant is the identified ṙ = a22·r + b2·δ = a22·r + b·s with b = b2·δfs. Design rule:

* **FF = −a22/b** (output per rad/s of turn rate): the steady turn needs exactly that output;
  with it the rate error obeys ė = (a22 − b·P)·e, whatever r_d does.
* **P = (ωr + a22)/b** moves the rate-loop pole from a22 to −ωr, the stated rate bandwidth
  (``rate_bandwidth``, 3 rad/s by default); 0 when the plant is already that fast.
* **Without a feed-forward** (an autopilot that does not apply it: ArduSub 4.7 computes
  ``ATC_RAT_YAW_FF`` but never adds it, so its range is (0, 0)) the steady turn must come from P and
  I: with P alone the rate settles at b·P/(b·P − a22) of the demand, so P is at least 2·|a22|/b
  (two thirds of the demand from P, the rest from I). Measured on ArduSub's own SITL sub (a22 ≈ −15,
  a plant faster than ωr): the rule above gave P = 0 and heading steps overshot 78–124 %.
* **I = ωr_a/(N·b)** with N = 10: the integrator alone would close a loop a decade slower than the
  achieved bandwidth ωr_a = −a22 + b·P; it removes the trim δ0 and any model error.
* **The output's speed scaling**: ArduRover multiplies a rudder's steering output by k = base/|U|
  above MOT_SPD_SCA_BASE (``AP_MotorsUGV::output_regular``; not for skid steering or vectored
  thrust), so the plant the gains see is b = k·b2·δfs (``CascadeRules.output_scale_base``, eq. A.2).
  Measured on ArduRover SITL before this was modelled: at 1.9 m/s (k = 0.53) the rate loop was half
  as fast as designed and the designed ±20° steps overshot 11 % against 3.3 % predicted.
* **ANG_P = ωr_a/2**: with the rate loop as a first-order lag 1/(1 + s/ωr_a), the heading loop
  s² + ωr_a·s + ωr_a·ANG_P has ζ = 0.7071 at ANG_P = ωr_a/2 (a 4.3 % step overshoot).

ωr, N, the ANG_P ratio (0.5 above) and a scale on FF (1 above) are the rule's parameters
(:class:`CascadeRules`); the quick procedure chooses them by optimising the predicted steps under
the autopilot's limits (eq. D.1, ``companion.numerics.step_design``), the defaults are the rule.

Every gain is kept inside ArduPilot's documented range (Rover ``ATC_STR_*``: ANG_P 1–10, RAT_P
and RAT_I 0–2, RAT_FF 0–3); a clamped gain is listed in ``clamped``. A clamp means the design's
damping is not met (e.g. FF at its limit at low speed); :func:`design_cascade_gains` reports the
damping ratio the clamped gains give, so a check can refuse them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion.checks import require_interval, require_positive
from .identification import YawModel


@dataclass(frozen=True)
class CascadeRules:
    """The stated design targets and the autopilot's documented gain ranges."""

    full_scale: float = 0.5236  # rad of rudder at output ±1 (the autopilot profile's)
    rate_bandwidth: float = 3.0  # ωr, rad/s
    integral_ratio: float = 10.0  # N
    angle_p_range: tuple[float, float] = (1.0, 10.0)
    rate_p_range: tuple[float, float] = (0.0, 2.0)
    rate_i_range: tuple[float, float] = (0.0, 2.0)
    rate_ff_range: tuple[float, float] = (0.0, 3.0)
    #: the speed (m/s) above which the autopilot scales the steering output by base/|U| (ArduRover's
    #: MOT_SPD_SCA_BASE for a rudder); None: the output is not scaled
    output_scale_base: float | None = None
    #: ANG_P = angle_ratio·ωr_a (0.5: ζ = 0.7071 with the rate loop as a first-order lag)
    angle_ratio: float = 0.5
    #: FF = ff_scale·(−a22/b) (1: the steady turn's exact output)
    ff_scale: float = 1.0

    def __post_init__(self) -> None:
        require_positive(self, "full_scale", "rate_bandwidth", "integral_ratio", "angle_ratio", "ff_scale")
        for name in ("angle_p_range", "rate_p_range", "rate_i_range", "rate_ff_range"):
            require_interval(self, name)

    def output_scale(self, speed: float | None) -> float:
        """k at ``speed`` (:func:`output_speed_scale`)."""
        return output_speed_scale(self.output_scale_base, speed)


def output_speed_scale(base: float | None, speed: float | None) -> float:
    """k of eq. A.2: ArduRover multiplies a rudder's steering output by base/|U| above the base speed
    (``AP_MotorsUGV::output_regular``, MOT_SPD_SCA_BASE); 1 at or below it, without a base (None,
    ≤ 0) or without a speed."""
    if base is None or not base > 0.0 or speed is None or not math.isfinite(speed) or abs(speed) <= base:
        return 1.0
    return base / abs(speed)


@dataclass
class CascadeGains:
    angle_p: float
    rate_p: float
    rate_i: float
    rate_ff: float
    rate_bandwidth: float  # achieved ωr_a, rad/s
    heading_damping: float  # ζ of the heading loop with these (clamped) gains
    speed: float | None = None
    clamped: tuple[str, ...] = ()

    def params(self) -> dict[str, float]:
        """Neutral parameter names (companion.link.autopilots.ardurover / ardusub)."""
        return {"heading_rate_ff": self.rate_ff, "heading_rate_p": self.rate_p, "heading_rate_i": self.rate_i,
                "heading_angle_p": self.angle_p}


def _clamp(name: str, value: float, limits: tuple[float, float], clamped: list[str]) -> float:
    low, high = limits
    if value < low or value > high:
        clamped.append(name)
        return min(max(value, low), high)
    return value


def design_cascade_gains(model: YawModel, rules: CascadeRules = CascadeRules(), speed: float | None = None) -> CascadeGains:
    """The rule of the module docstring; ValueError for a model without a22 < 0 and b2 > 0."""
    a22, b2 = float(model.a22), float(model.b2)
    if not (math.isfinite(a22) and math.isfinite(b2)) or a22 >= 0.0 or b2 <= 0.0:
        raise ValueError(f"the model needs finite a22 < 0 and b2 > 0, got a22={a22}, b2={b2}")
    b = b2 * rules.full_scale * rules.output_scale(speed)
    clamped: list[str] = []
    rate_ff = _clamp("rate_ff", rules.ff_scale * -a22 / b, rules.rate_ff_range, clamped)
    rate_p = max(0.0, (rules.rate_bandwidth + a22) / b)
    if rules.rate_ff_range[1] <= 0.0:  # no feed-forward: P carries the steady turn (docstring)
        rate_p = max(rate_p, 2.0 * -a22 / b)
    rate_p = _clamp("rate_p", rate_p, rules.rate_p_range, clamped)
    achieved = -a22 + b * rate_p
    rate_i = _clamp("rate_i", achieved / (rules.integral_ratio * b), rules.rate_i_range, clamped)
    angle_p = _clamp("angle_p", rules.angle_ratio * achieved, rules.angle_p_range, clamped)
    # heading loop s² + ωr_a·s + ωr_a·ANG_P (FF exact): ζ = ωr_a / (2·sqrt(ωr_a·ANG_P))
    damping = achieved / (2.0 * math.sqrt(achieved * angle_p))
    return CascadeGains(angle_p=angle_p, rate_p=rate_p, rate_i=rate_i, rate_ff=rate_ff, rate_bandwidth=achieved,
                        heading_damping=damping, speed=speed, clamped=tuple(clamped))

