"""Seeded band-limited random roll moment (SPEC C2, C6).

A first-order Gauss–Markov (Ornstein–Uhlenbeck) process, discretised exactly:
d[k+1] = d[k]·e^(−dt/T) + σ·√(1 − e^(−2dt/T))·n[k], so its stationary standard deviation is σ
(the ``amplitude``) whatever the step. Normals are drawn from a numpy Generator in blocks, because a
scalar draw per step would dominate the step time.
"""
from __future__ import annotations

import math

import numpy as np

_BLOCK = 4096


class RollDisturbance:
    """Band-limited random moment (N·m) with stationary σ = ``amplitude``; 0 switches it off."""

    def __init__(self, rng: np.random.Generator, correlation_time: float, amplitude: float = 0.0) -> None:
        self._rng = rng
        self.correlation_time = correlation_time
        self.amplitude = amplitude
        self.moment = 0.0
        self._normals: list[float] = []
        self._cached_dt = -1.0
        self._decay = 0.0
        self._gain = 0.0

    def step(self, dt: float) -> float:
        """Advance by ``dt`` and return the moment to apply over the next step."""
        if self.amplitude <= 0.0:
            self.moment = 0.0
            return 0.0
        if dt != self._cached_dt:
            self._cached_dt = dt
            self._decay = math.exp(-dt / self.correlation_time)
            self._gain = math.sqrt(1.0 - self._decay * self._decay)
        if not self._normals:
            self._normals = self._rng.standard_normal(_BLOCK).tolist()
        self.moment = self.moment * self._decay + self.amplitude * self._gain * self._normals.pop()
        return self.moment
