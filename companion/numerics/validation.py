"""Cross-validation of an identified model on fresh data (SPEC C4; thesis 002 §3.2.4, eq. 3.35–3.37).

The identified model is simulated on the *recorded* actuator input, held constant between samples
(zero-order hold, exact discretisation per interval with ``scipy.signal.cont2discrete``, so varying
intervals are handled), from the first recorded output and rate; the fit is

    R² = 1 − J_k / Var(y_real),  J_k = mean((y_sim − y_real)²),  Var = population variance.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.signal import cont2discrete

from .identification import PitchModel, YawEstimate

ArrayLike = Sequence[float] | np.ndarray


def _simulate_linear(
    a: np.ndarray, b: np.ndarray, times: ArrayLike, inputs: np.ndarray, x0: np.ndarray
) -> np.ndarray:
    """x' = A x + B u with u (rows of ``inputs``) held from each sample to the next; returns x at the samples."""
    times = np.asarray(times, dtype=float)
    n = times.size
    states = np.empty((n, a.shape[0]))
    if n == 0:
        return states
    states[0] = x0
    c = np.eye(a.shape[0])
    d = np.zeros((a.shape[0], b.shape[1]))
    cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    x = np.asarray(x0, dtype=float)
    finite_rows = np.flatnonzero(np.all(np.isfinite(inputs), axis=1))
    u_held = inputs[finite_rows[0]] if finite_rows.size else np.zeros(inputs.shape[1])
    for k in range(1, n):
        dt = times[k] - times[k - 1]
        if not (dt > 0.0):
            raise ValueError(f"times must be strictly increasing (index {k})")
        key = round(float(dt), 9)
        if key not in cache:
            ad, bd, *_ = cont2discrete((a, b, c, d), key, method="zoh")
            cache[key] = (ad, bd)
        ad, bd = cache[key]
        x = ad @ x + bd @ u_held
        states[k] = x
        if np.all(np.isfinite(inputs[k])):
            u_held = inputs[k]  # a NaN input sample keeps the previous value held
    return states


def simulate_yaw(
    model: YawEstimate, times: ArrayLike, rudder: ArrayLike, heading0: float, yaw_rate0: float = 0.0
) -> np.ndarray:
    """Heading (unwrapped, rad) of ψ̇ = r, ṙ = a22·r + b2·(δr − δ0) (eq. 3.5–3.6) on the recorded rudder."""
    a = np.array([[0.0, 1.0], [0.0, model.a22]])
    b = np.array([[0.0], [model.b2]])
    effective = (np.asarray(rudder, dtype=float) - model.delta0).reshape(-1, 1)
    return _simulate_linear(a, b, times, effective, np.array([heading0, yaw_rate0]))[:, 0]


def simulate_yaw_scaled(model: YawEstimate, times: ArrayLike, rudder: ArrayLike, heading0: float, yaw_rate0: float,
                        a22_scale: ArrayLike, b2_scale: ArrayLike) -> np.ndarray:
    """Heading of ψ̇ = r, ṙ = a22·sₐ(t)·r + b2·s_b(t)·δr − C0 (eq. L.3, C0 = b2·δ0): the model of one
    reference speed flown at the recorded speeds, the factors held like the rudder from each sample
    to the next (zero-order hold, exact per interval)."""
    times = np.asarray(times, dtype=float)
    rudder = np.asarray(rudder, dtype=float)
    a_scale, b_scale = np.asarray(a22_scale, dtype=float), np.asarray(b2_scale, dtype=float)
    if not len(times) == len(rudder) == len(a_scale) == len(b_scale):
        raise ValueError("times, rudder and the speed factors must have one length")
    headings = np.empty(times.size)
    if times.size == 0:
        return headings
    headings[0] = heading0
    c0 = model.b2 * model.delta0
    finite = np.flatnonzero(np.isfinite(rudder))
    held = rudder[finite[0]] if finite.size else 0.0
    dts = np.diff(times)
    if np.any(~(dts > 0.0)):
        raise ValueError(f"times must be strictly increasing (index {int(np.flatnonzero(~(dts > 0.0))[0]) + 1})")
    alphas = model.a22 * a_scale[:-1]
    phi1s, phi2s = interval_factors(alphas, dts)
    heading, rate = float(heading0), float(yaw_rate0)
    for k in range(1, times.size):
        phi1, phi2, beta = float(phi1s[k - 1]), float(phi2s[k - 1]), model.b2 * b_scale[k - 1] * held - c0
        heading, rate = heading + rate * phi1 + beta * phi2, (1.0 + alphas[k - 1] * phi1) * rate + beta * phi1
        headings[k] = heading
        if math.isfinite(rudder[k]):
            held = rudder[k]
    return headings


