"""The simulator's physics and autopilot in-process, driven by companion commands (no MAVLink).

For fast, exactly reproducible tests and bench runs of behaviours, the campaign state machine and
the abort paths. The harness may import both the simulator and the companion; the product never
does. The end-to-end tests over MAVLink live in tests/test_e2e_*.py.

* :class:`InProcessLink` — the runner's Link protocol (``next_telemetry``, ``execute``,
  parameters, modes, overrides, ground-station commands) over :class:`sim.autopilot.Autopilot`.
  Fault injection: ``refuse`` (native parameter names whose writes are refused),
  ``lose_link_at_s`` (next_telemetry raises after that vehicle time), ``nan_from_s`` (attitude
  turns NaN from then on).
* :class:`ClosedLoop` — a vehicle in the heading-and-depth holding mode that steps a behaviour at
  the telemetry rate (``run``), or the physics alone (``advance``).
* :class:`HuginLoop` — the ``hugin`` preset's vehicle with the simulator's heading PI and depth
  cascade as holding mode, without the autopilot (steady-state manoeuvres).

Both :class:`InProcessLink` and :class:`ClosedLoop` apply commands through :func:`dispatch`, the
one mapping of a :class:`companion.interface.Command` onto the simulated autopilot, the way the
MAVLink link would (set-points, RC overrides refreshed every physics step, rolling mass through
DO_SET_SERVO with its PWM rounding, modes and parameters through the ``sim`` profile).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Protocol, Sequence

from companion.interface import (
    Behavior,
    Command,
    NamedValue,
    OverrideActuator,
    ReleaseActuator,
    SetDepth,
    SetHeading,
    SetMode,
    SetParameters,
    SetRollingMass,
    SetThrust,
    StatusText,
    Telemetry,
)
from companion.link.parameters import ForeignChange
from companion.link.profiles import SIM as PROFILE
from sim.autopilot import MODE_ALT_HOLD, Autopilot, pwm_from_fin
from sim.params import ParamTable
from sim.preset import load_preset
from sim.build import build_vehicle
from sim.vehicle import ActuatorDemand, Vehicle

__all__ = ["ClosedLoop", "HuginLoop", "InProcessLink", "LinkLost", "ParamRefused", "dispatch", "telemetry_from"]


class LinkLost(RuntimeError):
    pass


class ParamRefused(RuntimeError):
    pass


def telemetry_from(measurements, mode: str = "hold", armed: bool = True) -> Telemetry:
    """A Telemetry snapshot from :meth:`sim.vehicle.Vehicle.measure` output."""
    m = measurements
    return Telemetry(
        time_s=round(m.time_s * 1000.0) / 1000.0,  # time_boot_ms resolution
        roll=m.roll, pitch=m.pitch, yaw=m.yaw,
        roll_rate=m.roll_rate, pitch_rate=m.pitch_rate, yaw_rate=m.yaw_rate,
        depth=m.depth, north=m.north, east=m.east, down=m.depth,
        vel_north=m.vel_north, vel_east=m.vel_east, vel_down=m.vel_down,
        speed_water=m.speed_water, speed_ground=m.speed_ground,
        rudder=m.rudder, elevator=m.elevator, thrust_ratio=m.thrust_ratio, mass_angle=m.mass_angle,
        mode=mode, armed=armed,
    )


def dispatch(host: "_AutopilotHost", command: Command) -> None:
    """Apply one companion command to ``host``'s simulated autopilot (the one command mapping)."""
    autopilot = host.simulated
    if isinstance(command, SetHeading):
        autopilot.set_heading(command.heading)
    elif isinstance(command, SetDepth):
        autopilot.set_depth(command.depth)
    elif isinstance(command, SetThrust):
        autopilot.set_thrust(command.thrust_level)
    elif isinstance(command, SetRollingMass):
        autopilot.set_servo(int(autopilot.params["MASS_SERVO"]), pwm_from_fin(command.angle))
    elif isinstance(command, OverrideActuator):
        host.overrides[command.actuator] = command.value
    elif isinstance(command, ReleaseActuator):
        host.release(command.actuator)
    elif isinstance(command, SetMode):
        host.set_mode(command.mode)
    elif isinstance(command, SetParameters):
        host.set_params(command.values)
    elif isinstance(command, StatusText):
        host.status_text(command.text, command.severity)
    elif isinstance(command, NamedValue):
        host.named_values.append((command.name, command.value))
    else:
        raise TypeError(f"unknown command {command!r}")


