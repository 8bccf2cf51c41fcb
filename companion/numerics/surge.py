"""The surge (speed) dynamics of a boat, identified from the settles a campaign already flies (eq. S.4).

Thrust against quadratic drag, m·u̇ = T(x) − d·u|u|, written with the steady speed U_ss(x) the
throttle holds (T(x) = d·U_ss(x)²), the thrust following the throttle t the autopilot outputs
through a first-order lag τl (propeller spin-up, and the autopilot's own speed estimate):

    u̇ = γ·(U_ss(x)² − u·|u|),   ẋ = (t − x)/τl,   U_ss(x) = k·x^p,   γ = d/m          (eq. S.4)

so about a speed U the speed answers a throttle change with the time constant τ(U) = 1/(2·γ·U)
behind the lag τl, and the steady gain is dU/dt = p·U/t. The lag matters for the speed loop's
design: measured on the skid boat behind ArduRover (propeller lag 0.3 s in the physics), gains
designed without it overshot 10–15 % where 5 % was predicted; the record's output error falls from
0.83 to 0.10 m²/s² with τl = 0.45 s. Fitted in two steps:

1. **a start from the steady levels**: at the end of each thrust level's last settle (the speed
   and throttle the autopilot's speed loop held there), ln U = ln k + p·ln t over ≥ 2 levels (p = 1
   through the origin with one level, or when the levels give an exponent outside 0.2–3, which no
   thrust against drag does). A thrust ∝ t² propeller against quadratic drag gives p = 1
   (our simulated boats); ArduPilot SITL's motorboat, whose thrust is linear in t, gives p = 1/2;
2. **output error** on (ln k, p, ln γ, τl): the model is integrated (the lag exactly, the speed by
   Heun, in steps of at most 50 ms) over each straight, contiguous stretch of the record from its
   first measured speed (the thrust starting at the throttle then), driven by the measured
   throttle, and ``scipy.optimize.least_squares`` minimises the speed error (γ's start by a bounded
   scalar search without lag, τl's from 0.2 s, bounded to 0–3 s). Output error, not a regression on a differentiated speed:
   the speed is noisy and its derivative more so; and all three together, because a level the speed
   loop had not quite settled at (the first one, reached from rest, overshoots) would bend the
   steady law alone.

The throttle is the one the speed controller outputs (ArduRover: SERVO3 read back, or a skid pair's
un-mixed throttle, eq. S.1), so closed-loop records serve: the input is measured, not commanded. The
propeller's lag and the speed estimate's lag are not modelled; they are folded into γ. Pure numerics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares, minimize_scalar

#: the bounds of γ searched (1/m): time constants from 5 ms to 500 s at 1 m/s
GAMMA_BOUNDS = (1e-3, 100.0)
#: the throttle-to-thrust lag: where its fit starts, and its largest value (s)
LAG_START_S = 0.2
LAG_MAX_S = 3.0


@dataclass
class SurgeModel:
    """Eq. S.4: U_ss(t) = ``gain``·t^``exponent``, u̇ = ``gamma``·(U_ss² − u|u|)."""

    gain: float  # k, m/s at throttle 1
    exponent: float  # p
    gamma: float  # 1/m
    lag: float = 0.0  # τl, s
    r2: float = math.nan  # speed predicted over the straight stretches (eq. 3.35's form)
    levels: list[dict] = field(default_factory=list)  # {"throttle", "speed"} at each steady level
    samples: int = 0
    stretches: int = 0

    def steady_speed(self, throttle: float) -> float:
        return self.gain * max(throttle, 0.0) ** self.exponent

    def throttle_for(self, speed: float) -> float:
        """The throttle that holds ``speed`` (the steady law inverted)."""
        return (max(speed, 0.0) / self.gain) ** (1.0 / self.exponent)

    def time_constant(self, speed: float) -> float:
        """τ(U) = 1/(2γU) of the linearisation about ``speed``."""
        return 1.0 / (2.0 * self.gamma * max(speed, 1e-6))

    def throttle_gain(self, speed: float) -> float:
        """dU_ss/dt at ``speed``: p·U/t."""
        return self.exponent * speed / max(self.throttle_for(speed), 1e-6)

    def acceleration(self, speed: float, throttle: float) -> float:
        target = self.steady_speed(throttle)
        return self.gamma * (target * target - speed * abs(speed))

    def simulate(self, times: Sequence[float] | NDArray[np.float64], throttle: Sequence[float] | NDArray[np.float64],
                 speed0: float) -> np.ndarray:
        """u over ``times`` from ``speed0`` (steady: the thrust at the first throttle), throttle held
        over each interval."""
        return simulate_surge(self.gain, self.exponent, self.gamma, times, throttle, speed0, self.lag)

    def describe(self) -> str:
        return (f"U = {self.gain:.3f}·t^{self.exponent:.2f} m/s, u̇ = {self.gamma:.3f}·(U² − u|u|), "
                f"τ = {1.0 / (2.0 * self.gamma):.2f} s·m/s / U, lag {self.lag:.2f} s")


#: the longest integration step (s)
MAX_STEP_S = 0.05


def simulate_surge(gain: float, exponent: float, gamma: float, times: Sequence[float] | NDArray[np.float64],
                   throttle: Sequence[float] | NDArray[np.float64], speed0: float, lag: float = 0.0) -> np.ndarray:
    """Eq. S.4 from ``speed0`` with the thrust starting at ``throttle[0]``; each interval in steps of
    at most :data:`MAX_STEP_S`: the lag exactly (throttle held), the speed by Heun."""
    n = len(times)
    out = np.empty(n)
    u = float(speed0)
    x = float(throttle[0]) if n else 0.0
    for k in range(n):
        out[k] = u
        if k == n - 1:
            break
        interval = times[k + 1] - times[k]
        steps = max(1, int(math.ceil(interval / MAX_STEP_S - 1e-9)))
        h = interval / steps
        follow = 1.0 if lag <= 0.0 else 1.0 - math.exp(-h / lag)
        for _ in range(steps):
            x += (throttle[k] - x) * follow
            target = gain * max(x, 0.0) ** exponent
            drive = target * target
            a1 = gamma * (drive - u * abs(u))
            u1 = u + h * a1
            u = u + 0.5 * h * (a1 + gamma * (drive - u1 * abs(u1)))
    return out


def steady_law(levels: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """(k, p) of U = k·t^p from (throttle, speed) pairs with both > 0 (step 1 of the module docstring)."""
    pairs = [(t, u) for t, u in levels if t > 0.0 and u > 0.0 and math.isfinite(t) and math.isfinite(u)]
    if not pairs:
        raise ValueError("no steady level with a positive throttle and speed")
    throttles = np.array([t for t, _ in pairs])
    if len(pairs) == 1 or np.ptp(np.log(throttles)) < 0.05:
        return float(np.mean([u / t for t, u in pairs])), 1.0
    design = np.column_stack([np.ones(len(pairs)), np.log(throttles)])
    (log_k, p), *_ = np.linalg.lstsq(design, np.log([u for _, u in pairs]), rcond=None)
    if not 0.2 <= p <= 3.0:  # a level the speed loop had not settled at: start from p = 1, the fit decides
        return float(np.median([u / t for t, u in pairs])), 1.0
    return float(math.exp(log_k)), float(p)


def fit_surge_model(times: Sequence[float] | NDArray[np.float64], throttle: Sequence[float] | NDArray[np.float64],
                    speed: Sequence[float] | NDArray[np.float64], levels: Sequence[tuple[float, float]],
                    stretches: Sequence[tuple[int, int]]) -> SurgeModel:
    """Eq. S.4 from a record (``times``, measured ``throttle`` and ``speed``), its steady ``levels``
    (throttle, speed) and the index ranges [start, stop) of its straight, contiguous ``stretches``
    (those shorter than 5 samples are skipped). ValueError when nothing can be fitted."""
    t = np.asarray(times, dtype=float)
    thr = np.asarray(throttle, dtype=float)
    u = np.asarray(speed, dtype=float)
    gain, exponent = steady_law(levels)
    usable = [(a, b) for a, b in stretches if b - a >= 5 and np.all(np.isfinite(thr[a:b])) and np.all(np.isfinite(u[a:b]))]
    if not usable:
        raise ValueError("no straight stretch of at least 5 samples to fit the surge dynamics on")

    def residual(theta: np.ndarray) -> np.ndarray:
        k, p, gamma, lag = math.exp(theta[0]), theta[1], math.exp(theta[2]), theta[3]
        return np.concatenate([simulate_surge(k, p, gamma, t[a:b], thr[a:b], u[a], lag) - u[a:b]
                               for a, b in usable])

    def cost(log_gamma: float) -> float:
        error = residual(np.array([math.log(gain), exponent, log_gamma, 0.0]))
        return float(error @ error)

    start = minimize_scalar(cost, bounds=tuple(math.log(v) for v in GAMMA_BOUNDS), method="bounded",
                            options={"xatol": 1e-3})
    fit = least_squares(residual, [math.log(gain), exponent, float(start.x), LAG_START_S],
                        bounds=([-5.0, 0.2, math.log(GAMMA_BOUNDS[0]), 0.0],
                                [5.0, 3.0, math.log(GAMMA_BOUNDS[1]), LAG_MAX_S]))
    gain, exponent, gamma, lag = math.exp(fit.x[0]), float(fit.x[1]), math.exp(fit.x[2]), float(fit.x[3])
    measured = np.concatenate([u[a:b] for a, b in usable])
    spread = float(np.sum((measured - measured.mean()) ** 2))
    r2 = 1.0 - float(fit.fun @ fit.fun) / spread if spread > 0.0 else math.nan
    return SurgeModel(gain=gain, exponent=exponent, gamma=gamma, lag=lag, r2=r2,
                      levels=[{"throttle": float(a), "speed": float(b)} for a, b in levels],
                      samples=int(sum(b - a for a, b in usable)), stretches=len(usable))
