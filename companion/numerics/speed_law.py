"""Which speed law the steering authority b2 follows, chosen by the models themselves (eq. S.3).

Two physical laws compete (docs/method.md §13):

* **rudder** (a fin in the flow): b2 = k·u² + c, the lift grows with the dynamic pressure (the form
  of eq. 3.51);
* **differential thrust** (a skid-steered pair): b2 = k·u + c, the yaw moment per unit of steering
  grows with the mean propeller loading, and with quadratic drag the throttle that holds a speed is
  proportional to it (eq. S.2).

Both are fitted by weighted least squares over the identified models (each with its own
intercept c). The vehicle's actuation says which law physics predicts (``prior``: "u2" for a rudder or
steering servo, "u" for a skid-steered pair; "u2" when unknown, the thesis' law), and the models may
overrule it:

1. with models at ≥ 4 distinct speeds spanning ≥ 20 % in speed, the other law is chosen when the
   prior's residual RMS is at least :data:`OVERRULE_RATIO` (2) times the other's;
2. otherwise the prior stands, and the reason says whether the residuals agree with it (the prior's
   at least 1.25 times smaller), are alike, or point the other way without the evidence to overrule.

Why so demanding: with 3 speeds each law keeps one residual degree of freedom, and the ratio of two
such residuals is heavy-tailed. Simulated with 1.5 % of noise on b2 (2000 draws, 1.2–2.2 m/s): at 3
speeds the wrong law fitted 2× better in 5 % (u² truth) and 15 % (u truth) of the draws; at 5 speeds
in 0.1 % and 1.6 %, while the right law fitted 2× better in 79 % and 48 %.

The power law b2 = k·uⁿ is fitted too, in logarithms, and its exponent n̂ ± σ_n reported beside: it
is not the criterion, because an intercept bends it (the thesis' own Table 3.1, b2 = 0.31·u² + 0.26,
gives n̂ = 1.47 ± 0.06 over 1.1–2.2 m/s, nearer 1 than 2, while its u² + c residual is half the
u + c one). Measured on the rehearsals: u² + c against u + c residuals 0.010 against 0.046 s⁻² on the
rudder boat (``boat-3dof``), 0.050 against 0.033 on the skid boat (``boat-skid``).

The chosen law, every law's residual RMS, n̂ ± σ_n and the reason travel with the schedule, so a
design can be traced to the evidence behind it. Pure numerics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

#: law name → exponent of u in b2 = k·u^e + c
LAW_EXPONENTS = {"u2": 2.0, "u": 1.0}
LAW_TEXT = {"u2": "b2 = k·u² + c (a rudder: lift ∝ dynamic pressure)",
            "u": "b2 = k·u + c (differential thrust: moment ∝ propeller loading ∝ u)"}
#: the narrowest speed range (max/min) over which the laws' curvatures can be told apart
MIN_SPEED_RATIO = 1.2
#: how many times the prior's residual RMS must exceed the other law's for the models to overrule it
OVERRULE_RATIO = 2.0
#: the fewest distinct speeds that may overrule the prior
OVERRULE_SPEEDS = 4
#: a residual this many times smaller counts as agreement in the reason
AGREE_RATIO = 1.25


@dataclass
class SpeedLawChoice:
    """The chosen law (``law``: a key of :data:`LAW_EXPONENTS`) and the evidence for it."""

    law: str
    reason: str
    slope: float  # k
    intercept: float  # c
    residual_rms: dict[str, float] = field(default_factory=dict)  # law → RMS of b2 − fit, s⁻²
    exponent: float = math.nan  # n̂ of b2 = k·uⁿ
    exponent_sigma: float = math.nan  # its standard error
    prior: str = "u2"

    @property
    def exponent_of_law(self) -> float:
        return LAW_EXPONENTS[self.law]


def fit_law(speeds: np.ndarray, b2: np.ndarray, weights: np.ndarray, law: str) -> tuple[float, float, float]:
    """(k, c, residual RMS) of b2 = k·u^e + c by weighted least squares (e of ``law``)."""
    exponent = LAW_EXPONENTS[law]
    sqrt_w = np.sqrt(weights)
    design = np.column_stack([speeds ** exponent, np.ones_like(speeds)])
    (slope, intercept), *_ = np.linalg.lstsq(design * sqrt_w[:, None], b2 * sqrt_w, rcond=None)
    residual = b2 - (slope * speeds ** exponent + intercept)
    return float(slope), float(intercept), float(np.sqrt(np.mean(residual ** 2)))


def power_exponent(speeds: np.ndarray, b2: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    """(n̂, σ_n) of ln b2 = ln k + n·ln u (weighted LS; σ from the residuals, NaN with < 3 speeds)."""
    x, y = np.log(speeds), np.log(b2)
    sqrt_w = np.sqrt(weights)
    design = np.column_stack([np.ones_like(x), x]) * sqrt_w[:, None]
    coef, *_ = np.linalg.lstsq(design, y * sqrt_w, rcond=None)
    dof = x.size - 2
    if dof < 1:
        return float(coef[1]), math.nan
    residual = y * sqrt_w - design @ coef
    covariance = float(residual @ residual) / dof * np.linalg.inv(design.T @ design)
    return float(coef[1]), math.sqrt(max(float(covariance[1, 1]), 0.0))


def choose_speed_law(speeds: Sequence[float], b2: Sequence[float], weights: Sequence[float] | None = None,
                     prior: str | None = None) -> SpeedLawChoice:
    """The rule of the module docstring over models at ≥ 2 distinct speeds (ValueError otherwise)."""
    prior = prior or "u2"
    if prior not in LAW_EXPONENTS:
        raise ValueError(f"unknown speed law {prior!r} (known: {', '.join(LAW_EXPONENTS)})")
    u = np.asarray(speeds, dtype=float)
    y = np.asarray(b2, dtype=float)
    w = np.ones(u.size) if weights is None else np.asarray(weights, dtype=float)
    if u.size != y.size or u.size != w.size:
        raise ValueError("speeds, b2 and weights must have the same length")
    if np.unique(u).size < 2 or np.any(u <= 0.0) or np.any(y <= 0.0):
        raise ValueError("a speed law needs b2 > 0 at two or more distinct speeds > 0")
    fits = {law: fit_law(u, y, w, law) for law in LAW_EXPONENTS}
    rms = {law: fit[2] for law, fit in fits.items()}
    exponent, sigma = power_exponent(u, y, w)
    law, reason = _decide(u, rms, exponent, sigma, prior)
    slope, intercept, _ = fits[law]
    return SpeedLawChoice(law=law, reason=reason, slope=slope, intercept=intercept, residual_rms=rms,
                          exponent=exponent, exponent_sigma=sigma, prior=prior)


def _decide(speeds: np.ndarray, rms: dict[str, float], exponent: float, sigma: float,
            prior: str) -> tuple[str, str]:
    distinct = np.unique(speeds).size
    ratio = float(speeds.max() / speeds.min())
    other = next(law for law in rms if law != prior)
    evidence = (f"residual RMS {rms[prior]:.3f} s⁻² for {prior} against {rms[other]:.3f} for {other}; "
                f"b2 = k·uⁿ: n = {exponent:.2f} ± {sigma:.2f}")
    if distinct < 3 or ratio < MIN_SPEED_RATIO:
        span = f"speeds span only {100 * (ratio - 1):.0f} %" if distinct >= 3 else f"{distinct} speeds"
        return prior, f"{LAW_TEXT[prior]}, the law of this actuation ({span}: the models cannot tell)"
    if distinct >= OVERRULE_SPEEDS and rms[prior] >= OVERRULE_RATIO * rms[other]:
        return other, f"{LAW_TEXT[other]}: the models overrule the {prior} law of this actuation ({evidence})"
    if rms[other] >= AGREE_RATIO * rms[prior]:
        verdict = "the models agree"
    elif rms[prior] >= AGREE_RATIO * rms[other]:
        verdict = (f"the models lean to {other}, short of overruling it ({OVERRULE_SPEEDS} speeds and a "
                   f"{OVERRULE_RATIO:g}x residual needed)")
    else:
        verdict = "the laws fit alike"
    return prior, f"{LAW_TEXT[prior]}, the law of this actuation; {verdict} ({evidence})"
