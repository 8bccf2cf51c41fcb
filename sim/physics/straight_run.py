"""Straight running of a 3-DOF surface vessel: steady speed for a thrust, and the thrust for a speed.

At a straight, steady run r = 0, ṙ = v̇ = u̇ = 0. The control trim that keeps r = 0 is

* rudder: δ0 = the rudder's misalignment (its force is then zero, so v = 0);
* twin thrusters: the steering s0 with T_L(t + s0) = T_R(t − s0), i.e. zero yaw moment (the thrusters
  push along x only, so v = 0 too);

and the speed U solves the surge balance X_thrust + X_hull(U, 0, 0) = 0 (``hull_forces``). Both are
found with scipy ``brentq`` on the simulator's own force functions, so the run is exactly an
equilibrium of the nonlinear model the vessel integrates.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.optimize import brentq

from sim.physics.hull3dof import HullConstants, hull_forces
from sim.physics.propulsion3dof import RudderConstants, rudder_forces, twin_thruster_forces
from sim.physics.thruster import thrust_force
from sim.preset import Preset

#: thrust ratios searched when inverting speed → thrust (beyond 1 the map is extrapolated)
_THRUST_SEARCH_MAX = 5.0


@dataclass(frozen=True)
class StraightRun:
    """A straight steady run: water speed, thrust ratio (throttle), steering trim and motor demands.

    ``steering`` is the trim in the vessel's steering unit: the rudder angle (rad) with a rudder,
    the normalised steering s0 (±1) with twin thrusters; ``left``/``right`` are the motor demands."""

    speed: float
    thrust_ratio: float
    steering: float
    left: float
    right: float


def _twin_trim(preset: Preset, throttle: float) -> float:
    """Steering s0 with zero yaw moment at ``throttle`` (0 when the motors are matched or stopped)."""
    twin = preset.twin_thrusters

    def moment(s: float) -> float:
        return twin_thruster_forces(twin, preset.thruster, throttle + s, throttle - s)[2]

    if moment(0.0) == 0.0:
        return 0.0
    span = max(abs(throttle), 1e-3)
    return brentq(moment, -span, span, xtol=1e-14)


def _thrust_at(preset: Preset, throttle: float) -> tuple[float, float, float, float]:
    """(surge force, steering trim, left, right) of the propulsion held for a straight run."""
    if preset.is_skid:
        trim = _twin_trim(preset, throttle)
        left, right = throttle + trim, throttle - trim
        force = twin_thruster_forces(preset.twin_thrusters, preset.thruster, left, right)[0]
        return force, trim, left, right
    return thrust_force(preset.thruster, throttle), preset.rudder.offset, throttle, throttle


def straight_run_at_thrust(preset: Preset, thrust_ratio: float) -> StraightRun:
    """The straight run a thrust ratio (throttle) settles to: speed 0 in the thruster dead zone."""
    hull = HullConstants.from_preset(preset.hull)
    force, trim, left, right = _thrust_at(preset, thrust_ratio)
    if force <= 0.0:
        return StraightRun(0.0, thrust_ratio, trim, left, right)
    rudder = None if preset.is_skid else RudderConstants.from_preset(preset.rudder)

    def surge_balance(speed: float) -> float:
        x = hull_forces(hull, speed, 0.0, 0.0)[0] + force
        if rudder is not None:
            x += rudder_forces(rudder, speed, trim)[0]
        return x

    high = 1.0
    while surge_balance(high) > 0.0:
        high *= 2.0
        if high > 1e3:
            raise ValueError(f"no straight-run speed for thrust ratio {thrust_ratio}: the hull has no surge drag")
    speed = brentq(surge_balance, 0.0, high, xtol=1e-14)
    return StraightRun(speed, thrust_ratio, trim, left, right)


def straight_run_at_speed(preset: Preset, speed: float) -> StraightRun:
    """The straight run at water speed ``speed`` (m/s ≥ 0): the thrust ratio that holds it."""
    if speed <= 0.0:
        return straight_run_at_thrust(preset, 0.0)
    low = preset.thruster.deadzone
    if straight_run_at_thrust(preset, _THRUST_SEARCH_MAX).speed < speed:
        raise ValueError(f"{speed} m/s is beyond what thrust ratio {_THRUST_SEARCH_MAX} gives")
    thrust = brentq(lambda t: straight_run_at_thrust(preset, t).speed - speed, low, _THRUST_SEARCH_MAX, xtol=1e-14)
    run = straight_run_at_thrust(preset, thrust)
    if not math.isclose(run.speed, speed, rel_tol=1e-9, abs_tol=1e-9):
        raise ValueError(f"no straight run at {speed} m/s (found {run.speed})")
    return run
