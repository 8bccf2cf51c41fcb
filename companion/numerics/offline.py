"""Offline output-error baseline of Table 3.2 (SPEC C4; thesis 002 §3.4, eq. 3.38).

Θ = [a22, b2, C0] minimises J(Θ) = sqrt(mean((ψ_real − ψ_sim(Θ))²)) (eq. 3.38), where ψ_sim is
eq. 3.11 (ψ̈ = a22·ψ̇ + b2·δr − C0) driven by the recorded rudder from the first recorded heading and
yaw rate, integrated by the classical fourth-order Runge–Kutta method (one step per sample interval,
rudder held over the step — the thesis' Simulink set-up). The search is
``scipy.optimize.minimize(method="Nelder-Mead")`` from Θ = 0 with the thesis' stopping tolerances
(parameter 0.01, function 1e-4).

The RK4 loop is written out in scalar Python (not scipy.integrate) because it is called a few
hundred times per fit on a few hundred samples: the scalar loop is ~50× cheaper than a general ODE
solver call per interval, and RK4 specifically is what the baseline prescribes.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.optimize import minimize

from .identification import YawEstimate
from .validation import r_squared

logger = logging.getLogger(__name__)


@dataclass
class OfflineFit:
    """Result of the output-error fit (Table 3.2 columns): the estimate (a model or not:
    ``model.model()`` makes it one), Nelder–Mead iterations, J, R²."""

    model: YawEstimate
    iterations: int
    function_evaluations: int
    cost: float  # J of eq. 3.38 at the optimum, rad
    r2: float  # eq. 3.35 on the fitted (training) record
    success: bool
    message: str = ""


def simulate_yaw_rk4(
    a22: float,
    b2: float,
    c0: float,
    times: Sequence[float],
    rudder: Sequence[float],
    heading0: float,
    yaw_rate0: float = 0.0,
) -> np.ndarray:
    """ψ of eq. 3.11 by RK4, one step per sample interval, rudder held over each step."""
    n = len(times)
    out = np.empty(n)
    heading = float(heading0)
    yaw_rate = float(yaw_rate0)
    if n == 0:
        return out
    out[0] = heading
    for k in range(1, n):
        h = times[k] - times[k - 1]
        forcing = b2 * rudder[k - 1] - c0
        k1r = a22 * yaw_rate + forcing
        r2 = yaw_rate + 0.5 * h * k1r
        k2r = a22 * r2 + forcing
        r3 = yaw_rate + 0.5 * h * k2r
        k3r = a22 * r3 + forcing
        r4 = yaw_rate + h * k3r
        k4r = a22 * r4 + forcing
        heading += h / 6.0 * (yaw_rate + 2.0 * r2 + 2.0 * r3 + r4)
        yaw_rate += h / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r)
        out[k] = heading
    return out


def fit_yaw_offline(
    times: Sequence[float],
    heading: Sequence[float],
    rudder: Sequence[float],
    theta0: Sequence[float] = (0.0, 0.0, 0.0),
    yaw_rate0: float = 0.0,
    parameter_tolerance: float = 0.01,
    function_tolerance: float = 1e-4,
    max_iterations: int = 2000,
    initial_step: Sequence[float] = (-0.5, 0.5, 0.01),
) -> OfflineFit:
    """Nelder–Mead output-error fit of [a22, b2, C0] (eq. 3.38) from ``theta0`` (thesis: zero).

    ``heading`` may be wrapped (it is unwrapped); samples with a non-finite heading or rudder are
    dropped; ``rudder`` is in rad. The initial simplex is ``theta0`` and ``theta0 + initial_step[i]·e_i``:
    scipy's default simplex around a zero start (±0.00025) is already smaller than the 0.01
    parameter tolerance, so the search would stop at once without moving.
    """
    all_times = np.asarray(times, dtype=float)
    all_heading = np.asarray(heading, dtype=float)
    all_rudder = np.asarray(rudder, dtype=float)
    ok = np.isfinite(all_times) & np.isfinite(all_heading) & np.isfinite(all_rudder)
    t, psi, delta = all_times[ok], np.unwrap(all_heading[ok]), all_rudder[ok]
    if t.size < 4:
        raise ValueError("need at least 4 finite samples")
    if np.any(np.diff(t) <= 0.0):
        raise ValueError("times must be strictly increasing")
    time_list = t.tolist()
    rudder_list = delta.tolist()
    heading0 = float(psi[0])

    def cost(theta: np.ndarray) -> float:
        simulated = simulate_yaw_rk4(theta[0], theta[1], theta[2], time_list, rudder_list, heading0, yaw_rate0)
        value = math.sqrt(float(np.mean((psi - simulated) ** 2)))
        return value if math.isfinite(value) else 1e12

    start = np.asarray(theta0, dtype=float)
    simplex = np.vstack([start, start + np.diag(np.asarray(initial_step, dtype=float))])
    result = minimize(
        cost,
        start,
        method="Nelder-Mead",
        options={
            "xatol": parameter_tolerance,
            "fatol": function_tolerance,
            "maxiter": max_iterations,
            "initial_simplex": simplex,
        },
    )
    a22, b2, c0 = (float(v) for v in result.x)
    model = YawEstimate(a22=a22, b2=b2, delta0=c0 / b2 if b2 != 0.0 else 0.0)
    simulated = simulate_yaw_rk4(a22, b2, c0, time_list, rudder_list, heading0, yaw_rate0)
    fit = OfflineFit(
        model=model,
        iterations=int(result.nit),
        function_evaluations=int(result.nfev),
        cost=float(result.fun),
        r2=r_squared(simulated, psi),
        success=bool(result.success),
        message=str(result.message),
    )
    logger.debug("offline fit: %s", fit)
    return fit
