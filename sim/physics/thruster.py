"""Thruster map: thrust ratio → thrust force (SPEC §3.5, thesis Fig. 5.3 with the corrected −0.53)."""
from __future__ import annotations

import math

from sim.preset import ThrusterMap


def thrust_force(thruster: ThrusterMap, thrust_ratio: float) -> float:
    """Ft = a·TR² + b·TR + c above the dead zone, else 0; never negative (SPEC §3.5)."""
    if thrust_ratio <= thruster.deadzone:
        return 0.0
    force = (thruster.quadratic * thrust_ratio + thruster.linear) * thrust_ratio + thruster.constant
    return force if force > 0.0 else 0.0


def thrust_ratio_for_force(thruster: ThrusterMap, force: float) -> float:
    """Inverse map: the smallest thrust ratio above the dead zone that gives ``force`` (thesis eq. 5.55).

    Solves a·TR² + b·TR + (c − Ft) = 0 for its larger root (the branch above the dead zone).
    """
    if force <= 0.0:
        return thruster.deadzone
    a, b, c = thruster.quadratic, thruster.linear, thruster.constant - force
    if a == 0.0:
        return max(thruster.deadzone, -c / b)
    root = (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    return max(thruster.deadzone, root)
