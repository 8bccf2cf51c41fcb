"""Level-flight equilibria of the dive-plane model (thesis §5.2.1, eq. 5.17–5.22).

At a level, steady equilibrium q = 0, α = θ (ż = 0, eq. 5.17) and R + F = 0 (eq. 5.18). Solved
numerically with scipy.optimize.fsolve on the same force function the simulator integrates, so the
trim is exactly an equilibrium of the nonlinear model (no small-angle approximation).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.optimize import fsolve

from sim.physics.dive_plane import DivePlaneConstants, dive_plane_forces
from sim.physics.thruster import thrust_force, thrust_ratio_for_force
from sim.preset import Preset


@dataclass(frozen=True)
class LevelTrim:
    """A level-flight equilibrium: water speed V, pitch θ = α, elevator δ, thrust force and ratio."""

    speed: float
    pitch: float
    elevator: float
    thrust: float
    thrust_ratio: float


def _residual(c: DivePlaneConstants, speed: float, pitch: float, elevator: float, thrust: float) -> list[float]:
    surge = speed * math.cos(pitch)
    heave = speed * math.sin(pitch)
    fx, fz, my = dive_plane_forces(c, surge, heave, 0.0, pitch, elevator, thrust)
    return [fx, fz, my]


def level_trim_at_speed(preset: Preset, speed: float) -> LevelTrim:
    """Pitch, elevator and thrust that hold level flight at water speed ``speed`` (m/s > 0)."""
    c = DivePlaneConstants.from_preset(preset.dive_plane)
    drag_guess = -c.half_rho_ab * c.drag_coefficient * speed * speed

    def residual(x: list[float]) -> list[float]:
        pitch, elevator, thrust_scaled = x
        return _residual(c, speed, pitch, elevator, thrust_scaled * drag_guess)

    solution, info, ok, message = fsolve(residual, [0.0, 0.0, 1.0], full_output=True, xtol=1e-12)
    if ok != 1:
        raise ValueError(f"no level-flight trim at {speed} m/s: {message}")
    pitch, elevator, thrust_scaled = (float(v) for v in solution)
    thrust = thrust_scaled * drag_guess
    return LevelTrim(speed, pitch, elevator, thrust, thrust_ratio_for_force(preset.thruster, thrust))


def level_trim_at_thrust(preset: Preset, thrust_ratio: float) -> LevelTrim:
    """Level-flight equilibrium for a thrust ratio: speed, pitch and elevator (elevator unbounded)."""
    c = DivePlaneConstants.from_preset(preset.dive_plane)
    thrust = thrust_force(preset.thruster, thrust_ratio)
    if thrust <= 0.0:
        return LevelTrim(0.0, 0.0, 0.0, 0.0, thrust_ratio)
    speed_guess = math.sqrt(thrust / (-c.half_rho_ab * c.drag_coefficient))

    def residual(x: list[float]) -> list[float]:
        speed, pitch, elevator = x
        return _residual(c, speed, pitch, elevator, thrust)

    solution, info, ok, message = fsolve(residual, [speed_guess, 0.0, 0.0], full_output=True, xtol=1e-12)
    if ok != 1:
        raise ValueError(f"no level-flight equilibrium at thrust ratio {thrust_ratio}: {message}")
    speed, pitch, elevator = (float(v) for v in solution)
    return LevelTrim(speed, pitch, elevator, thrust, thrust_ratio)
