"""State-variable filter F(s) = λ²/(s+λ)² giving a signal and its first two derivatives (SPEC C3).

Thesis 002 §3.2.2, eq. 3.16 (n = 2) and eq. 3.23–3.31: the filter input ``w`` drives the
controllable-canonical state ``x = [w_f⁽¹⁾/λ², w_f⁽⁰⁾/λ²]`` with

    A = [[-2λ, -λ²], [1, 0]],  B = [1, 0]ᵀ,
    C = λ²·[[-2λ, -λ²], [1, 0], [0, 1]],  D = λ²·[1, 0, 0]ᵀ        (eq. 3.28)

so that ``y = C x + D w = [w_f⁽²⁾, w_f⁽¹⁾, w_f⁽⁰⁾]`` (eq. 3.24, 3.27). The state equation is
discretised exactly with a zero-order hold at the *actual* interval ``h_k`` of every sample
(eq. 3.29–3.31, ``scipy.signal.cont2discrete``); the discrete matrices are memoised per
(λ, hold, interval rounded to 1 µs), so the hot path is a cache look-up and a 2×2 product.

Timing convention (causal, eq. 3.29–3.30): on ``update(w_k, h_k)`` the state is propagated from
t_{k-1} to t_k with the previous input ``w_{k-1}`` held over the interval, then the output at t_k is
``C x_k + D w_k``.

``hold="foh"`` is an option beyond the thesis: it treats the input as piecewise *linear* between
samples (first-order hold, also exact, via ``cont2discrete(method="foh")``), which removes the
half-sample lag a ZOH puts on a smooth measured signal such as heading. The default is the thesis'
ZOH.
"""
from __future__ import annotations

import logging
import math
from functools import lru_cache

import numpy as np
from scipy.signal import cont2discrete

logger = logging.getLogger(__name__)

#: thesis §3.2.2, Fig. 3.3: the yaw SVF is run with λ = 1 rad/s
DEFAULT_BANDWIDTH = 1.0
_CACHE_SIZE = 512
_DT_RESOLUTION_DIGITS = 6  # cache key: dt rounded to 1 µs


@lru_cache(maxsize=_CACHE_SIZE)
def _discretise(bandwidth: float, hold: str, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation of eq. 3.26/3.28 over ``dt`` (eq. 3.31) for the given hold.

    A memo of a pure function (read-only results), shared by all filters of the same λ and hold so
    that a fresh identifier per thrust setting does not pay ``cont2discrete`` again for every
    interval it meets.
    """
    lam = bandwidth
    a = np.array([[-2.0 * lam, -lam * lam], [1.0, 0.0]])
    b = np.array([[1.0], [0.0]])
    ad, bd, _, dd, _ = cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), dt, method=hold)
    if hold == "zoh":
        b_prev, b_now = bd[:, 0].copy(), np.zeros(2)
    else:
        # scipy's FOH realisation uses the shifted state ξ_k = x_k − dd·w_k with
        # ξ_{k+1} = Ad ξ_k + bd w_k; back in x: x_{k+1} = Ad x_k + (bd − Ad·dd) w_k + dd·w_{k+1}
        # (C = I here, so dd is the direct term on x).
        b_prev = bd[:, 0] - ad @ dd[:, 0]
        b_now = dd[:, 0].copy()
    for matrix in (ad, b_prev, b_now):
        matrix.flags.writeable = False
    return ad, b_prev, b_now


class StateVariableFilter:
    """Second-order SVF λ²/(s+λ)² with exact hold discretisation at a varying interval (eq. 3.26–3.31).

    ``update(value, dt)`` returns ``(filtered, filtered_rate, filtered_acceleration)`` =
    ``(w_f⁽⁰⁾, w_f⁽¹⁾, w_f⁽²⁾)``. Call ``reset(value)`` first to start at rest at ``value`` (the
    steady state for a constant input), otherwise the filter starts at rest at zero.
    """

    def __init__(self, bandwidth: float = DEFAULT_BANDWIDTH, hold: str = "zoh") -> None:
        if not (math.isfinite(bandwidth) and bandwidth > 0.0):
            raise ValueError(f"bandwidth must be a positive finite number, got {bandwidth!r}")
        if hold not in ("zoh", "foh"):
            raise ValueError(f"hold must be 'zoh' or 'foh', got {hold!r}")
        self.bandwidth = float(bandwidth)
        self.hold = hold
        lam = self.bandwidth
        self._a = np.array([[-2.0 * lam, -lam * lam], [1.0, 0.0]])
        self._b = np.array([[1.0], [0.0]])
        self._c = lam * lam * np.array([[-2.0 * lam, -lam * lam], [1.0, 0.0], [0.0, 1.0]])
        self._d = lam * lam * np.array([[1.0], [0.0], [0.0]])
        self._state = np.zeros(2)
        self._last_input = 0.0

    # ------------------------------------------------------------------ discretisation
    def _discrete(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Ad, B_prev, B_now): x_k = Ad x_{k-1} + B_prev w_{k-1} + B_now w_k (exact for the hold)."""
        return _discretise(self.bandwidth, self.hold, round(dt, _DT_RESOLUTION_DIGITS))

    # ------------------------------------------------------------------ use
    def reset(self, value: float = 0.0) -> None:
        """Start at rest with a constant input ``value``: outputs (value, 0, 0)."""
        lam2 = self.bandwidth * self.bandwidth
        self._state = np.array([0.0, float(value) / lam2])
        self._last_input = float(value)

    def outputs(self, value: float) -> tuple[float, float, float]:
        """Filter output for the current state with input ``value`` (eq. 3.27)."""
        y = self._c @ self._state + self._d[:, 0] * value
        return float(y[2]), float(y[1]), float(y[0])

    def update(self, value: float, dt: float) -> tuple[float, float, float]:
        """Advance by ``dt`` seconds to the new sample ``value``; return (y_f, ẏ_f, ÿ_f) (eq. 3.29–3.30)."""
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be a positive finite number, got {dt!r}")
        ad, b_prev, b_now = self._discrete(dt)
        value = float(value)
        self._state = ad @ self._state + b_prev * self._last_input + b_now * value
        self._last_input = value
        return self.outputs(value)