class InProcessParameters:
    """The link's parameter channel as procedures see it (``companion.link.parameters``): listeners
    told of each write before it is applied (a crash trail records it), the watched parameters and
    the changes someone else made to them (``foreign``), and which values our writes asked for."""

    def __init__(self) -> None:
        self._listeners: list[Callable[[str, float], None]] = []
        self.watched: set[str] = set()
        self.foreign: dict[str, ForeignChange] = {}
        self.cache: dict[str, float] = {}  # the last value read or written of each native parameter
        self._asked: dict[str, list[float]] = {}

    def on_write(self, listener: Callable[[str, float], None]) -> Callable[[], None]:
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener) if listener in self._listeners else None

    def notify(self, native: str, value: float) -> None:
        self._asked.setdefault(native, []).append(float(value))
        for listener in list(self._listeners):
            listener(native, value)

    def watch(self, names) -> None:
        self.watched, self.foreign, self._asked = set(names), {}, {}

    def ours(self, name: str, value: float) -> bool:
        return any(abs(asked - value) <= 1e-6 * max(1.0, abs(value)) for asked in self._asked.get(name, ()))


class InProcessClock:
    """The in-process vehicle's clock (``companion.link.port.ClockPort``): it never reboots, and it is
    in lockstep — the physics step only as the companion reads them, after every command is applied."""

    reboots = 0
    lockstep = True

    def __init__(self, vehicle: Vehicle) -> None:
        self._vehicle = vehicle

    @property
    def vehicle_time_s(self) -> float:
        return self._vehicle.time_s


class InProcessCommands:
    """The command channel of a link that applies every command at once (``CommandPort``): nothing is
    ever left unanswered, so nothing is abandoned and nothing answers late."""

    answers_late = False
    max_round_trip_s = 0.0
    abandon_generation = 0
    abandoned: tuple[int, ...] = ()
    period_s = 0.1

    def __init__(self) -> None:
        self.sends_of: dict[int, int] = {}

    def abandon(self) -> list[int]:
        return []

    def forget_abandoned(self) -> None:
        return None

    def late_answers(self, command: int) -> int:
        return 0

    def last_setpoint(self, command: int) -> tuple[float, ...] | None:
        return None

    def send(self, command: int, params: Sequence[float], *, confirmation: int = 0) -> int:
        raise NotImplementedError("the in-process link carries no MAVLink command: nothing is ever sent late")


class _Releasing(Protocol):
    def release(self, actuator: str | None = None) -> None: ...


class InProcessStrategy:
    """The autopilot strategy of the in-process link (``StrategyPort``): the simulator's autopilot
    keeps no set-point the restore must put back, and an override is released on the link itself."""

    streams: dict[int, float] = {}

    def __init__(self, host: "_Releasing", persistent_setpoints: tuple[str, ...] = ()) -> None:
        self._host = host
        self.persistent_setpoints = persistent_setpoints

    def release(self, actuator: str | None) -> None:
        self._host.release(actuator)

    def forget_targets(self) -> None:
        return None

    def forget_excitation(self) -> None:
        return None

    def release_after_crash(self, actuators: list[str]) -> None:
        for actuator in actuators:
            self._host.release(actuator)

    def not_ready(self, telemetry: Telemetry) -> str | None:
        return None


@dataclass(frozen=True)
class InProcessTransport:
    """Who the in-process link talks to (``TransportPort``): no bytes travel."""

    system_id: int = 1
    component: int = 191
    autopilot_component: int = 1
    endpoint: str = "in-process"
    bytes_received: int = 0


@dataclass(frozen=True)
class InProcessAnnouncements:
    """What the simulated vehicle announces of itself (``AnnouncementPort``): no board id."""

    hardware_uid: str | None = None


@dataclass
class InProcessModes:
    """When the vehicle confirmed the companion's latest mode (``ModePort``): NaN, no heartbeat
    confirms it in process (the mode is set at once). Mode requests are not announced: a crash
    trail of an in-process run records the behaviours' SetMode commands only."""

    commanded_at_s: float = math.nan

    def on_request(self, listener: Callable[[str], None]) -> Callable[[], None]:
        return lambda: None


class InProcessOverrides(dict):
    """The actuators held by override, by name (``OverridePort``): refreshed every physics step by the
    host; a newly held channel is not announced (a crash trail of an in-process run records the
    behaviours' OverrideActuator commands)."""

    def on_hold(self, listener: Callable[[int], None]) -> Callable[[], None]:
        return lambda: None


class InProcessTelemetry:
    """Listeners called after each snapshot the companion reads (``TelemetryPort``)."""

    def __init__(self) -> None:
        self._listeners: list[Callable[[], None]] = []

    def after_snapshot(self, listener: Callable[[], None]) -> None:
        self._listeners.append(listener)

    def stop_calling(self, listener: Callable[[], None]) -> None:
        if listener in self._listeners:
            self._listeners.remove(listener)

    def snapshot_read(self) -> None:
        for listener in list(self._listeners):
            listener()