def interval_factors(alpha: float | np.ndarray, dt: float | np.ndarray) -> tuple:
    """φ₁ = (e^{αdt} − 1)/α and φ₂ = (φ₁ − dt)/α of one held interval (eq. L.3), by their series
    dt·(1 + αdt/2) and dt²·(1/2 + αdt/6) where |α·dt| < 1e-6 (scalars or arrays alike)."""
    alpha, dt = np.asarray(alpha, dtype=float), np.asarray(dt, dtype=float)
    ad = alpha * dt
    small = np.abs(ad) < 1e-6
    safe = np.where(small, 1.0, alpha)
    phi1 = np.where(small, dt * (1.0 + ad / 2.0), np.expm1(ad) / safe)
    phi2 = np.where(small, dt * dt * (0.5 + ad / 6.0), (phi1 - dt) / safe)
    return phi1, phi2


def simulate_pitch(
    model: PitchModel, times: ArrayLike, elevator: ArrayLike, pitch0: float, pitch_rate0: float = 0.0
) -> np.ndarray:
    """Pitch (rad) of θ̇ = q, q̇ = −c22·q − c23·θ + d2·δs + Cb (eq. B.9–B.10) on the recorded elevator."""
    a = np.array([[0.0, 1.0], [-model.c23, -model.c22]])
    b = np.array([[0.0, 0.0], [model.d2, model.cb]])
    elevator = np.asarray(elevator, dtype=float)
    inputs = np.column_stack([elevator, np.ones_like(elevator)])
    return _simulate_linear(a, b, times, inputs, np.array([pitch0, pitch_rate0]))[:, 0]


def r_squared(simulated: ArrayLike, measured: ArrayLike) -> float:
    """R² = 1 − mean((sim − real)²)/Var(real) (eq. 3.35–3.37); NaN pairs are ignored."""
    simulated = np.asarray(simulated, dtype=float)
    measured = np.asarray(measured, dtype=float)
    if simulated.shape != measured.shape:
        raise ValueError("simulated and measured must have the same length")
    ok = np.isfinite(simulated) & np.isfinite(measured)
    if ok.sum() < 2:
        return math.nan
    variance = float(np.var(measured[ok]))
    if variance == 0.0:
        return math.nan
    return 1.0 - float(np.mean((simulated[ok] - measured[ok]) ** 2)) / variance


def unwrap_finite(angles: ArrayLike) -> np.ndarray:
    """``np.unwrap`` over the finite entries only (NaN entries stay NaN and do not poison the rest)."""
    angles = np.asarray(angles, dtype=float).copy()
    ok = np.isfinite(angles)
    angles[ok] = np.unwrap(angles[ok])
    return angles


def _from_first_finite(times: ArrayLike, output: np.ndarray, actuator: ArrayLike):
    finite = np.flatnonzero(np.isfinite(output))
    if finite.size < 2:
        raise ValueError("need at least two finite output samples")
    start = int(finite[0])
    return np.asarray(times, dtype=float)[start:], output[start:], np.asarray(actuator, dtype=float)[start:]


def validate_yaw(
    model: YawEstimate, times: ArrayLike, heading: ArrayLike, rudder: ArrayLike, yaw_rate0: float = 0.0
) -> float:
    """R² (eq. 3.35) of the yaw estimate (a model or not) on a validation record, simulated from its
    first finite heading.

    ``heading`` may be wrapped (it is unwrapped here); NaN headings are ignored in R², a NaN rudder
    sample keeps the previous rudder held.
    """
    times, heading_unwrapped, rudder = _from_first_finite(times, unwrap_finite(heading), rudder)
    simulated = simulate_yaw(model, times, rudder, float(heading_unwrapped[0]), yaw_rate0)
    return r_squared(simulated, heading_unwrapped)


def validate_pitch(
    model: PitchModel, times: ArrayLike, pitch: ArrayLike, elevator: ArrayLike, pitch_rate0: float = 0.0
) -> float:
    """R² of the pitch model on a validation record (same conventions as :func:`validate_yaw`)."""
    times, pitch, elevator = _from_first_finite(times, np.asarray(pitch, dtype=float), elevator)
    simulated = simulate_pitch(model, times, elevator, float(pitch[0]), pitch_rate0)
    return r_squared(simulated, pitch)
