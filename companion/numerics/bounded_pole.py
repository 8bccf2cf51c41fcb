"""The yaw model refitted by output error with its pole bounded by the sampling (eq. 3.38p in
docs/method.md).

A vehicle whose yaw rate follows the rudder within one sample interval (ArduPilot SITL's
`motorboat` sets the rate from the steering at once) gives the online regression (eq. 3.14)
collinear regressors: r ∝ δ, so only the static gain K = −b2/a22 is determined, and a22 comes out
anywhere between −3 and −30, or positive with b2 negative (an "inverted" estimate). This fit tells
that case from a lag the record does resolve:

    min over a22 ∈ [−1/h, a22_slow] of  min over (b2, C0, r0) of  Σ_k (ψ_k − ψ_sim,k)²

where h is the median sample interval and ψ_sim is eq. 3.11 from the first heading with initial
rate r0, exact per held interval (eq. L.3). For a fixed a22, ψ_sim is affine in (b2, C0, r0), so
the inner problem is linear least squares (``numpy.linalg.lstsq``) and the outer one a bounded
scalar search (``scipy.optimize.minimize_scalar``): separable least squares. A pole on the fast
bound means the lag is shorter than one sample: the record says K and nothing more.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.optimize import minimize_scalar

from .identification import YawEstimate
from .validation import interval_factors, r_squared

SLOWEST_A22 = -0.02  # 1/s: a yaw time constant of 50 s, slower than any hull's
BOUND_SHARE = 0.98  # a pole within 2 % of the fast bound sits on it


@dataclass(frozen=True)
class BoundedPoleFit:
    """The fit of eq. 3.38p: the estimate (its a22 stable by the bounds, its b2 of any sign), its R² on
    the fitted record, the fast bound (1/s) and whether the pole sits on it (the lag is shorter than
    one sample interval)."""

    model: YawEstimate
    r2: float
    fast_bound: float
    at_bound: bool
    initial_rate: float

    def __post_init__(self) -> None:
        if not self.fast_bound > 0.0:
            raise ValueError(f"the fast bound is a positive rate, not {self.fast_bound}")

    @property
    def static_gain(self) -> float:
        """K = −b2/a22: the steady yaw rate per radian of rudder, rad/s."""
        return -self.model.b2 / self.model.a22


def _responses(dts: np.ndarray, rudder: np.ndarray, a22: float) -> np.ndarray:
    """Heading (from 0) of eq. 3.11 to the three unit causes: b2 = 1 on the held rudder, C0 = 1, and an
    initial rate of 1 (columns), exact per held interval (eq. L.3)."""
    phi1s, phi2s = interval_factors(a22, dts)
    decays = 1.0 + a22 * phi1s
    columns = np.zeros((dts.size + 1, 3))
    state = np.zeros((2, 3))  # rows: heading, rate; columns: the causes
    state[1, 2] = 1.0
    forcing = np.zeros(3)
    for k in range(dts.size):
        forcing[0], forcing[1] = rudder[k], -1.0
        heading = state[0] + state[1] * phi1s[k] + forcing * phi2s[k]
        state[1] = state[1] * decays[k] + forcing * phi1s[k]
        state[0] = heading
        columns[k + 1] = heading
    return columns


def fit_yaw_bounded_pole(times: Sequence[float], heading: Sequence[float], rudder: Sequence[float], *,
                         slowest_a22: float = SLOWEST_A22) -> BoundedPoleFit:
    """The output-error fit of eq. 3.38p on one record (module docstring). ``heading`` may be wrapped;
    samples with a non-finite value are dropped. ValueError for fewer than 8 samples, or times that
    do not increase."""
    t_all, psi_all, delta_all = (np.asarray(v, dtype=float) for v in (times, heading, rudder))
    ok = np.isfinite(t_all) & np.isfinite(psi_all) & np.isfinite(delta_all)
    t, psi, delta = t_all[ok], np.unwrap(psi_all[ok]), delta_all[ok]
    if t.size < 8:
        raise ValueError(f"the bounded-pole fit needs at least 8 finite samples, not {t.size}")
    dts = np.diff(t)
    if np.any(dts <= 0.0):
        raise ValueError("times must be strictly increasing")
    fast_bound = 1.0 / float(np.median(dts))
    if not -fast_bound < slowest_a22 < 0.0:
        raise ValueError(f"the slowest a22 ({slowest_a22}) must lie in (−{fast_bound:.3g}, 0)")
    target = psi - psi[0]

    def solve(a22: float) -> tuple[float, np.ndarray, np.ndarray]:
        columns = _responses(dts, delta, a22)
        coefficients, *_ = np.linalg.lstsq(columns, target, rcond=None)
        fitted = columns @ coefficients
        return float(np.sum((fitted - target) ** 2)), coefficients, fitted

    search = minimize_scalar(lambda a22: solve(a22)[0], bounds=(-fast_bound, slowest_a22), method="bounded",
                             options={"xatol": 1e-3 * fast_bound})
    a22 = float(search.x)
    _, (b2, c0, rate0), fitted = solve(a22)
    delta0 = c0 / b2 if b2 != 0.0 and math.isfinite(b2) else 0.0
    return BoundedPoleFit(model=YawEstimate(a22=a22, b2=float(b2), delta0=float(delta0)),
                          r2=float(r_squared(fitted, target)), fast_bound=fast_bound,
                          at_bound=a22 <= -BOUND_SHARE * fast_bound, initial_rate=float(rate0))


ONLINE = "online"  # the online estimate (eq. 3.32–3.34) is the model
LAG_UNRESOLVED = "lag unresolved"  # the bounded fit's, its pole on the sampling's bound
ONLINE_UNSTABLE = "online estimate unstable"  # the bounded fit's, the online one not a stable model


@dataclass(frozen=True)
class YawModelChoice:
    """Which estimate an identification attempt keeps (eq. 3.38p): ``source`` is one of the three words
    above, ``note`` says why in a sentence (empty for the online estimate). The bounded fit's is kept
    only as a :class:`~companion.numerics.identification.YawModel`; the online one may be no model
    (an attempt holding it is then rejected)."""

    model: YawEstimate
    source: str
    note: str = ""

    def __post_init__(self) -> None:
        if self.source not in (ONLINE, LAG_UNRESOLVED, ONLINE_UNSTABLE):
            raise ValueError(f"a yaw model's source is {ONLINE!r}, {LAG_UNRESOLVED!r} or {ONLINE_UNSTABLE!r}, "
                             f"not {self.source!r}")


def choose_yaw_model(online: YawEstimate, fit: BoundedPoleFit | None) -> YawModelChoice:
    """The online estimate, unless the bounded fit of the same record puts the pole on the sampling's
    bound, or the online estimate is not a stable model and the fit is (eq. 3.38p)."""
    if fit is None or not fit.model.is_model:
        return YawModelChoice(online, ONLINE)
    if fit.at_bound:
        return YawModelChoice(fit.model.model(), LAG_UNRESOLVED,
                              f"the yaw rate follows the rudder within one sample ({1000.0 / fit.fast_bound:.0f} ms): "
                              f"a22 put at {fit.model.a22:.1f}/s, the static gain {fit.static_gain:.3g} rad/s per rad "
                              f"from the record (online a22 {online.a22:.3g})")
    if not online.is_model:
        return YawModelChoice(fit.model.model(), ONLINE_UNSTABLE,
                              f"the online estimate (a22 {online.a22:.3g}, b2 {online.b2:.3g}) is not a stable model; "
                              f"the output-error fit's is used")
    return YawModelChoice(online, ONLINE)
