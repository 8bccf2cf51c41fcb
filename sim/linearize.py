"""Truth for scoring identification: what the nonlinear physics linearises to (PROTOCOL "Truth").

``linearized_yaw`` differentiates the simulator's own yaw-acceleration function numerically (central
differences at r = 0), so it stays correct if the yaw law changes; ``steady_speed`` solves the
level-flight equilibrium of the dive-plane model (thesis eq. 5.18) with scipy.

A 3-DOF surface vessel (a preset with a ``hull``) is linearised about its straight run instead
(``sim/nomoto.py``): Nomoto's 2nd-order model of the sway–yaw linearisation and its first-order
approximation K, T = T1 + T2 − T3 (+ the propeller lag of a skid vessel), a22 = −1/T, b2 = K/T; its
steady speed comes from the surge balance (``sim/physics/straight_run.py``). The truth a doublet
identification of such a hull is scored against is the doublet-equivalent first-order model of that
linearisation (eq. S.6, ``sim/doublet_truth.py``; ``python -m sim linearize --doublet``), reported beside
the classic K/T.
"""
from __future__ import annotations

from sim.physics.equilibrium import level_trim_at_thrust
from sim.physics.yaw import YawConstants, yaw_acceleration
from sim.preset import Preset

_STEP = 1e-6


def linearized_yaw(preset: Preset, speed: float) -> dict:
    """{"a22", "b2", "delta0", "speed"} with ṙ ≈ a22·r + b2·(δr − δ0) at water speed ``speed``, r = 0.

    A 3-DOF preset adds "K", "T", "T1", "T2", "T3", "T_lag", "thrust_ratio", "model", "input" (and
    "b2_per_steering" for a skid vessel): see :func:`sim.nomoto.linearized_3dof`."""
    if preset.is_3dof:
        from sim.nomoto import linearized_3dof

        return linearized_3dof(preset, speed)
    c = YawConstants.from_preset(preset.yaw, preset.sway)
    a22 = (yaw_acceleration(c, speed, _STEP, 0.0) - yaw_acceleration(c, speed, -_STEP, 0.0)) / (2 * _STEP)
    b2 = (yaw_acceleration(c, speed, 0.0, _STEP) - yaw_acceleration(c, speed, 0.0, -_STEP)) / (2 * _STEP)
    delta0 = -yaw_acceleration(c, speed, 0.0, 0.0) / b2 if b2 != 0.0 else 0.0
    return {"a22": a22, "b2": b2, "delta0": delta0, "speed": speed}


def steady_speed(preset: Preset, thrust_ratio: float) -> float:
    """Steady water speed (m/s) for a thrust ratio (0 in the thruster dead zone): level flight of the
    dive plane, or a 3-DOF vessel's straight run (both motors at ``thrust_ratio`` for a skid vessel)."""
    if preset.is_3dof:
        from sim.physics.straight_run import straight_run_at_thrust

        return straight_run_at_thrust(preset, thrust_ratio).speed
    return level_trim_at_thrust(preset, thrust_ratio).speed