class NothingInFlight:
    """The link members of ``VehiclePort`` that have nothing to do where every command is applied at
    once and nobody else is on the link (the in-process link, the test stub)."""

    def await_setpoints(self) -> None:
        """Every set-point is applied when it is executed: nothing to wait for."""

    def skip_to_now(self) -> int:
        """No snapshot is ever queued."""
        return 0

    def other_companion(self) -> str | None:
        return None

    def reconnect(self, timeout_s: float | None = None) -> bool:
        """A lost link here (``lose_link_at_s``) never comes back."""
        return False


class _AutopilotHost:
    """A simulated vehicle and autopilot (``simulated``) plus what the commands leave behind
    (overrides, texts, parameter writes, mode changes); shared by :class:`InProcessLink` and
    :class:`ClosedLoop`."""

    profile = PROFILE
    gcs_sysid: int = 255
    refuse: set[str] | frozenset[str] = frozenset()

    def _build(self, preset_name: str, seed: int, depth: float, speed: float | None = None,
               faults: tuple = ()) -> None:
        preset = load_preset(preset_name)
        self.vehicle = build_vehicle(preset, seed=seed, depth=depth, speed=speed, faults=faults)
        self.simulated = Autopilot(self.vehicle, ParamTable.for_preset(preset))
        self.overrides = InProcessOverrides()
        self.status_texts: list[str] = []
        self.named_values: list[tuple[str, float]] = []
        self.param_writes: list[tuple[str, float]] = []
        self.mode_changes: list[str] = []
        self.parameters = InProcessParameters()

    # ------------------------------------------------------------------ stepping
    def _step(self, dt: float) -> None:
        """One physics step; active overrides are refreshed first, as the MAVLink link does."""
        if self.overrides:
            channels = [65535] * 8
            for actuator, value in self.overrides.items():
                channels[self.profile.channel(actuator) - 1] = self.profile.actuator_to_pwm(actuator, value)
            self.simulated.rc_override(self.gcs_sysid, channels)
        self.simulated.step(dt)

    # ------------------------------------------------------------------ commands
    def execute(self, commands: Sequence[Command]) -> None:
        for command in commands:
            dispatch(self, command)

    @property
    def mode(self) -> str:
        return self.profile.mode_name(self.simulated.mode)

    def set_mode(self, neutral: str) -> None:
        self.mode_changes.append(neutral)
        self.simulated.set_mode(self.profile.mode_number(neutral))

    def release(self, actuator: str | None = None) -> None:
        names = list(self.overrides) if actuator is None else [actuator]
        channels = [65535] * 8
        for name in names:
            self.overrides.pop(name, None)
            channels[self.profile.channel(name) - 1] = 0
        self.simulated.rc_override(self.gcs_sysid, channels)

    def set_params(self, neutral_values: dict) -> dict:
        echoed = {}
        for name, value in neutral_values.items():
            native = self.profile.native_param(name)
            echoed[name] = self.set_param(native, value)
            self.param_writes.append((name, float(value)))
        return echoed

    def get_param(self, native: str) -> float:
        if native not in self.simulated.params:
            raise ParamRefused(f"no parameter {native}")
        value = self.simulated.params[native]
        self.parameters.cache[native] = value
        return value

    def set_by_someone_else(self, native: str, value: float) -> None:
        """A ground station's PARAM_SET: applied, and seen as someone else's change where watched."""
        before = self.simulated.params[native]
        self.simulated.set_param(native, float(value))
        if native in self.parameters.watched and before != value:
            self.parameters.foreign[native] = ForeignChange(native, before, float(value), self.vehicle.time_s)

    def set_param(self, native: str, value: float) -> float:
        if native in self.refuse:
            raise ParamRefused(f"{native} refused")
        self.parameters.notify(native, float(value))
        result = self.simulated.set_param(native, float(value))
        if not result.accepted:
            raise ParamRefused(f"{native} = {value} refused")
        self.parameters.cache[native] = self.simulated.params[native]
        return self.simulated.params[native]

    def status_text(self, text: str, severity: int = 6) -> None:
        self.status_texts.append(text)


