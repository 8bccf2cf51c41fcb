"""The vocabulary shared by the vehicle interface and the behaviours (SPEC §5, layers 2 and 3).

A behaviour is a step function ``step(telemetry) -> list[Command]`` of vehicle time and telemetry
(SPEC §5). The link (``companion.link``) turns MAVLink into :class:`Telemetry` snapshots and
executes :class:`Command` objects; a log replayer produces the same snapshots from a recording.
Nothing here does I/O or reads a clock, so behaviours written against it run identically on a
vehicle, against the simulator and over a recorded log.

Units are SI throughout: metres, seconds, radians. A commanded *thrust level* is a fraction 0..1 of
the vehicle's full forward demand; what that demand is on each autopilot (a thrust ratio on our
simulator, a fraction of WP_SPEED on ArduRover, the forward stick on ArduSub) is stated once, by
its profile's ``thrust_meaning``, and converted once, by its strategy's ``set_thrust``. The
telemetry's ``thrust_ratio`` is the thrust actuator's read-back (0..1 forward). Angles of actuators
are the physical deflections (rudder δr, elevator δs, rolling-mass angle α), already converted from
PWM by the autopilot profile.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol, Sequence, runtime_checkable

NAN = float("nan")


@dataclass(frozen=True)
class Telemetry:
    """One snapshot of the vehicle, stamped with the autopilot's clock.

    ``time_s`` is ``time_boot_ms / 1000`` of the ATTITUDE message that completed the snapshot:
    vehicle time, never wall-clock. Fields the vehicle has not reported yet are NaN.
    """

    time_s: float
    roll: float = NAN
    pitch: float = NAN
    yaw: float = NAN  # wrapped to (-pi, pi]; unwrap before filtering (SPEC C3)
    roll_rate: float = NAN
    pitch_rate: float = NAN
    yaw_rate: float = NAN
    depth: float = NAN  # m, positive down (pressure sensor)
    north: float = NAN  # m, navigation solution
    east: float = NAN
    down: float = NAN
    vel_north: float = NAN  # m/s over ground, NED
    vel_east: float = NAN
    vel_down: float = NAN
    speed_water: float = NAN  # m/s, water-relative speed (speed log / VFR_HUD.airspeed)
    speed_ground: float = NAN  # m/s, horizontal over ground (DVL / VFR_HUD.groundspeed)
    rudder: float = NAN  # rad, actual deflection
    elevator: float = NAN  # rad, actual deflection
    thrust_ratio: float = NAN  # 0..1, actual
    mass_angle: float = NAN  # rad, rolling-mass angle
    heading_target: float = NAN  # rad, the heading set-point the autopilot reports it holds (NAV_CONTROLLER_OUTPUT)
    turn_rate_target: float = NAN  # rad/s, the turn rate its rate loop is asked for (PID_TUNING, profile.pid_tuning)
    turn_rate_achieved: float = NAN  # rad/s, the turn rate that loop measured (same message)
    speed_target: float = NAN  # m/s, the speed its speed loop is asked for (PID_TUNING, profile.speed_loop_report)
    speed_achieved: float = NAN  # m/s, the speed that loop measured (same message)
    cross_track: float = NAN  # m, the navigation's cross-track error (NAV_CONTROLLER_OUTPUT.xtrack_error)
    mode: str = ""
    armed: bool = False

    def finite(self, *names: str) -> bool:
        """True when every named field is a finite number (guards against NaN telemetry)."""
        return all(math.isfinite(getattr(self, name)) for name in names)


# --------------------------------------------------------------------------- commands
class Command:
    """Base class of everything a behaviour may ask of the vehicle."""


@dataclass(frozen=True)
class OverrideActuator(Command):
    """Drive one actuator open loop through an RC override (rudder/elevator/thrust).

    ``actuator`` is one of ``"rudder"``, ``"elevator"``, ``"thrust"``; ``value`` is radians for
    fins and a ratio for thrust. The link keeps refreshing the override until it is released.
    """

    actuator: str
    value: float


@dataclass(frozen=True)
class ReleaseActuator(Command):
    """Give an overridden actuator back to the autopilot (RC override value 0)."""

    actuator: str


@dataclass(frozen=True)
class SetHeading(Command):
    heading: float  # rad, true north, clockwise


@dataclass(frozen=True)
class SetDepth(Command):
    depth: float  # m, positive down


@dataclass(frozen=True)
class SetThrust(Command):
    """The holding/guided mode's forward demand, as a thrust level 0..1 (module docstring)."""

    thrust_level: float


@dataclass(frozen=True)
class SetRollingMass(Command):
    angle: float  # rad, rolling-mass angle (spare servo output, DO_SET_SERVO)


@dataclass(frozen=True)
class SetMode(Command):
    mode: str  # profile-neutral name: "manual", "hold" (heading-and-depth hold), "guided"


@dataclass(frozen=True)
class SetParameters(Command):
    """Write parameters by the product's neutral names (see ``companion.link.profiles``),
    e.g. ``{"heading_p": 1.2, "heading_i": 0.05, "rudder_trim": 0.01}``; the link verifies echoes."""

    values: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class StatusText(Command):
    text: str
    severity: int = 6  # MAV_SEVERITY_INFO


@dataclass(frozen=True)
class NamedValue(Command):
    """A live value for the ground station to graph (NAMED_VALUE_FLOAT, name <= 10 chars)."""

    name: str
    value: float


# --------------------------------------------------------------------------- behaviours
@runtime_checkable
class Behavior(Protocol):
    """A closed-loop procedure as a step function of vehicle time and telemetry (SPEC §5).

    ``step`` is called once per telemetry snapshot (the attitude rate) and returns the commands to
    send now. ``abort`` returns the commands that put the vehicle back as the behaviour found it;
    after it, ``done`` is true. ``result`` is what it found: a frozen record whose ``to_dict()`` is
    its JSON (``behaviors.base.BehaviourResult``; a procedure's ``ProcedureResult``,
    ``companion.procedures.results``).
    """

    @property
    def done(self) -> bool: ...

    def step(self, telemetry: Telemetry) -> Sequence[Command]: ...

    def abort(self, reason: str) -> Sequence[Command]: ...

    def result(self) -> Any: ...
