"""The companion's MAVLink vehicle interface, one object over the link's parts (SPEC C1, §4).

:class:`VehicleLink` wires the parts of ``companion.link`` together and implements the port the
procedures use (``companion.link.port.VehiclePort``). Each part owns its state and is reachable by name: ``transport``
(connection, dispatch, send), ``clock`` (vehicle time, waits, lockstep), ``announcements``
(HEARTBEAT, STATUSTEXT, capabilities), ``commands`` and ``modes``, ``parameters``, ``overrides``,
``telemetry`` (snapshots in order), ``ground`` (our reports, the ground station's commands) and
``autopilot``, the profile's strategy (``autopilots/``): the only autopilot-specific code.
"""
from __future__ import annotations

from typing import Any, Iterable, Sequence

from companion.interface import Command, Telemetry
from companion.link import dispatch, handshake
from companion.link.autopilots import CONNECT_DIALECT
from companion.link.autopilots.base import AutopilotStrategy, LinkPorts
from companion.link.clock import LinkTimeouts, VehicleClock
from companion.link.commands import CommandChannel
from companion.link.errors import known_once_set_up
from companion.link.ground_station import GroundStation, UserCommand, validate_named_value_name
from companion.link.modes import ModeControl
from companion.link.overrides import OverrideChannels
from companion.link.parameters import ParameterChannel
from companion.link.profile import AutopilotProfile
from companion.link.snapshot import DepthSensor
from companion.link.telemetry import TelemetryFeed
from companion.link.transport import Transport, await_autopilot_heartbeat, open_connection
from companion.link.vehicle_state import VehicleAnnouncements

__all__ = ["LinkTimeouts", "UserCommand", "VehicleLink", "validate_named_value_name"]


