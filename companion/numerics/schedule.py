"""Speed schedule of the yaw model and of the heading gains (SPEC C5; thesis 002 §3.3.2, §3.6, Fig. 3.8).

Laws fitted over the stored models (one per speed):

- a22(u) ≈ constant: the weighted mean (thesis: "small variation around its mean value of 1.1"),
  **unless** the models show a significant trend: with ≥ 3 distinct speeds and a weighted LS slope
  β of a22 against u larger than twice its standard error, a22(u) = ā22 + β·(u − ū). A vehicle
  whose damping grows with speed (the simulator's STARFISH: a22 −1.0 → −1.2 over 1.1–2.2 m/s) would
  otherwise get gains ~25 % too high at low speed (Kp ∝ a22²), i.e. ~10 % step overshoot instead of
  the design's 5.8 % (bench/bench_identification.py);
- b2(u) = k·u² + c: weighted linear least squares in u² (``numpy.linalg.lstsq``; Fig. 3.8 /
  eq. 3.51: b2 = 0.31·u² + 0.26), since a fin's authority scales with dynamic pressure, **or**
  b2(u) = k·u + c, the law of differential thrust (eq. S.2), whichever the models support
  (``companion.numerics.speed_law``, eq. S.3; the vehicle's actuation is the prior when they cannot
  tell);
- δ0(u) ≈ constant: the weighted mean.

Weights default to 1 (pass e.g. each model's validation R²).

Extrapolation is **clamped**: the laws are evaluated at the speed limited to
[u_min·(1 − margin), u_max·(1 + margin)] of the identified range (margin 0.2 by default), so a
speed far outside what was identified does not produce gains from an unsupported extrapolation
(the thesis itself warns that Fig. 3.13's extrapolation holds only if the laws do). b2 is further
floored at ``b2_floor_fraction`` (0.5) of the smallest identified b2, so a negative fitted intercept
can never produce b2 ≤ 0 at low speed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .gains import GainBounds, HeadingGains, design_heading_gains
from .identification import YawModel
from .speed_law import LAW_EXPONENTS, LAW_TEXT, choose_speed_law


@dataclass
class YawSchedule:
    a22: float
    b2_slope: float  # k in b2 = k·u^e + c (e = 2 for the law "u2", 1 for "u"), s⁻² per (m/s)^e
    b2_intercept: float  # c, s⁻²
    delta0: float
    speed_range: tuple[float, float]
    b2_residual_rms: float = math.nan  # RMS of b2 − (k·u² + c) over the models
    a22_std: float = math.nan  # weighted standard deviation of a22 around the mean
    b2_min_identified: float = math.nan
    a22_per_speed: float = 0.0  # β: 0 when a22 is constant (see module docstring)
    a22_reference_speed: float = 0.0  # ū, the weighted mean speed of the models
    margin: float = 0.2
    b2_floor_fraction: float = 0.5
    speeds: list[float] = field(default_factory=list)
    # the speed law of b2 and the evidence for it (companion.numerics.speed_law, eq. S.3)
    b2_law: str = "u2"
    b2_law_reason: str = ""
    b2_law_rms: dict = field(default_factory=dict)  # law → residual RMS of its fit, s⁻²
    b2_exponent: float = math.nan  # n̂ of b2 = k·uⁿ
    b2_exponent_sigma: float = math.nan

    def __post_init__(self) -> None:
        """A schedule is fitted on accepted (stable) models over the speeds they were flown at: its
        mean a22 is negative and its speed range is 0 < low ≤ high, both finite."""
        if not (math.isfinite(self.a22) and self.a22 < 0.0):
            raise ValueError(f"YawSchedule.a22 must be finite and negative (a stable yaw), not {self.a22!r}")
        low, high = (float(v) for v in self.speed_range)
        if not (math.isfinite(low) and math.isfinite(high) and 0.0 < low <= high):
            raise ValueError(f"YawSchedule.speed_range must be 0 < low <= high, not {self.speed_range!r}")
        self.speed_range = (low, high)
        if self.b2_law not in LAW_EXPONENTS:
            raise ValueError(f"YawSchedule.b2_law must be one of {', '.join(LAW_EXPONENTS)}, not {self.b2_law!r}")
        if not (math.isfinite(self.b2_slope) and math.isfinite(self.b2_intercept) and self.margin >= 0.0):
            raise ValueError("YawSchedule: b2's law and the extrapolation margin must be finite numbers")

    def clamp_speed(self, speed: float) -> float:
        """The speed at which the laws are evaluated (clamped extrapolation, see module docstring)."""
        low, high = self.speed_range
        return min(max(float(speed), low * (1.0 - self.margin)), high * (1.0 + self.margin))

    def b2_at(self, speed: float) -> float:
        u = self.clamp_speed(speed)
        b2 = self.b2_slope * u ** LAW_EXPONENTS.get(self.b2_law, 2.0) + self.b2_intercept
        return max(b2, self.b2_floor_fraction * self.b2_min_identified)

    def a22_at(self, speed: float) -> float:
        """ā22 + β·(u − ū) at the clamped speed; never above 0.1·ā22 (stays stable, a22 < 0)."""
        value = self.a22 + self.a22_per_speed * (self.clamp_speed(speed) - self.a22_reference_speed)
        return min(value, 0.1 * self.a22)

    def model_at(self, speed: float) -> YawModel:
        return YawModel(a22=self.a22_at(speed), b2=self.b2_at(speed), delta0=self.delta0)

    def gains_at(self, speed: float, bounds: GainBounds = GainBounds()) -> HeadingGains:
        return design_heading_gains(self.model_at(speed), bounds, speed=float(speed))

    def describe(self) -> str:
        """The laws in words, as the report and the command line print them (trend included)."""
        if self.a22_per_speed:
            a22 = (f"a22 = {self.a22:.3f} {self.a22_per_speed:+.3f}·(u − {self.a22_reference_speed:.2f}) s⁻¹"
                   " (significant trend with speed)")
        else:
            a22 = f"a22 = {self.a22:.3f} s⁻¹ (constant)"
        power = "u²" if self.b2_law == "u2" else "u"
        return f"{a22}, b2 = {self.b2_slope:.3f}·{power} + {self.b2_intercept:.3f} s⁻², δ0 = {self.delta0:.4f} rad"


def constant_schedule(speed: float, model: YawModel, prior_law: str | None = None) -> YawSchedule:
    """One speed cannot fit b2(u): that model's gains at every speed (no extrapolation of an
    unknown law) -- the honest fallback of :func:`schedule_from_models`; the actuation's law is
    recorded, not used."""
    if not (model.a22 < 0 and model.b2 > 0):
        raise ValueError("the model needs a22 < 0 and b2 > 0")
    law = prior_law or "u2"
    return YawSchedule(a22=model.a22, b2_slope=0.0, b2_intercept=model.b2, delta0=model.delta0,
                       speed_range=(speed, speed), b2_min_identified=model.b2, a22_reference_speed=speed,
                       speeds=[speed], b2_law=law,
                       b2_law_reason=f"one speed: its model at every speed ({LAW_TEXT[law]} is this actuation's law)")


def schedule_from_models(
    speeds: Sequence[float],
    models: Sequence[YawModel],
    weights: Sequence[float] | None = None,
    margin: float = 0.2,
    prior_law: str | None = None,
) -> YawSchedule:
    """The one schedule fit of the product: the laws of :func:`fit_yaw_schedule` over models at
    ≥ 2 distinct speeds, :func:`constant_schedule` of the last model when all share one speed.
    ``prior_law`` is the b2 law of the vehicle's actuation ("u2" rudder, "u" skid; None: "u2").
    ValueError when no model is usable."""
    usable = [(float(u), m) for u, m in zip(speeds, models) if math.isfinite(u)]
    if not usable:
        raise ValueError("no model with a measured speed")
    if len({round(u, 3) for u, _ in usable}) == 1:
        return constant_schedule(*usable[-1], prior_law)
    return fit_yaw_schedule(speeds, models, weights, margin, prior_law)


def fit_yaw_schedule(
    speeds: Sequence[float],
    models: Sequence[YawModel],
    weights: Sequence[float] | None = None,
    margin: float = 0.2,
    prior_law: str | None = None,
) -> YawSchedule:
    """Fit the speed laws to ≥ 2 models at ≥ 2 distinct speeds (ValueError otherwise); b2's law is
    chosen by :func:`companion.numerics.speed_law.choose_speed_law` (eq. S.3)."""
    speeds_arr = np.asarray(speeds, dtype=float)
    if speeds_arr.size != len(models):
        raise ValueError("speeds and models must have the same length")
    w = np.ones(speeds_arr.size) if weights is None else np.asarray(weights, dtype=float)
    a22 = np.array([m.a22 for m in models], dtype=float)
    b2 = np.array([m.b2 for m in models], dtype=float)
    delta0 = np.array([m.delta0 for m in models], dtype=float)
    ok = np.isfinite(speeds_arr) & np.isfinite(a22) & np.isfinite(b2) & np.isfinite(delta0) & np.isfinite(w) & (w > 0)
    speeds_arr, w, a22, b2, delta0 = speeds_arr[ok], w[ok], a22[ok], b2[ok], delta0[ok]
    if speeds_arr.size < 2 or np.unique(speeds_arr).size < 2:
        raise ValueError("need models at two or more distinct speeds")
    if np.any(a22 >= 0.0) or np.any(b2 <= 0.0):
        raise ValueError("every model needs a22 < 0 and b2 > 0")
    a22_mean = float(np.average(a22, weights=w))
    a22_std = float(math.sqrt(np.average((a22 - a22_mean) ** 2, weights=w)))
    law = choose_speed_law(speeds_arr, b2, w, prior_law)
    a22_slope, reference_speed = _a22_trend(speeds_arr, a22, w)
    return YawSchedule(
        a22=a22_mean,
        b2_slope=law.slope,
        b2_intercept=law.intercept,
        delta0=float(np.average(delta0, weights=w)),
        speed_range=(float(speeds_arr.min()), float(speeds_arr.max())),
        b2_residual_rms=law.residual_rms[law.law],
        a22_std=a22_std,
        b2_min_identified=float(b2.min()),
        a22_per_speed=a22_slope,
        a22_reference_speed=reference_speed,
        margin=margin,
        speeds=speeds_arr.tolist(),
        b2_law=law.law,
        b2_law_reason=law.reason,
        b2_law_rms=dict(law.residual_rms),
        b2_exponent=law.exponent,
        b2_exponent_sigma=law.exponent_sigma,
    )


def _a22_trend(speeds: np.ndarray, a22: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    """Weighted LS slope of a22 against u, kept only when |β| > 2·σ_β with ≥ 3 distinct speeds.

    Returns (β, ū); β = 0 means "a22 constant" (the thesis' law)."""
    reference = float(np.average(speeds, weights=weights))
    if np.unique(speeds).size < 3:
        return 0.0, reference
    sqrt_w = np.sqrt(weights)
    design = np.column_stack([np.ones_like(speeds), speeds - reference]) * sqrt_w[:, None]
    coef, *_ = np.linalg.lstsq(design, a22 * sqrt_w, rcond=None)
    residual = a22 * sqrt_w - design @ coef
    dof = speeds.size - 2
    sigma2 = float(residual @ residual) / dof
    covariance = sigma2 * np.linalg.inv(design.T @ design)
    slope, slope_sigma = float(coef[1]), math.sqrt(max(covariance[1, 1], 0.0))
    return (slope, reference) if abs(slope) > 2.0 * slope_sigma else (0.0, reference)