@dataclass
class InProcessLink(NothingInFlight, _AutopilotHost):
    """The runner's Link protocol over the simulator's autopilot and physics in-process."""

    preset: str = "starfish"
    seed: int = 1
    telemetry_hz: float = 20.0
    physics_dt: float = 0.01
    depth: float = 2.0
    refuse: set[str] = field(default_factory=set)
    lose_link_at_s: float | None = None
    nan_from_s: float | None = None
    gcs_sysid: int = 255
    faults: tuple = ()  # sim.faults.Fault: the physics changes at their vehicle time

    def __post_init__(self) -> None:
        self._build(self.preset, self.seed, self.depth, faults=self.faults)
        self.system_id = 1
        # the rest of companion.link.port.VehiclePort: what a MAVLink link has, as it is in process
        self.clock = InProcessClock(self.vehicle)
        self.commands = InProcessCommands()
        self.autopilot = InProcessStrategy(self)
        self.transport = InProcessTransport(system_id=self.system_id)
        self.announcements = InProcessAnnouncements()
        self.modes = InProcessModes()
        self.telemetry = InProcessTelemetry()
        self.commanded_mode: str | None = None
        self.statustexts: list[tuple[float, int, str]] = []  # the simulated vehicle says nothing
        self.latest_telemetry: Telemetry | None = None
        self._report_listeners: list[Callable] = []
        self.simulated.arm(True)
        self.simulated.set_mode(MODE_ALT_HOLD)  # as a vehicle waiting for its mission would be
        self._steps_per_sample = max(1, round(1.0 / (self.telemetry_hz * self.physics_dt)))
        self._user_callback = None
        self._user_queue: list[tuple[float, int, tuple]] = []
        self.acks: list[tuple[int, int, int]] = []

    # ------------------------------------------------------------------ state
    @property
    def vehicle_time_s(self) -> float:
        return self.vehicle.time_s

    @property
    def waits_for_companion(self) -> bool:
        """The physics step only as the procedure reads them: a computation costs no vehicle time."""
        return True

    def param(self, neutral: str) -> float:
        return self.simulated.params[self.profile.native_param(neutral)]

    def get_params(self, neutral_names) -> dict:
        return {name: self.param(name) for name in neutral_names}

    # ------------------------------------------------------------------ Link protocol
    def next_telemetry(self, timeout_s: float = 5.0) -> Telemetry:
        for _ in range(self._steps_per_sample):
            self._step(self.physics_dt)
        now = self.vehicle.time_s
        if self.lose_link_at_s is not None and now >= self.lose_link_at_s:
            raise LinkLost(f"no message for {timeout_s} s")
        due = [item for item in self._user_queue if item[0] <= now]
        for item in due:
            self._user_queue.remove(item)
            if self._user_callback is not None:
                self._user_callback(item[1], item[2])
        sample = telemetry_from(self.vehicle.measure(), mode=self.mode, armed=self.simulated.armed)
        if self.mode != "manual":  # the set-point the autopilot holds (NAV_CONTROLLER_OUTPUT over MAVLink)
            sample = replace(sample, heading_target=self.simulated.heading_setpoint)
        if self.nan_from_s is not None and now >= self.nan_from_s:
            sample = replace(sample, roll=math.nan, pitch=math.nan, yaw=math.nan)
        self.latest_telemetry = sample
        self.telemetry.snapshot_read()
        return sample

    @property
    def armed(self) -> bool:
        return bool(self.simulated.armed)

    # ------------------------------------------------------------------ ground station
    @property
    def ground(self) -> "InProcessLink":
        """The ground-station side (``VehicleLink.ground``): this object answers for it."""
        return self

    def on_user_command(self, callback: Callable[[int, tuple[float, ...]], None] | None) -> None:
        self._user_callback = callback

    def inject_user_command(self, command: int, at_s: float, params: tuple = (0.0,) * 7) -> None:
        """A COMMAND_LONG from a ground station, delivered at vehicle time ``at_s``."""
        self._user_queue.append((at_s, command, params))

    def send_command_ack(self, command: int, result: int, progress: int = 0, target_system: int = 0,
                         target_component: int = 0) -> None:
        self.acks.append((command, result, progress))

    def on_report(self, listener: Callable) -> None:
        """The ground station's reports (none in process: nobody else is on the link)."""
        self._report_listeners.append(listener)