class VehicleLink:
    """MAVLink interface to one autopilot. Build it with :meth:`connect`."""

    def __init__(self, master: Any, *, system_id: int, autopilot_component: int, component: int,
                 timeouts: LinkTimeouts = LinkTimeouts(), lockstep: bool = False, endpoint: str | None = None,
                 signing_key: bytes | None = None) -> None:
        self.transport = Transport(master, system_id=system_id, autopilot_component=autopilot_component,
                                   component=component, endpoint=endpoint, signing_key=signing_key,
                                   dialect=CONNECT_DIALECT)
        self.timeouts = timeouts
        self.clock = VehicleClock(self.transport, timeouts, lockstep=lockstep)
        self.waits_for_companion = bool(lockstep)  # vehicle time advances only as the companion reads it
        self.announcements = VehicleAnnouncements(self.transport)
        self.announcements.clock_s = lambda: self.clock.vehicle_time_s
        self.commands = CommandChannel(self.transport, self.clock)
        self.modes = ModeControl(self.commands, self.announcements, self.clock)
        self.parameters = ParameterChannel(self.transport, self.clock, self.announcements)
        self.overrides = OverrideChannels()
        self.telemetry = TelemetryFeed(self.transport, self.clock)
        self.ground = GroundStation(self.transport, self.clock)
        self.announcements.on_heartbeat(self.telemetry.on_heartbeat)
        self.telemetry.after_snapshot(self.overrides.refresh)
        self.ports = LinkPorts(self.transport, self.clock, self.announcements, self.commands, self.modes,
                               self.parameters, self.overrides, self.telemetry, self.ground)
        self._strategy: AutopilotStrategy | None = None  # the profile's strategy, set by setup()
        self.override_timeout_s = 3.0
        self._stream_rates: dict[int, float] = {}
        self.transport.on_reconnect(lambda: handshake.request_streams(self.ports, self._stream_rates))

    @classmethod
    def connect(cls, endpoint: str, *, profile: str | None = None, component: int = 191,
                signing_key: bytes | None = None, heartbeat_timeout_s: float = 10.0,
                system_id_hint: int = 1, stream_rates: dict[int, float] | None = None,
                water_density: float = 1000.0, timeouts: LinkTimeouts = LinkTimeouts(),
                lockstep: bool = False, vehicle: dict | None = None) -> "VehicleLink":
        """Connect to the autopilot at ``endpoint`` (any pymavlink connection string): wait (wall clock)
        for its HEARTBEAT, beaconing ours from ``system_id_hint``, take its system id, then run the
        handshake (``stream_rates``: message id → Hz, ``{}`` asks for none). Raises HeartbeatTimeout,
        ProfileError, ParamTimeout or EndpointError."""
        master = open_connection(endpoint, system_id=system_id_hint, component=component, dialect=CONNECT_DIALECT,
                                 signing_key=signing_key)
        try:
            heartbeat = await_autopilot_heartbeat(master, heartbeat_timeout_s, endpoint, signed=signing_key is not None)
            link = cls(master, system_id=heartbeat.get_srcSystem(), autopilot_component=heartbeat.get_srcComponent(),
                       component=component, timeouts=timeouts, lockstep=lockstep, endpoint=endpoint,
                       signing_key=signing_key)
            master.mav.srcSystem, master.mav.srcComponent = link.transport.system_id, component
            link.announcements.take_heartbeat(heartbeat)
            link.setup(profile, stream_rates, DepthSensor(water_density=water_density), vehicle or {})
        except BaseException:
            master.close()
            raise
        return link

    def setup(self, profile: str | None, stream_rates: dict[int, float] | None, depth_sensor: DepthSensor,
              vehicle: dict | None = None) -> None:
        """The handshake (``companion.link.handshake.setup``) on this link."""
        done = handshake.setup(self.ports, profile, stream_rates, depth_sensor, vehicle)
        self._strategy, self._stream_rates, self.override_timeout_s = done.strategy, done.stream_rates, done.override_timeout_s

    @property
    def autopilot(self) -> AutopilotStrategy:
        """The autopilot's strategy (``companion.link.autopilots``), known once :meth:`setup` ran."""
        return known_once_set_up(self._strategy, "autopilot strategy")

    # ------------------------------------------------------------------ the runner's protocol
    def next_telemetry(self, timeout_s: float = 5.0) -> Telemetry:
        """The next telemetry snapshot, in order (``TelemetryFeed``); set-point answers are checked
        first (CommandFailed) and queued ground-station commands handed to their callback after.
        LinkLost after ``timeout_s`` of wall clock without one; VehicleRebooted."""
        self.telemetry.wait(timeout_s)
        self.commands.check_answers()
        snapshot = self.telemetry.pop()
        self.ground.deliver()
        return snapshot

    def execute(self, commands: Sequence[Command]) -> None:
        """Carry out behaviour commands in order (``companion.link.dispatch``). Set-points are sent
        without waiting (a refusal or a missing acknowledgement makes the next
        :meth:`next_telemetry` raise); SetMode and SetParameters block until verified."""
        dispatch.execute(self.autopilot, self.ports, commands)

    def get_params(self, neutral_names: Iterable[str]) -> dict[str, float]:
        return self.parameters.get_params(neutral_names)

    def set_params(self, neutral_values: dict[str, float]) -> dict[str, float]:
        return self.parameters.set_params(neutral_values)

    def get_param(self, name: str, *, retries: int = 3) -> float:
        return self.parameters.get_param(name, retries=retries)

    def set_param(self, name: str, value: float, *, retries: int = 3) -> float:
        return self.parameters.set_param(name, value, retries=retries)

    def set_mode(self, neutral: str) -> None:
        self.modes.set_mode(neutral)

    def arm(self, armed: bool = True) -> None:
        self.modes.arm(armed)

    def release(self, actuator: str | None = None) -> None:
        """Give ``actuator`` (None = every overridden one) back to the autopilot, bypassing the strategy."""
        self.overrides.release(actuator)

    def status_text(self, text: str, severity: int = 6) -> None:
        self.ground.status_text(text, severity)

    def await_setpoints(self) -> None:
        self.commands.await_setpoints()

    def skip_to_now(self) -> int:
        return self.telemetry.skip_to_now()

    def other_companion(self) -> str | None:
        return self.ground.other_companion()

    def reconnect(self, timeout_s: float | None = None) -> bool:
        """Open a closed TCP link again (``Transport.reconnect``), bounded by ``timeouts.reconnect_s``."""
        return self.transport.reconnect(self.timeouts.reconnect_s if timeout_s is None else timeout_s)

    # ------------------------------------------------------------------ state
    @property
    def profile(self) -> AutopilotProfile:
        return known_once_set_up(self.ports.profile, "autopilot profile")

    @property
    def vehicle_time_s(self) -> float:
        return self.clock.vehicle_time_s

    @property
    def latest_telemetry(self) -> Telemetry | None:
        return self.telemetry.latest

    @property
    def mode(self) -> str:
        return self.announcements.mode

    @property
    def armed(self) -> bool:
        return self.announcements.armed

    @property
    def commanded_mode(self) -> str | None:
        return self.modes.commanded

    @commanded_mode.setter
    def commanded_mode(self, value: str | None) -> None:
        self.modes.commanded = value

    @property
    def statustexts(self):
        return self.announcements.statustexts

    def close(self) -> None:
        """Release every override we hold, then close the connection."""
        try:
            if self.overrides.active and self.overrides.send is not None:
                self.overrides.release(None)
        finally:
            self.transport.close()

    def __enter__(self) -> "VehicleLink":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
