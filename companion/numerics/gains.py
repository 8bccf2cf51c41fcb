"""Heading PI gains from the identified yaw model (SPEC C5; thesis 002 §3.6.2, eq. 3.55–3.57).

Plant (eq. 3.9): ψ/δ' = b2 / (s² − a22·s), with δ' = δr − δ0; δ0 is fed forward as the trim.

Proportional gain (eq. 3.57): with u = Kp·e the closed loop is Kp·b2/(s² − a22·s + Kp·b2); its
poles lie on the ζ = 0.7071 line when **Kp = a22²/(2·b2)**, giving ωn = |a22|/√2.

Integral action — design rule: keep eq. 3.57's Kp and put the PI zero ``integral_ratio`` (N = 100)
times below ωn: **Ki = Kp·ωn/N**. Closed loop from ψd (PI on the error, as autopilots implement it):

    T(s) = b2·(Kp·s + Ki) / (s³ − a22·s² + b2·Kp·s + b2·Ki)

Because the plant already integrates, a PI on the error makes the loop type 2, whose step
response must overshoot until the error area is cancelled (∫e dt = 0); the extra overshoot is
≈ √2/N above the ζ = 0.7071 pair's 4.3 %. The design is scale-invariant in |a22| (all Table 3.4
models give the same normalised loop), so the figures below hold for every model:

    N = 100: dominant pair s = |a22|·(−0.4964 ± 0.4964j), ζ = 0.70709 (ωn ≈ 0.702·|a22|);
             slow real pole s = −0.00717·|a22| next to the zero −0.00707·|a22|;
             step overshoot 5.78 % (python-control step_info).
    (N = 10, the classic "decade below" rule, gives 17.9 % overshoot; N = 40 gives 7.9 %.)

The price is a slow integrator (integral time N/ωn ≈ 100 s for |a22| ≈ 1.4): it trims only slow
residual offsets, while the identified δ0 feed-forward removes the known one at once.

Damping margin (the quick procedure): ``GainBounds.damping`` generalises eq. 3.57 to any ζ of the pair,
**Kp = a22²/(4·ζ²·b2)**, ωn = |a22|/(2ζ) (ζ = 0.7071 gives eq. 3.57 exactly, the default here). A
doublet-identified |a22| carries the vehicle's quadratic yaw damping at the doublet's yaw rates, so
it is a few % larger than the damping that acts as a heading step comes to rest, where the overshoot
forms; the campaign therefore designs for ζ = :data:`CAMPAIGN_DAMPING` (a margin that holds under
that bias, measured in ``bench/bench_identification.py --damping``). Linear-model step overshoot
for N = 100: ζ 0.7071 → 5.78 %, 0.73 → 5.06 %, 0.75 → 4.45 %.

All gains are clamped to :class:`GainBounds`; a clamped gain is listed in ``HeadingGains.clamped``.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from companion.checks import require_non_negative, require_positive, require_range
from .identification import YawModel

logger = logging.getLogger(__name__)

#: damping ratio of eq. 3.57 (the constant-damping line y = −x)
DESIGN_DAMPING = 1.0 / math.sqrt(2.0)
#: the campaign's design damping, with a margin for the doublet's |a22| bias (module docstring)
CAMPAIGN_DAMPING = 0.75


@dataclass(frozen=True)
class GainBounds:
    """Limits applied to every designed gain (rad of rudder per rad of heading error, per rad·s, rad)."""

    kp_min: float = 0.05
    kp_max: float = 5.0
    ki_min: float = 0.0
    ki_max: float = 1.0
    trim_limit: float = 0.15  # |trim| ≤ this (rad); the rudder limit is ~0.26–0.52 rad
    integral_ratio: float = 100.0  # N: PI zero at ωn/N (see module docstring)
    damping: float = DESIGN_DAMPING  # ζ of the dominant pair (eq. 3.57: 0.7071; see module docstring)

    def __post_init__(self) -> None:
        require_non_negative(self, "kp_min", "ki_min", "trim_limit")
        require_positive(self, "kp_max", "ki_max", "integral_ratio")
        require_range(self, "damping", 0.1, 5.0)
        if self.kp_min > self.kp_max or self.ki_min > self.ki_max:
            raise ValueError(f"GainBounds: a lower bound above its upper bound ({self})")


@dataclass
class HeadingGains:
    """Heading PI gains: rudder = trim + kp·e + ki·∫e dt (e = ψd − ψ, rad)."""

    kp: float
    ki: float
    trim: float
    speed: float | None = None
    clamped: tuple[str, ...] = ()


def _clamp(name: str, value: float, low: float, high: float, clamped: list[str]) -> float:
    if value < low or value > high:
        clamped.append(name)
        logger.warning("%s = %.4g outside [%.4g, %.4g]: clamped", name, value, low, high)
        return min(max(value, low), high)
    return value


def proportional_gain(a22: float, b2: float, damping: float = DESIGN_DAMPING) -> float:
    """Kp = a22²/(4·ζ²·b2): eq. 3.57 (Kp = a22²/(2·b2)) at ζ = 0.7071, the pair at ζ otherwise."""
    return a22 * a22 / (4.0 * damping * damping * b2)


def design_heading_gains(
    model: YawModel, bounds: GainBounds = GainBounds(), speed: float | None = None
) -> HeadingGains:
    """PI gains with the pair at ζ = ``bounds.damping`` (eq. 3.57 at 0.7071) and the integral rule
    of the module docstring."""
    a22, b2, delta0 = float(model.a22), float(model.b2), float(model.delta0)
    if not (math.isfinite(a22) and math.isfinite(b2) and math.isfinite(delta0)):
        raise ValueError(f"model parameters must be finite: {model}")
    if a22 >= 0.0:
        raise ValueError(f"a22 must be negative (stable yaw damping), got {a22}")
    if b2 <= 0.0:
        raise ValueError(f"b2 must be positive (rudder authority), got {b2}")
    if not 0.0 < bounds.damping < 2.0:
        raise ValueError(f"design damping must be in (0, 2), got {bounds.damping}")
    kp = proportional_gain(a22, b2, bounds.damping)
    natural_frequency = abs(a22) / (2.0 * bounds.damping)
    ki = kp * natural_frequency / bounds.integral_ratio
    clamped: list[str] = []
    kp = _clamp("kp", kp, bounds.kp_min, bounds.kp_max, clamped)
    ki = _clamp("ki", ki, bounds.ki_min, bounds.ki_max, clamped)
    trim = _clamp("trim", delta0, -bounds.trim_limit, bounds.trim_limit, clamped)
    return HeadingGains(kp=kp, ki=ki, trim=trim, speed=speed, clamped=tuple(clamped))
