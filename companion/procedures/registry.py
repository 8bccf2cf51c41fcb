"""The procedures the companion runs by name or by a ground-station command, registered in one place.

``PROCEDURES``: name → :class:`ProcedureSpec` (how to build it, its figures, whether it applies to
a vehicle); ``COMMANDS``: the ground station's COMMAND_LONG ids (to component 191) and what they
start. The identification campaign (``MAV_CMD_USER_1``) is run by
``companion.procedures.app.run_campaign`` because it stores its records as it goes. The gain
schedules are registered beside the behaviours (``behaviors.schedules``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Protocol

from pymavlink.dialects.v20.common import MAV_CMD_USER_1, MAV_CMD_USER_2, MAV_CMD_USER_3, MAV_CMD_USER_4, MAV_CMD_USER_5

from companion.interface import Behavior
from companion.procedures.min_speed import (MinSpeedProcedure, MinSpeedProcedureConfig, analytic_minimum_speed,
                                            min_speed_summary, read_depth_gains)
from companion.procedures.roll import RollProcedure, RollProcedureConfig, roll_summary
from companion.procedures.results import ProcedureResult
from companion.procedures.steady_state import SteadyStateConfig, SteadyStateProcedure, steady_summary


class Procedure(Behavior, Protocol):
    """What :attr:`ProcedureSpec.build` returns: a behaviour whose result is a :class:`ProcedureResult`."""

    def result(self) -> ProcedureResult: ...


@dataclass(frozen=True)
class ProcedureContext:
    """What a procedure is built with: its configuration, the simulator preset (vehicle data and
    test hooks, when rehearsing) and a duration asked for by the ground station (param1, seconds).

    Minimum-speed seeking starts with the levelled move to the predicted TR* (the level-flight pitch
    fed forward through the depth set-point), falling back to the thesis' nominal start when the
    vehicle data give no TR* (``MinSpeedProcedure``)."""

    roll: RollProcedureConfig = field(default_factory=RollProcedureConfig)
    min_speed: MinSpeedProcedureConfig = field(default_factory=MinSpeedProcedureConfig.levelled)
    steady_state: SteadyStateConfig = field(default_factory=SteadyStateConfig)
    preset: str | None = None
    simulator: bool = False
    seconds: float | None = None


@dataclass(frozen=True)
class ProcedureSpec:
    """A procedure the companion can run by name (command line) or by command (ground station).

    ``build(link, context)`` returns the procedure (a behaviour, run by ``run_procedure`` under one
    restore point); ``summary(stored_result)`` the JSON figures of its result."""

    name: str
    command: int | None
    build: Callable[[object, ProcedureContext], Procedure]
    summary: Callable[[dict], dict]
    applies: Callable[[object], str | None] = lambda profile: None  # None, or why it does not apply


def _build_roll(link, context: ProcedureContext) -> RollProcedure:
    config = replace(context.roll, closed_s=context.seconds) if context.seconds else context.roll
    return RollProcedure(config, simulator=context.simulator)


def _build_min_speed(link, context: ProcedureContext) -> MinSpeedProcedure:
    config = replace(context.min_speed, duration_s=context.seconds) if context.seconds else context.min_speed
    return MinSpeedProcedure(config, depth_gains=read_depth_gains(link), analytic=analytic_minimum_speed(context.preset))


def _build_steady_state(link, context: ProcedureContext) -> SteadyStateProcedure:
    return SteadyStateProcedure(context.steady_state)


def _needs_rolling_mass(profile) -> str | None:
    if profile is not None and getattr(profile, "mass_servo", None) is None:
        return f"roll stabilisation needs a rolling mass on a spare servo output; the {profile.name} profile has none"
    return None


def _needs_fin_depth_loop(profile) -> str | None:
    if profile is None:
        return None
    if "elevator" not in profile.servo_outputs or not getattr(profile, "depth_setpoint", True):
        return (f"minimum-speed seeking needs a depth loop flown by an elevator with a thrust set-point; "
                f"the {profile.name} profile has none (a boat, or an ROV holding depth with thrusters)")
    return None


PROCEDURES: dict[str, ProcedureSpec] = {
    "roll": ProcedureSpec("roll", MAV_CMD_USER_2, _build_roll, roll_summary, _needs_rolling_mass),
    "min_speed": ProcedureSpec("min_speed", MAV_CMD_USER_3, _build_min_speed, min_speed_summary, _needs_fin_depth_loop),
    "steady_state": ProcedureSpec("steady_state", MAV_CMD_USER_5, _build_steady_state, steady_summary),
}

IDENTIFICATION_COMMAND = MAV_CMD_USER_1
ABORT_COMMAND = MAV_CMD_USER_4
COMMANDS: dict[int, str] = {IDENTIFICATION_COMMAND: "identification",
                            **{spec.command: name for name, spec in PROCEDURES.items() if spec.command is not None}}
