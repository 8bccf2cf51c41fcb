"""SVF (SPEC C3, eq. 3.26–3.31) and RLS (thesis §3.2.3) unit tests."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.numerics.rls import RecursiveLeastSquares
from companion.numerics.svf import StateVariableFilter


def _jittered_times(duration: float, seed: int, h: float = 0.05, jitter: float = 0.3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = h * (1.0 + rng.uniform(-jitter, jitter, int(duration / h * 1.5)))
    times = np.round(np.concatenate([[0.0], np.cumsum(steps)]), 3)  # time_boot_ms grid
    return times[times <= duration]


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("bandwidth", [0.5, 1.0, 3.0])
def test_step_response_is_exact_at_varying_intervals(hold, bandwidth):
    """A unit step starting exactly at a sample is reproduced to round-off, jittered intervals included.

    Times are on the 1 ms grid of MAVLink's time_boot_ms (the discretisation cache keys dt to 1 µs).
    """
    times = _jittered_times(10.0, seed=1)
    svf = StateVariableFilter(bandwidth, hold=hold)
    svf.reset(0.0)
    # at rest at 0, the input becomes 1 at the sample t=0 (held from it on, for both holds)
    svf._last_input = 1.0
    lam = bandwidth
    worst = 0.0
    for k in range(1, times.size):
        y, y_dot, y_ddot = svf.update(1.0, times[k] - times[k - 1])
        t = times[k]
        expected = (
            1.0 - (1.0 + lam * t) * math.exp(-lam * t),
            lam * lam * t * math.exp(-lam * t),
            lam * lam * (1.0 - lam * t) * math.exp(-lam * t),
        )
        worst = max(worst, *(abs(a - b) for a, b in zip((y, y_dot, y_ddot), expected)))
    assert worst < 1e-10


@pytest.mark.parametrize("hold, tolerance", [("foh", 2e-3), ("zoh", 8e-2)])
def test_sinusoid_derivatives_after_transient(hold, tolerance):
    """Outputs equal Im(F(jω)·[1, jω, −ω²]·e^{jωt}) after the transient, relative to each amplitude.

    FOH is exact to O(h²) for a smooth input; ZOH treats the samples as a staircase (half-sample
    lag, O(ωh)), hence its looser bound.
    """
    omega, lam = 0.8, 1.0
    times = _jittered_times(40.0, seed=2)
    svf = StateVariableFilter(lam, hold=hold)
    svf.reset(0.0)
    gain = lam**2 / (1j * omega + lam) ** 2
    errors = []
    for k in range(1, times.size):
        t = times[k]
        outputs = svf.update(math.sin(omega * t), t - times[k - 1])
        if t < 20.0:
            continue
        phasor = gain * np.exp(1j * omega * t)  # sin(ωt) = Im(e^{jωt})
        expected = [phasor.imag, (1j * omega * phasor).imag, ((1j * omega) ** 2 * phasor).imag]
        amplitude = [abs(gain), abs(gain) * omega, abs(gain) * omega**2]
        errors.append([abs(o - e) / a for o, e, a in zip(outputs, expected, amplitude)])
    worst = np.max(errors)
    assert worst < tolerance


def test_reset_gives_steady_state_and_rejects_bad_interval():
    svf = StateVariableFilter(1.0)
    svf.reset(2.5)
    for _ in range(50):
        y = svf.update(2.5, 0.05)
    assert y == pytest.approx((2.5, 0.0, 0.0), abs=1e-12)
    for bad in (0.0, -0.1, math.nan):
        with pytest.raises(ValueError):
            svf.update(1.0, bad)
    with pytest.raises(ValueError):
        StateVariableFilter(-1.0)


def test_discretisation_cache_is_bounded_and_shared():
    from companion.numerics.svf import _discretise

    svf = StateVariableFilter(1.0)
    svf.reset(0.0)
    for k in range(600):
        svf.update(0.0, 0.04 + k * 1e-5)
    info = _discretise.cache_info()
    assert info.currsize <= info.maxsize == 512
    hits = info.hits
    StateVariableFilter(1.0).update(0.0, 0.04 + 599e-5)  # a new filter reuses the memo
    assert _discretise.cache_info().hits == hits + 1


def test_rls_equals_regularised_batch_least_squares():
    rng = np.random.default_rng(3)
    phi = rng.normal(size=(200, 3))
    y = phi @ np.array([1.5, -0.7, 0.2]) + rng.normal(0, 0.1, 200)
    rls = RecursiveLeastSquares(3, p0=100.0)
    for row, target in zip(phi, y):
        rls.update(row, target)
    batch = np.linalg.solve(phi.T @ phi + np.eye(3) / 100.0, phi.T @ y)
    assert rls.theta == pytest.approx(batch, abs=1e-9)
    assert rls.covariance == pytest.approx(np.linalg.inv(phi.T @ phi + np.eye(3) / 100.0), abs=1e-12)
    # parameter covariance ≈ σ²(ΦᵀΦ)⁻¹ with σ = 0.1
    sigma = np.sqrt(np.diag(rls.parameter_covariance()))
    assert sigma == pytest.approx(0.1 / np.sqrt(np.diag(phi.T @ phi)), rel=0.3)


def test_rls_forgetting_tracks_a_parameter_change():
    rng = np.random.default_rng(4)
    plain, forgetful = RecursiveLeastSquares(1), RecursiveLeastSquares(1, forgetting=0.95)
    for k in range(400):
        x = rng.normal()
        true = 1.0 if k < 200 else 2.0
        plain.update([x], true * x)
        forgetful.update([x], true * x)
    assert forgetful.theta[0] == pytest.approx(2.0, abs=1e-3)
    assert abs(plain.theta[0] - 2.0) > 0.2
    with pytest.raises(ValueError):
        RecursiveLeastSquares(2, forgetting=1.5)
