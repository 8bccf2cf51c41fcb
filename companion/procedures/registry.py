"""What the companion can run, registered in one place.

``PROCEDURES``: the procedures started by name or by a ground-station command (``COMMANDS``).
``GAIN_SCHEDULES``: the gain schedules a campaign can design and ``companion run`` keeps matched to
speed (name -> factory taking the gain bounds, or nothing for the kind's defaults). Adding a
schedule is its behaviour module, its numerics, and one line here.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable

from pymavlink.dialects.v20.common import MAV_CMD_USER_1, MAV_CMD_USER_2, MAV_CMD_USER_3, MAV_CMD_USER_4, MAV_CMD_USER_5

from behaviors.cascade_schedule import cascade_kind
from behaviors.gain_scheduling import ScheduleKind
from behaviors.heading_schedule import heading_kind
from behaviors.pitch_schedule import pitch_kind

if TYPE_CHECKING:
    from companion.procedures.min_speed import MinSpeedProcedureConfig
    from companion.procedures.roll import RollProcedureConfig
    from companion.procedures.steady_state import SteadyStateConfig

GAIN_SCHEDULES: dict[str, Callable[..., ScheduleKind]] = {
    "heading": heading_kind,
    "pitch": pitch_kind,
    "cascade": cascade_kind,  # ArduPilot's native heading gains (the ardurover/ardusub profiles' "heading")
}


def schedule_kind(name: str, bounds=None) -> ScheduleKind:
    """The registered kind ``name`` (with ``bounds`` when given); ValueError for an unknown name."""
    try:
        factory = GAIN_SCHEDULES[name]
    except KeyError:
        raise ValueError(f"unknown gain schedule {name!r} (known: {', '.join(GAIN_SCHEDULES)})") from None
    return factory(bounds) if bounds is not None else factory()


# --------------------------------------------------------------------------- procedures
@dataclass(frozen=True)
class ProcedureContext:
    """What a procedure is built with: its configuration, the simulator preset (vehicle data and
    test hooks, when rehearsing) and a duration asked for by the ground station (param1, seconds)."""

    roll: "RollProcedureConfig" = field(default_factory=lambda: _roll_config())
    min_speed: "MinSpeedProcedureConfig" = field(default_factory=lambda: _min_speed_config())
    steady_state: "SteadyStateConfig" = field(default_factory=lambda: _steady_config())
    preset: str | None = None
    simulator: bool = False
    seconds: float | None = None


@dataclass(frozen=True)
class ProcedureSpec:
    """A procedure the companion can run by name (command line) or by command (ground station).

    ``build(link, context)`` returns the procedure (a behaviour, run by ``run_procedure`` under one
    restore point); ``summary(result)`` the JSON figures of its result."""

    name: str
    command: int | None
    build: Callable[[object, ProcedureContext], object]
    summary: Callable[[dict], dict]
    applies: Callable[[object], str | None] = lambda profile: None  # None, or why it does not apply


def _roll_config():
    from companion.procedures.roll import RollProcedureConfig

    return RollProcedureConfig()


def _min_speed_config():
    from companion.procedures.min_speed import MinSpeedProcedureConfig

    # issue 10: the governed move to the predicted TR* (falls back to the thesis' nominal start when
    # the vehicle data give no TR*: MinSpeedProcedure)
    return MinSpeedProcedureConfig.governed()


def _steady_config():
    from companion.procedures.steady_state import SteadyStateConfig

    return SteadyStateConfig()


def _build_roll(link, context: ProcedureContext):
    from companion.procedures.roll import RollProcedure

    config = replace(context.roll, closed_s=context.seconds) if context.seconds else context.roll
    return RollProcedure(config, simulator=context.simulator)


def _build_min_speed(link, context: ProcedureContext):
    from companion.procedures.min_speed import MinSpeedProcedure, analytic_minimum_speed, read_depth_gains

    config = replace(context.min_speed, duration_s=context.seconds) if context.seconds else context.min_speed
    return MinSpeedProcedure(config, depth_gains=read_depth_gains(link), analytic=analytic_minimum_speed(context.preset))


def _build_steady_state(link, context: ProcedureContext):
    from companion.procedures.steady_state import SteadyStateProcedure

    return SteadyStateProcedure(context.steady_state)


def _roll_summary(result: dict) -> dict:
    from companion.procedures.roll import roll_summary

    return roll_summary(result)


def _min_speed_summary(result: dict) -> dict:
    from companion.procedures.min_speed import min_speed_summary

    return min_speed_summary(result)


def _steady_summary(result: dict) -> dict:
    from companion.procedures.steady_state import steady_summary

    return steady_summary(result)


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


#: procedures started by name; the identification campaign (MAV_CMD_USER_1) is run by
#: ``companion.procedures.app.run_campaign`` because it stores its records as it goes
PROCEDURES: dict[str, ProcedureSpec] = {
    "roll": ProcedureSpec("roll", MAV_CMD_USER_2, _build_roll, _roll_summary, _needs_rolling_mass),
    "min_speed": ProcedureSpec("min_speed", MAV_CMD_USER_3, _build_min_speed, _min_speed_summary, _needs_fin_depth_loop),
    "steady_state": ProcedureSpec("steady_state", MAV_CMD_USER_5, _build_steady_state, _steady_summary),
}

#: the ground station's commands (COMMAND_LONG to component 191) and what they start
IDENTIFICATION_COMMAND = MAV_CMD_USER_1
ABORT_COMMAND = MAV_CMD_USER_4
COMMANDS: dict[int, str] = {IDENTIFICATION_COMMAND: "identification",
                            **{spec.command: name for name, spec in PROCEDURES.items() if spec.command is not None}}