@dataclass
class ClosedLoop(_AutopilotHost):
    """A vehicle in the heading-and-depth holding mode, ready to run behaviours.

    Physics at ``physics_hz`` (100 Hz); every ``1/telemetry_hz`` (20 Hz) the vehicle's noisy
    measurements become a :class:`Telemetry`, the behaviour is stepped and its commands applied
    through :func:`dispatch` (and appended to ``log``). ``params`` are native parameter names.
    """

    preset_name: str = "starfish"
    seed: int = 0
    depth: float = 2.0
    speed: float | None = None  # None: the cruise-thrust trim speed; 0: at rest
    thrust: float | None = None  # initial thrust set-point (default CRUISE_THR)
    physics_hz: float = 100.0
    telemetry_hz: float = 20.0
    params: dict[str, float] = field(default_factory=dict)
    log: list[Command] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._build(self.preset_name, self.seed, self.depth, self.speed)
        for name, value in self.params.items():
            self.set_param(name, value)
        self.simulated.arm(True)
        self.simulated.set_mode(MODE_ALT_HOLD)
        if self.thrust is not None:
            self.simulated.set_thrust(self.thrust)
        self._substeps = max(1, round(self.physics_hz / self.telemetry_hz))
        self._dt = 1.0 / self.physics_hz

    def param(self, name: str) -> float:
        """A native parameter (e.g. ``DPT_P``)."""
        return self.simulated.params[name]

    def apply(self, commands) -> None:
        for command in commands:
            self.log.append(command)
            dispatch(self, command)

    def telemetry(self) -> Telemetry:
        return telemetry_from(self.vehicle.measure(), mode=self.mode, armed=self.simulated.armed)

    def advance(self, seconds: float) -> None:
        """Physics and autopilot only (no behaviour)."""
        for _ in range(max(0, round(seconds * self.physics_hz))):
            self._step(self._dt)

    def run(self, behavior: Behavior | None, seconds: float,
            on_sample: Callable[[Telemetry], None] | None = None) -> None:
        """Run ``seconds`` of vehicle time, stepping ``behavior`` at the telemetry rate."""
        ticks = max(0, round(seconds * self.telemetry_hz))
        for _ in range(ticks):
            sample = self.telemetry()
            if on_sample is not None:
                on_sample(sample)
            if behavior is not None and not behavior.done:
                self.apply(behavior.step(sample))
            for _ in range(self._substeps):
                self._step(self._dt)

    @property
    def time_s(self) -> float:
        return self.vehicle.time_s


class HuginLoop:
    """The sim's ``hugin`` Vehicle in-process with the sim's heading PI and depth cascade as the
    holding mode, driven by the behaviour's commands (no autopilot, no MAVLink)."""

    def __init__(self, current, seed: int) -> None:
        from sim.controllers import DepthPitchCascade, HeadingPI

        preset = load_preset("hugin")
        ap = preset.autopilot
        self.vehicle = Vehicle(preset, seed=seed, current_north=current[0], current_east=current[1],
                               depth=50.0, heading=0.4)
        self.heading_pi = HeadingPI(kp=ap.heading_p, ki=ap.heading_i, imax=ap.heading_imax, trim=ap.heading_trim,
                                    output_max=preset.actuators.rudder_max)
        self.depth = DepthPitchCascade(ap.depth_p, ap.depth_i, ap.pitch_p, ap.pitch_i, ap.pitch_max,
                                       preset.actuators.elevator_max)
        self.heading_sp, self.depth_sp, self.thrust = 0.4, 50.0, ap.cruise_thrust
        self.rudder_override: float | None = None

    def apply(self, commands) -> None:
        for c in commands:
            if isinstance(c, SetHeading):
                self.heading_sp = c.heading
            elif isinstance(c, SetThrust):
                self.thrust = c.thrust_level
            elif isinstance(c, OverrideActuator) and c.actuator == "rudder":
                self.rudder_override = c.value
            elif isinstance(c, ReleaseActuator) and c.actuator == "rudder":
                self.rudder_override = None
                self.heading_pi.reset()

    def run(self, behavior, max_s: float, dt: float = 0.05, telemetry_every: int = 2) -> None:
        steps = 0
        while not behavior.done and self.vehicle.time_s < max_s:
            m = self.vehicle.measure() if steps % telemetry_every == 0 else None
            if m is not None:
                tel = Telemetry(time_s=round(m.time_s, 6), roll=m.roll, pitch=m.pitch, yaw=m.yaw, yaw_rate=m.yaw_rate,
                                north=m.north, east=m.east, down=m.depth, depth=m.depth, vel_north=m.vel_north,
                                vel_east=m.vel_east, vel_down=m.vel_down, rudder=m.rudder, thrust_ratio=m.thrust_ratio,
                                mode="hold")
                self.apply(behavior.step(tel))
            s = self.vehicle.state
            rudder = (self.rudder_override if self.rudder_override is not None
                      else self.heading_pi.update(dt, self.heading_sp, s.yaw))
            elevator = self.depth.update(dt, self.depth_sp, s.depth, s.pitch)
            self.vehicle.step(dt, ActuatorDemand(rudder, elevator, self.thrust, 0.0))
            steps += 1
