"""The simulated vehicle a preset describes: the first-order model, or the 3-DOF surface vessel.

Every place that makes a vehicle from a preset (the MAVLink server, the ArduPilot JSON bridge,
tests) calls :func:`build_vehicle`, so a preset with a ``hull`` flies the surge–sway–yaw model
(:class:`sim.vessel3dof.Vessel3Dof`) and every other preset the unchanged :class:`sim.vehicle.Vehicle`.
"""
from __future__ import annotations

from typing import Any

from sim.preset import Preset
from sim.vehicle import Vehicle


def build_vehicle(preset: Preset, **kwargs: Any) -> Vehicle:
    """``Vessel3Dof(preset, **kwargs)`` for a 3-DOF preset, else ``Vehicle(preset, **kwargs)``."""
    if preset.is_3dof:
        from sim.vessel3dof import Vessel3Dof

        return Vessel3Dof(preset, **kwargs)
    return Vehicle(preset, **kwargs)
