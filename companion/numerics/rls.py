"""Recursive least squares with an optional forgetting factor (SPEC C3; thesis 002 §3.2.3).

Hand-written because neither filterpy nor scipy ship an RLS estimator; it is ten lines of the
textbook recursion (thesis §3.2.3, after Ljung):

    ε_k = y_k − Θ_{k−1}ᵀ φ_k
    K_k = P_{k−1} φ_k / (μ + φ_kᵀ P_{k−1} φ_k)
    Θ_k = Θ_{k−1} + K_k ε_k
    P_k = (I − K_k φ_kᵀ) P_{k−1} / μ

with forgetting factor μ (1.0 = the thesis' plain RLS). The thesis prints the covariance update as
``[1 − Kᵀφ] P``; the matrix form above is the standard one it abbreviates. Initial Θ = 0 and
P = 100·I are the thesis' choice (exposed as ``theta0`` and ``p0``).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np


class RecursiveLeastSquares:
    """RLS estimator of Θ in y = φᵀΘ (thesis §3.2.3)."""

    def __init__(
        self,
        n: int,
        p0: float = 100.0,
        theta0: Sequence[float] | None = None,
        forgetting: float = 1.0,
    ) -> None:
        if n < 1:
            raise ValueError("n must be at least 1")
        if not (math.isfinite(p0) and p0 > 0.0):
            raise ValueError(f"p0 must be positive, got {p0!r}")
        if not (0.0 < forgetting <= 1.0):
            raise ValueError(f"forgetting factor must be in (0, 1], got {forgetting!r}")
        self.n = n
        self.p0 = float(p0)
        self.forgetting = float(forgetting)
        self.theta = np.zeros(n) if theta0 is None else np.asarray(theta0, dtype=float).copy()
        if self.theta.shape != (n,):
            raise ValueError(f"theta0 must have {n} entries")
        self.covariance = self.p0 * np.eye(n)
        self.samples = 0
        #: a-priori error of the last update, and the running mean of ε²/(1+φᵀPφ) (noise variance)
        self.last_error = 0.0
        self._normalised_error_sum = 0.0

    def update(self, regressor: Sequence[float], target: float) -> np.ndarray:
        """One RLS step with regressor φ and measurement y; returns the new Θ (a copy)."""
        phi = np.asarray(regressor, dtype=float)
        p_phi = self.covariance @ phi
        denominator = self.forgetting + float(phi @ p_phi)
        gain = p_phi / denominator
        error = float(target) - float(phi @ self.theta)
        self.theta = self.theta + gain * error
        self.covariance = (self.covariance - np.outer(gain, p_phi)) / self.forgetting
        # keep P symmetric against round-off
        self.covariance = 0.5 * (self.covariance + self.covariance.T)
        self.samples += 1
        self.last_error = error
        self._normalised_error_sum += error * error / denominator
        return self.theta.copy()

    @property
    def noise_variance(self) -> float:
        """Estimate of the equation-error variance from the normalised a-priori errors."""
        dof = self.samples - self.n
        return self._normalised_error_sum / dof if dof > 0 else math.nan

    def parameter_covariance(self) -> np.ndarray:
        """σ̂²·P: the covariance of Θ under white equation error (NaN before n+1 samples)."""
        return self.noise_variance * self.covariance
