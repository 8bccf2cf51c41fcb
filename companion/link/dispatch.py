"""Behaviour commands onto the link's parts: the one mapping of :mod:`companion.interface`'s
commands to what carries them out (SPEC §5: behaviours return commands, the link executes them).

Set-points and excitation go through the autopilot's strategy (the only autopilot-specific code);
modes, parameters and ground-station reports through the link's own parts.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

from companion.interface import (Command, NamedValue, OverrideActuator, ReleaseActuator, SetDepth, SetHeading,
                                 SetMode, SetParameters, SetRollingMass, SetThrust, StatusText)


def execute(strategy: Any, ports: Any, commands: Sequence[Command]) -> None:
    """Carry out ``commands`` in order (TypeError for anything that is not a known command)."""
    actions: dict[type, Callable[[Any], object]] = {
        OverrideActuator: lambda c: strategy.override(c.actuator, c.value),
        ReleaseActuator: lambda c: strategy.release(c.actuator),
        SetHeading: lambda c: strategy.set_heading(c.heading),
        SetDepth: lambda c: strategy.set_depth(c.depth),
        SetThrust: lambda c: strategy.set_thrust(c.thrust_level),
        SetRollingMass: lambda c: strategy.set_rolling_mass(c.angle),
        SetMode: lambda c: ports.modes.set_mode(c.mode),
        SetParameters: lambda c: ports.parameters.set_params(c.values),
        StatusText: lambda c: ports.ground.status_text(c.text, c.severity),
        NamedValue: lambda c: ports.ground.named_value(c.name, c.value),
    }
    for command in commands:
        action = actions.get(type(command))
        if action is None:
            raise TypeError(f"unknown command {command!r}")
        action(command)
