"""Synthetic steering records for tests: the linear yaw model ṙ = a22·r + b2·(δ − δ0) (SPEC C3)
flown by a proportional heading hold through course changes, with a rate- and range-limited rudder,
at a speed profile of the caller's choice. Exact discretisation over ``substeps`` per sample, seeded
heading noise. The truth is the model's (a22, b2, δ0) by construction.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SteeringTruth:
    a22: float = -1.1
    b2: float = 1.0
    delta0: float = 0.01


def synth_steering(seconds: float = 240.0, rate_hz: float = 20.0, *, truth: SteeringTruth = SteeringTruth(),
                   speed=lambda t: 1.5, course_every_s: float = 30.0, course_deg=(25.0, -30.0, 20.0, -15.0),
                   kp: float = 0.6, rudder_max: float = 0.35, rudder_rate: float = 0.5,
                   heading_noise_deg: float = 0.1, seed: int = 0, substeps: int = 10,
                   b2_change: tuple[float, float] | None = None) -> dict[str, np.ndarray]:
    """{"t", "heading" (wrapped, rad), "rudder" (rad), "speed" (m/s), "course"} sampled at ``rate_hz``;
    ``b2_change`` = (time s, factor) scales b2 from that time on (a fault)."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds * rate_hz))
    dt = 1.0 / rate_hz
    h = dt / substeps
    psi = r = 0.0
    delta = truth.delta0
    out = {k: np.empty(n) for k in ("t", "heading", "rudder", "speed", "course")}
    for k in range(n):
        t = k * dt
        legs = int(t // course_every_s)
        course = math.radians(sum(course_deg[i % len(course_deg)] for i in range(legs)))
        demand = truth.delta0 + kp * (course - psi)
        demand = max(-rudder_max, min(rudder_max, demand))
        out["t"][k], out["heading"][k], out["rudder"][k] = t, psi, delta
        out["speed"][k], out["course"][k] = speed(t), course
        for _ in range(substeps):
            delta += max(-rudder_rate * h, min(rudder_rate * h, demand - delta))
            b2 = truth.b2 * (b2_change[1] if b2_change is not None and t >= b2_change[0] else 1.0)
            acc = truth.a22 * r + b2 * (delta - truth.delta0)
            psi += h * r + 0.5 * h * h * acc
            r += h * acc
    out["heading"] = np.remainder(out["heading"] + rng.normal(0, math.radians(heading_noise_deg), n) + math.pi,
                                  2 * math.pi) - math.pi
    return out
