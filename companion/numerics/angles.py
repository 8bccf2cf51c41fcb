"""Angle helpers shared by the companion and the behaviours (pure functions, no state).

The simulator keeps its own copy (``sim.vehicle.wrap_angle``) because ``sim`` never imports the
companion; both wrap to the same interval.
"""
from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * math.pi


def wrap_pi(angle):
    """Angle wrapped to (−π, π] (rad): a float for a scalar, an array for an array-like.

    Scalars use the exact IEEE remainder; arrays the same rounding of the quotient (half to even).
    Non-finite input gives NaN.
    """
    if np.ndim(angle) == 0:
        value = float(angle)
        if not math.isfinite(value):
            return math.nan
        wrapped = math.remainder(value, TWO_PI)
        return math.pi if wrapped == -math.pi else wrapped
    values = np.asarray(angle, dtype=float)
    with np.errstate(invalid="ignore"):  # ±inf → NaN, like the scalar branch
        wrapped = values - TWO_PI * np.round(values / TWO_PI)
    return np.where(wrapped <= -math.pi, wrapped + TWO_PI, wrapped)
