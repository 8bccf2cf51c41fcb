"""The procedures the companion runs by name or by a ground-station command, registered in one place.

``PROCEDURES``: name → :class:`ProcedureSpec` (how to build it, its figures, whether it applies to
a vehicle); ``COMMANDS``: the ground station's COMMAND_LONG ids (to component 191) and what they
start. The identification campaign (``MAV_CMD_USER_1``) is run by
``companion.procedures.app.run_campaign`` because it stores its records as it goes. The gain
schedules are registered beside the behaviours (``behaviors.schedules``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol

from pymavlink.dialects.v20.common import MAV_CMD_USER_1, MAV_CMD_USER_2, MAV_CMD_USER_3, MAV_CMD_USER_4, MAV_CMD_USER_5

from companion.interface import Behavior
from companion.link.profile import AutopilotProfile
from companion.procedures.min_speed import (MIN_SPEED_COLUMNS, MinSpeedProcedure, MinSpeedProcedureConfig,
                                            analytic_minimum_speed, min_speed_columns, min_speed_summary,
                                            read_depth_gains)
from companion.procedures.roll import ROLL_COLUMNS, RollProcedure, RollProcedureConfig, roll_columns, roll_summary
from companion.procedures.results import ProcedureResult
from companion.procedures.steady_state import (STEADY_COLUMNS, SteadyStateConfig, SteadyStateProcedure, steady_columns,
                                               steady_summary)
from companion.records.report_section import ReportSection


class Procedure(Behavior, Protocol):
    """What :attr:`ProcedureSpec.build` returns: a behaviour whose result is a :class:`ProcedureResult`."""

    def result(self) -> ProcedureResult: ...


@dataclass(frozen=True)
class ProcedureContext:
    """What a procedure is built with: its configuration by procedure name (``configs``; a name not
    there takes its registry entry's default), the simulator preset (vehicle data and test hooks,
    when rehearsing) and a duration asked for by the ground station (param1, seconds)."""

    configs: Mapping[str, Any] = field(default_factory=dict)
    preset: str | None = None
    simulator: bool = False
    seconds: float | None = None

    def config_for(self, name: str) -> Any:
        """The configuration of procedure ``name``: the one given, else its registered default."""
        if name in self.configs:
            return self.configs[name]
        return PROCEDURES[name].default_config()


@dataclass(frozen=True)
class ProcedureSpec:
    """One entry per procedure the companion can run by name (command line) or by command (ground
    station); everything that lists procedures derives from these entries: the command-line choices
    (``cli_name``), the rehearsal (``after_campaign``), the report (``report``) and the sweep
    (``sweep_columns``, ``sweep_row``).

    ``build(link, context)`` returns the procedure (a behaviour, run by ``run_procedure`` under one
    restore point) with ``context.config_for(name)``, whose type ``default_config`` makes;
    ``summary(stored_result)`` the JSON figures of its result; ``applies(profile)`` None or why it
    does not apply to that autopilot; ``report`` its figure in a campaign's report;
    ``sweep_row(summary_section)`` the sweep row's ``sweep_columns`` from the rehearsal summary's
    section of this name, its outcome among them as ``<name>_status``; ``after_campaign``: a
    rehearsal may fly it after its campaign."""

    name: str
    command: int | None
    build: Callable[[object, ProcedureContext], Procedure]
    summary: Callable[[dict], dict]
    default_config: Callable[[], Any]
    applies: Callable[[AutopilotProfile | None], str | None] = lambda profile: None
    report: ReportSection | None = None
    sweep_columns: tuple[str, ...] = ()
    sweep_row: Callable[[dict], dict] = lambda section: {}
    after_campaign: bool = False

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"ProcedureSpec.name must be a Python identifier, not {self.name!r}")
        if self.sweep_columns and f"{self.name}_status" not in self.sweep_columns:
            raise ValueError(f"ProcedureSpec {self.name}: its sweep columns must hold {self.name}_status")

    @property
    def cli_name(self) -> str:
        """The name on the command line (``min-speed``)."""
        return self.name.replace("_", "-")


def _build_roll(link, context: ProcedureContext) -> RollProcedure:
    base: RollProcedureConfig = context.config_for("roll")
    config = replace(base, closed_s=context.seconds) if context.seconds else base
    return RollProcedure(config, simulator=context.simulator)


def _build_min_speed(link, context: ProcedureContext) -> MinSpeedProcedure:
    base: MinSpeedProcedureConfig = context.config_for("min_speed")
    config = replace(base, duration_s=context.seconds) if context.seconds else base
    return MinSpeedProcedure(config, depth_gains=read_depth_gains(link), analytic=analytic_minimum_speed(context.preset))


def _build_steady_state(link, context: ProcedureContext) -> SteadyStateProcedure:
    return SteadyStateProcedure(context.config_for("steady_state"))


# the figures draw with matplotlib, loaded only when a report is written
def _plot_roll(result: dict, path: Path) -> str | None:
    from companion.records.behavior_plots import plot_roll

    return plot_roll(result, path)


def _plot_min_speed(result: dict, path: Path) -> str | None:
    from companion.records.behavior_plots import plot_min_speed

    return plot_min_speed(result, path)


def _plot_steady_state(result: dict, path: Path) -> str | None:
    from companion.records.behavior_plots import plot_steady_state

    return plot_steady_state(result, path)


def _needs_rolling_mass(profile: AutopilotProfile | None) -> str | None:
    if profile is not None and profile.mass_servo is None:
        return f"roll stabilisation needs a rolling mass on a spare servo output; the {profile.name} profile has none"
    return None


def _needs_fin_depth_loop(profile: AutopilotProfile | None) -> str | None:
    if profile is None:
        return None
    if "elevator" not in profile.servo_outputs or not profile.depth_setpoint:
        return (f"minimum-speed seeking needs a depth loop flown by an elevator with a thrust set-point; "
                f"the {profile.name} profile has none (a boat, or an ROV holding depth with thrusters)")
    return None


PROCEDURES: dict[str, ProcedureSpec] = {spec.name: spec for spec in (
    ProcedureSpec("roll", MAV_CMD_USER_2, _build_roll, roll_summary, RollProcedureConfig, _needs_rolling_mass,
                  ReportSection("Roll stabilisation", "roll.png", _plot_roll), ROLL_COLUMNS, roll_columns,
                  after_campaign=True),
    ProcedureSpec("min_speed", MAV_CMD_USER_3, _build_min_speed, min_speed_summary, MinSpeedProcedureConfig.levelled,
                  _needs_fin_depth_loop, ReportSection("Minimum-speed seeking", "min_speed.png", _plot_min_speed),
                  MIN_SPEED_COLUMNS, min_speed_columns, after_campaign=True),
    ProcedureSpec("steady_state", MAV_CMD_USER_5, _build_steady_state, steady_summary, SteadyStateConfig,
                  report=ReportSection("Steady-state manoeuvres under current", "steady_state.png", _plot_steady_state),
                  sweep_columns=STEADY_COLUMNS, sweep_row=steady_columns),
)}


def rehearsal_behaviors() -> tuple[str, ...]:
    """The procedures a rehearsal may fly after its campaign (``rehearse --behaviors``)."""
    return tuple(name for name, spec in PROCEDURES.items() if spec.after_campaign)


def report_sections() -> dict[str, ReportSection]:
    """Each procedure's figure in a campaign's report, by the kind its result is stored under."""
    return {name: spec.report for name, spec in PROCEDURES.items() if spec.report is not None}


def sweep_columns() -> tuple[str, ...]:
    """The sweep row's columns of every procedure, in registry order."""
    return tuple(column for spec in PROCEDURES.values() for column in spec.sweep_columns)


def sweep_row(summary: dict) -> dict:
    """The sweep row's procedure figures from a rehearsal summary (each from its own section)."""
    return {k: v for spec in PROCEDURES.values() for k, v in spec.sweep_row(summary.get(spec.name) or {}).items()}


def by_cli_name(name: str) -> ProcedureSpec | None:
    """The procedure named ``name`` on the command line (``min-speed``) or in code (``min_speed``)."""
    return PROCEDURES.get(name.replace("-", "_"))

IDENTIFICATION_COMMAND = MAV_CMD_USER_1
ABORT_COMMAND = MAV_CMD_USER_4
COMMANDS: dict[int, str] = {IDENTIFICATION_COMMAND: "identification",
                            **{spec.command: name for name, spec in PROCEDURES.items() if spec.command is not None}}
