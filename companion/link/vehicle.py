"""The companion's MAVLink vehicle interface (SPEC C1, SPEC §4, docs/PROTOCOL.md).

:class:`VehicleLink` connects to an autopilot, turns its telemetry into
:class:`companion.interface.Telemetry` snapshots and executes :class:`companion.interface.Command`
objects. All timing is on the **vehicle clock** (``time_boot_ms``): heartbeats, override refresh
and parameter/command timeouts; the wall clock is used only as a guard against a silent link
(``LinkLost``, ``HeartbeatTimeout`` and per-try wall guards).

One receive path (:meth:`VehicleLink._pump`: ``recv_match`` over all types, then a dispatch dict)
serves every blocking call, so telemetry, acks, parameters and incoming user commands are
processed — and active overrides refreshed — whatever the caller is waiting for.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

from pymavlink.dialects.v20.common import (MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_FAILED,
                                           MAV_RESULT_IN_PROGRESS, MAV_RESULT_UNSUPPORTED)

from companion.interface import (Command, NamedValue, OverrideActuator, ReleaseActuator, SetDepth, SetHeading,
                                 SetMode, SetParameters, SetRollingMass, SetThrust, StatusText, Telemetry)
from companion.link import params as paramcodec
from companion.link.errors import (CommandFailed, EndpointError, HeartbeatTimeout, LinkLost, ModeChangeFailed, ParamRefused,
                                   ParamTimeout, ProfileError, VehicleRebooted)
from companion.link.overrides import OverrideTable, single_shot
from companion.link.autopilots import strategy_for
from companion.link.profiles import AutopilotProfile, detect_profile, get_profile, marker_params
from companion.link.snapshot import SAFETY_ARMED, DepthSensor, TelemetryAssembler

log = logging.getLogger(__name__)

# MAVLink constants used here (numbers from the common dialect, kept local so this module does not
# depend on which dialect module pymavlink has loaded globally)
MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_SET_SERVO = 183
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_USER_1, MAV_CMD_USER_5 = 31010, 31014
MAV_SEVERITY_WARNING = 4
MSG_ID_AUTOPILOT_VERSION = 148

STATUSTEXT_CHUNK = 50
SNAPSHOT_QUEUE_MAX = 2000
NAMED_VALUE_MAX = 10


@dataclass(frozen=True)
class LinkTimeouts:
    """Timeouts of the blocking calls: vehicle seconds per try, with wall-clock guards."""

    param_try_s: float = 1.0  # vehicle time per PARAM_SET / PARAM_REQUEST_READ try
    mode_s: float = 3.0  # vehicle time for the heartbeat to show a mode / armed state
    command_s: float = 1.0  # vehicle time per COMMAND_LONG try awaiting its ACK
    wall_guard_s: float = 3.0  # wall-clock guard of one try when the vehicle clock stops
    # A try also lasts at least this much wall clock: the round trip of a request is a property of
    # the link and of how far the companion lags behind the stream, not of the vehicle clock. At 1x
    # the vehicle-time budget dominates; at 50x a companion a few tens of ms behind would otherwise
    # time out (and then read the late echo as a refusal of its next write).
    min_try_wall_s: float = 0.5
    heartbeat_period_s: float = 1.0  # our HEARTBEAT, vehicle time
    # lockstep: wall seconds with nothing received while waiting before acknowledging again (a lost
    # acknowledgement or sample would otherwise stall vehicle time for good; a lossless link never
    # goes that long without a frame)
    lockstep_stall_s: float = 1.0
    reconnect_s: float = 10.0  # wall seconds a restore waits for a closed TCP link to come back


@dataclass(frozen=True)
class UserCommand:
    """A COMMAND_LONG MAV_CMD_USER_1..5 aimed at the companion, queued for the callback."""

    command: int
    params: tuple[float, ...]
    source_system: int
    source_component: int


class VehicleLink:
    """MAVLink interface to one autopilot. Build it with :meth:`connect`."""

    def __init__(self, master: Any, *, system_id: int, autopilot_component: int, component: int,
                 timeouts: LinkTimeouts = LinkTimeouts()) -> None:
        self.master = master
        # lockstep with a simulator started with --lockstep (docs/PROTOCOL.md): acknowledge every
        # processed sample with SYSTEM_TIME so the simulator never runs ahead of the companion
        self.lockstep = False
        self._returned_ms: int | None = None
        self._acked_ms = -1
        self._nudged_ms: int | None = None  # the last acknowledgement re-sent after a stall
        self._last_nudge_wall = -math.inf
        self._attitude_period_ms = 50  # between the latest two samples (a stalled lockstep steps one)
        self.system_id = system_id
        self.autopilot_component = autopilot_component
        self.component = component
        self.timeouts = timeouts
        self.profile: AutopilotProfile | None = None
        self.assembler: TelemetryAssembler | None = None
        self.vehicle_time_s: float = math.nan
        self.gcs_sysid: int = 255
        self.override_timeout_s: float = 3.0
        self.int_encoding: paramcodec.IntEncoding = "cast"
        self.capabilities: int | None = None
        self.custom_mode: int | None = None
        self.base_mode: int = 0
        self.param_cache: dict[str, float] = {}
        self.param_types: dict[str, int] = {}
        self.statustexts: collections.deque[tuple[float, int, str]] = collections.deque(maxlen=64)
        self.rejected_commands: collections.deque[tuple[float, int, int]] = collections.deque(maxlen=64)
        self._other_companion: tuple[int, int, float] | None = None  # (system, component, vehicle time)
        self.overrides = OverrideTable()
        self.autopilot = None  # the profile's strategy (companion.link.autopilots), set at connect
        self.commanded_mode: str | None = None  # the last mode the companion itself switched to
        self._awaiting_ack: dict[int, float] = {}  # set-point command -> vehicle time it was sent
        # set-point command -> (its latest parameters, vehicle time last sent, times sent): an
        # unanswered set-point is sent again every command period (a frame lost on the link)
        self._setpoint_sends: dict[int, tuple[tuple[float, ...], float, int]] = {}
        self._refusals: collections.deque[str] = collections.deque(maxlen=16)
        self._gcs_heartbeat_component = 190
        self._endpoint: str | None = None
        self._signing_key: bytes | None = None
        self._stream_rates: dict[int, float] = {}
        self.reconnects = 0  # connections opened again after the vehicle closed or reset one
        self.allowed_senders: set[int] = set()  # more system ids allowed to start procedures
        self._last_attitude_ms: float | None = None
        self._last_heartbeat_sent: float = -math.inf
        self._last_heartbeat_msg: Any = None
        self._last_rx_wall = time.monotonic()
        self._param_events: dict[str, int] = collections.defaultdict(int)
        self._statustext_count = 0
        self._acks: dict[int, tuple[int, int, int]] = {}  # command -> (result, progress, arrival counter)
        self._ack_count = 0
        self._heartbeat_count = 0
        # every snapshot is delivered, in order: a companion that falls behind (one pump draining
        # several ATTITUDEs) must not drop samples, or the estimator sees holes in its data
        # bounded (SNAPSHOT_QUEUE_MAX, ~100 s at 20 Hz) so a caller that never reads cannot grow it forever
        self._unread_snapshots: collections.deque[Telemetry] = collections.deque(maxlen=SNAPSHOT_QUEUE_MAX)
        self.snapshots_dropped = 0
        # wall-clock decisions, counted so a run can say it was not exact: blocking waits ended by
        # their wall-clock guard (the vehicle clock stalled) and lockstep re-acknowledgements
        self.wall_timeouts = 0
        self._user_callback: Callable[[int, tuple[float, ...]], None] | None = None
        self._user_queue: collections.deque[UserCommand] = collections.deque()
        self.last_user_command: UserCommand | None = None
        self._statustext_id = 0
        self._handlers: dict[str, Callable[[Any], None]] = {
            "ATTITUDE": self._on_attitude,
            "SERVO_OUTPUT_RAW": self._on_telemetry,
            "LOCAL_POSITION_NED": self._on_telemetry,
            "VFR_HUD": self._on_telemetry,
            "SCALED_PRESSURE": self._on_telemetry,
            "GLOBAL_POSITION_INT": self._on_telemetry,
            "HEARTBEAT": self._on_heartbeat,
            "SYSTEM_TIME": self._on_system_time,
            "PARAM_VALUE": self._on_param_value,
            "COMMAND_ACK": self._on_command_ack,
            "COMMAND_LONG": self._on_command_long,
            "STATUSTEXT": self._on_statustext,
            "AUTOPILOT_VERSION": self._on_autopilot_version,
        }

    # ================================================================== connection
    @classmethod
    def connect(cls, endpoint: str, *, profile: str | None = None, component: int = 191,
                signing_key: bytes | None = None, heartbeat_timeout_s: float = 10.0,
                system_id_hint: int = 1, stream_rates: dict[int, float] | None = None,
                water_density: float = 1000.0, timeouts: LinkTimeouts = LinkTimeouts(),
                lockstep: bool = False, vehicle: dict | None = None) -> "VehicleLink":
        """Connect to the autopilot at ``endpoint`` (any pymavlink connection string).

        Waits (wall clock, ``heartbeat_timeout_s``) for an autopilot HEARTBEAT, beaconing our own
        HEARTBEAT meanwhile (from ``system_id_hint``, so a ``udpout:`` peer learns our address);
        then takes the vehicle's system id, requests the telemetry streams (``stream_rates``:
        message id → Hz, ``{}`` requests none), detects the profile from marker parameters (or
        uses ``profile``), reads the GCS system id and override timeout, and the integer encoding
        from AUTOPILOT_VERSION. Raises HeartbeatTimeout, ProfileError or ParamTimeout.
        """
        from pymavlink import mavutil

        # MAVLink 2 is needed for signing and the servo9+ extension fields; pymavlink chooses the
        # wire version through this process-wide variable, so set it before loading the dialect.
        os.environ.setdefault("MAVLINK20", "1")
        mavutil.set_dialect("ardupilotmega")
        try:
            master = mavutil.mavlink_connection(endpoint, source_system=system_id_hint, source_component=component,
                                                robust_parsing=True)
        except OSError as exc:  # refused TCP connection, missing serial device (SerialException), bad address
            raise EndpointError(f"cannot open {endpoint}: {exc}") from exc
        if signing_key is not None:
            master.setup_signing(signing_key, sign_outgoing=True)
        _raise_on_stream_end(master, endpoint)
        try:
            try:
                heartbeat = cls._await_autopilot_heartbeat(master, heartbeat_timeout_s, endpoint, component)
            except HeartbeatTimeout as exc:
                if signing_key is not None:  # a signed link drops every unsigned frame
                    raise HeartbeatTimeout(f"{exc}; with a signing key only frames signed with the same key are "
                                           "accepted: is the vehicle signing, with this key?") from exc
                raise
            link = cls(master, system_id=heartbeat.get_srcSystem(), autopilot_component=heartbeat.get_srcComponent(),
                       component=component, timeouts=timeouts)
            link.lockstep = lockstep
            link._endpoint, link._signing_key = endpoint, signing_key  # to reconnect (a restore after EOF)
            master.mav.srcSystem = link.system_id
            master.mav.srcComponent = component
            link._on_heartbeat(heartbeat)
            link._setup(profile, stream_rates, DepthSensor(water_density=water_density), vehicle or {})
        except BaseException:
            master.close()
            raise
        return link

    @staticmethod
    def _await_autopilot_heartbeat(master: Any, timeout_s: float, endpoint: str, component: int) -> Any:
        deadline = time.monotonic() + timeout_s
        next_beacon = 0.0
        while True:
            now = time.monotonic()
            if now >= deadline:
                raise HeartbeatTimeout(f"no autopilot HEARTBEAT on {endpoint} within {timeout_s:g} s (wall clock)")
            if now >= next_beacon:
                master.mav.heartbeat_send(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE)
                next_beacon = now + 1.0
            msg = master.recv_match(type="HEARTBEAT", blocking=True, timeout=min(0.25, deadline - now))
            if msg is not None and msg.autopilot != MAV_AUTOPILOT_INVALID and msg.type not in (
                    MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER):
                return msg

    def _setup(self, profile: str | None, stream_rates: dict[int, float] | None, depth_sensor: DepthSensor,
               vehicle: dict | None = None) -> None:
        self.send_heartbeat()
        self._command_long(MAV_CMD_REQUEST_MESSAGE, (MSG_ID_AUTOPILOT_VERSION,))
        chosen = get_profile(profile) if profile is not None else self._detect_profile()
        if vehicle:  # properties of this vehicle (rudder full scale, servo rate) over the profile's defaults
            chosen = dataclasses.replace(chosen, **vehicle)
        self.profile = chosen
        self.autopilot = strategy_for(self, chosen)
        self._stream_rates = dict(self.autopilot.streams if stream_rates is None else stream_rates)
        self._request_streams()
        self.int_encoding = chosen.int_encoding
        self.assembler = TelemetryAssembler(chosen, depth_sensor=depth_sensor)
        if self._last_heartbeat_msg is not None:
            self.assembler.on_message(self._last_heartbeat_msg)
        self.gcs_sysid = int(self._read_first(chosen.native_candidates("gcs_sysid"), default=255.0))
        if "override_timeout" in chosen.params:
            self.override_timeout_s = self._read_first(chosen.native_candidates("override_timeout"), default=3.0)
        if self.capabilities is None:  # AUTOPILOT_VERSION may already have arrived while reading
            self._wait_until(lambda: self.capabilities is not None, self.timeouts.command_s)
        if self.capabilities is not None:
            self.int_encoding = paramcodec.encoding_from_capabilities(self.capabilities, chosen.int_encoding)
        log.info("connected: system %d, profile %s, GCS sysid %d, override timeout %.1f s, int encoding %s",
                 self.system_id, chosen.name, self.gcs_sysid, self.override_timeout_s, self.int_encoding)

    def _request_streams(self) -> None:
        for message_id, rate_hz in self._stream_rates.items():
            self._command_long(MAV_CMD_SET_MESSAGE_INTERVAL, (message_id, 1e6 / rate_hz if rate_hz > 0 else -1))

    def reconnect(self, timeout_s: float | None = None) -> bool:
        """Open the TCP connection again after the vehicle closed or reset it (issue 9, fault
        injection: a link that dropped for a moment left every gain and set-point unrestored,
        because the restore gave up at the first EOF). Tries for ``timeout_s`` of wall clock
        (default ``timeouts.reconnect_s``) until the autopilot's HEARTBEAT arrives on a new
        connection; then asks for the streams again (and, in lockstep, acknowledges where it was).
        Everything else the link knows (profile, parameters, overrides held) is kept. False when the
        vehicle did not come back, or for a link that is not a TCP connection (nothing to open)."""
        from pymavlink import mavutil

        if self._endpoint is None or not hasattr(self.master, "destination_addr"):
            return False
        deadline = time.monotonic() + (self.timeouts.reconnect_s if timeout_s is None else timeout_s)
        try:
            self.master.close()
        except OSError:
            pass
        while time.monotonic() < deadline:
            try:  # retries=0: one attempt, never pymavlink's print-and-sleep loop
                master = mavutil.mavlink_connection(self._endpoint, source_system=self.system_id,
                                                    source_component=self.component, robust_parsing=True, retries=0)
            except OSError:
                time.sleep(0.2)
                continue
            if self._signing_key is not None:
                master.setup_signing(self._signing_key, sign_outgoing=True)
            _raise_on_stream_end(master, self._endpoint)
            try:
                heartbeat = self._await_autopilot_heartbeat(master, max(deadline - time.monotonic(), 0.1),
                                                            self._endpoint, self.component)
            except (HeartbeatTimeout, LinkLost):
                master.close()
                continue
            self.master = master
            self.reconnects += 1
            self._last_rx_wall = time.monotonic()
            self._on_heartbeat(heartbeat)
            self._request_streams()
            if self.lockstep and self._acked_ms >= 0:  # a lockstep simulator waits for its new companion
                self.master.mav.system_time_send(0, self._acked_ms & 0xFFFFFFFF)
            log.warning("reconnected to %s", self._endpoint)
            return True
        log.error("%s did not come back within %.0f s", self._endpoint, self.timeouts.reconnect_s)
        return False

    def _detect_profile(self) -> AutopilotProfile:
        """Probe each profile's marker parameter with PARAM_REQUEST_READ; the one that answers wins
        (cheaper than a full PARAM_REQUEST_LIST of ~1000 ArduPilot parameters over a radio)."""
        markers = marker_params()
        for _attempt in range(3):
            for name in markers:
                self._request_param(name)
            self._wait_until(lambda: any(n in self.param_cache for n in markers), self.timeouts.param_try_s)
            found = {n for n in markers if n in self.param_cache}
            if found:
                return detect_profile(found)
        raise ProfileError(f"no answer to the profile marker parameters {markers}; pass profile= explicitly")

    def _read_first(self, names: Iterable[str], default: float) -> float:
        for name in names:
            try:
                return self.get_param(name, retries=2)
            except ParamTimeout:
                continue
        log.warning("none of %s answered; assuming %g", list(names), default)
        return default

    def close(self) -> None:
        """Release every override we hold, then close the connection."""
        try:
            if self.overrides.active:
                self.overrides.release_all()
                self._send_overrides()
        finally:
            self.master.close()

    def __enter__(self) -> "VehicleLink":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ================================================================== receive path
    def _pump(self, wall_timeout_s: float) -> Any:
        """Receive and dispatch one message (None when nothing arrived within the wall timeout)."""
        msg = self.master.recv_match(blocking=True, timeout=max(wall_timeout_s, 0.0))
        if msg is None:
            return None
        self._last_rx_wall = time.monotonic()
        handler = self._handlers.get(msg.get_type())
        if handler is not None:
            handler(msg)
        return msg

    def _wait_until(self, done: Callable[[], bool], vehicle_timeout_s: float, wall_guard_s: float | None = None) -> bool:
        """Pump until ``done()``; False after ``vehicle_timeout_s`` of vehicle time or the wall guard."""
        start_vehicle = self.vehicle_time_s
        wall_start = time.monotonic()
        wall_deadline = wall_start + (self.timeouts.wall_guard_s if wall_guard_s is None else wall_guard_s)
        while not done():
            # in lockstep the companion never lags the stream (the simulator waits for it), so the
            # wall-clock minimum would only let the vehicle run on for a machine-dependent time (issue 12)
            if (math.isfinite(start_vehicle) and self.vehicle_time_s - start_vehicle >= vehicle_timeout_s
                    and (self.lockstep or time.monotonic() - wall_start >= self.timeouts.min_try_wall_s)):
                return False
            if not math.isfinite(start_vehicle) and math.isfinite(self.vehicle_time_s):
                start_vehicle = self.vehicle_time_s  # vehicle clock appeared while waiting
            remaining = wall_deadline - time.monotonic()
            if remaining <= 0.0:
                self.wall_timeouts += 1  # a wall-clock decision: counted, so a run can say it was not exact
                return False
            self._pump(min(remaining, 0.1))
            if self.lockstep:
                # blocked on an answer: let the simulator run on (a real vehicle would); 0 before any
                # sample starts a simulator that waits at t = 0 for its companion
                self._acknowledge(int(self._last_attitude_ms) if self._last_attitude_ms is not None else 0)
                self._unstall_lockstep()
        return True

    def _acknowledge(self, time_ms: int) -> None:
        """SYSTEM_TIME(time_boot_ms) to a --lockstep simulator: samples up to here are processed."""
        if time_ms > self._acked_ms:
            self._acked_ms = time_ms
            self.master.mav.system_time_send(0, time_ms & 0xFFFFFFFF)

    def _unstall_lockstep(self) -> None:
        """Lockstep over a link that loses frames (issue 9, fault injection): a lost acknowledgement
        leaves the simulator waiting at its limit, and a lost sample leaves the companion waiting
        for one the simulator will not send before the next acknowledgement; vehicle time would
        stop for good (the procedure then died of link loss and its restore could not confirm
        the mode: no heartbeat comes from a stopped vehicle). After ``timeouts.lockstep_stall_s`` of
        wall clock with nothing received the last acknowledgement is sent again (a lost one is
        replaced), and if that was already done, one sample period further (a lost sample is
        skipped). A wall-clock decision, so it is counted in ``wall_timeouts``; a lossless link
        never stalls that long."""
        now = time.monotonic()
        if now - max(self._last_rx_wall, self._last_nudge_wall) < self.timeouts.lockstep_stall_s:
            return
        base = max(self._acked_ms, 0)
        target = base + self._attitude_period_ms if self._nudged_ms == base else base
        self._acked_ms = self._nudged_ms = target
        self._last_nudge_wall = now
        self.wall_timeouts += 1
        log.info("lockstep stalled %.1f s: acknowledging t=%d ms again", now - self._last_rx_wall, target)
        self.master.mav.system_time_send(0, target & 0xFFFFFFFF)

    def next_telemetry(self, timeout_s: float = 5.0) -> Telemetry:
        """The next telemetry snapshot, in order; blocks until an ATTITUDE completes one.

        Every snapshot is delivered (an estimator must not see holes): those completed while
        another call was blocking (connect, set_mode, set_params ...) are queued and returned
        first, so right after such a call the snapshots returned may predate it — use
        :meth:`skip_to_now` to drop that backlog. Everything else received meanwhile is processed;
        queued user commands are handed to the callback before returning. Raises LinkLost after
        ``timeout_s`` of wall clock without a snapshot, VehicleRebooted when time_boot_ms jumps back.
        """
        if self.lockstep:  # everything the last snapshot asked for is sent (0: start the waiting simulator)
            self._acknowledge(self._returned_ms if self._returned_ms is not None else 0)
        deadline = time.monotonic() + timeout_s
        while not self._unread_snapshots:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                silent = time.monotonic() - self._last_rx_wall
                raise LinkLost(f"no telemetry snapshot for {timeout_s:g} s of wall clock "
                               f"(last message of any kind {silent:.1f} s ago)")
            if self.lockstep:  # wake in time to notice a stall
                self._pump(min(remaining, 0.5, self.timeouts.lockstep_stall_s / 2.0))
                self._unstall_lockstep()
            else:
                self._pump(min(remaining, 0.5))
        self._check_setpoint_answers()
        snapshot = self._unread_snapshots.popleft()
        self._returned_ms = int(round(snapshot.time_s * 1000.0))
        self._deliver_user_commands()
        return snapshot

    def _check_setpoint_answers(self) -> None:
        """A set-point the vehicle refused, or left unanswered for 3 command periods of vehicle
        time, is a failure of the procedure that sent it (CommandFailed), never a warning. One
        unanswered for a command period is sent again first (issue 9, fault injection: a single
        lost command or acknowledgement aborted the procedure); set-points are absolute, so a
        vehicle that did get the first one is not moved by the second."""
        if self._refusals:
            reason = self._refusals.popleft()
            self._refusals.clear()
            raise CommandFailed(reason)
        overdue = [c for c, sent in self._awaiting_ack.items()
                   if self.vehicle_time_s - sent > 3.0 * self.timeouts.command_s]
        if overdue:
            self._awaiting_ack.clear()
            raise CommandFailed(f"the vehicle did not acknowledge command {overdue[0]}", command=overdue[0])
        self._resend_setpoints()

    def _resend_setpoints(self) -> None:
        """Send again every awaited set-point last sent a command period of vehicle time ago."""
        for command in list(self._awaiting_ack):
            params, last, sends = self._setpoint_sends.get(command, ((), -math.inf, 1))
            if params and self.vehicle_time_s - last >= self.timeouts.command_s:
                log.info("command %d unanswered for %.1f s: sent again", command, self.vehicle_time_s - last)
                self._command_long(command, params, confirmation=min(sends, 255))
                self._setpoint_sends[command] = (params, self.vehicle_time_s, sends + 1)

    def await_setpoints(self) -> None:
        """Wait (vehicle time, three command periods, sending unanswered ones again each period)
        until every set-point sent has been acknowledged; CommandFailed on a refusal or when one
        is still unanswered."""
        for _period in range(3):
            if self._wait_until(lambda: not self._awaiting_ack or bool(self._refusals), self.timeouts.command_s):
                break
            self._resend_setpoints()
        if self._refusals:
            reason = self._refusals.popleft()
            self._refusals.clear()
            self._awaiting_ack.clear()
            raise CommandFailed(reason)
        if self._awaiting_ack:
            unanswered = sorted(self._awaiting_ack)
            self._awaiting_ack.clear()
            raise CommandFailed(f"the vehicle did not acknowledge command {unanswered[0]}", command=unanswered[0])

    @property
    def pending_snapshots(self) -> int:
        """Snapshots received but not yet returned by :meth:`next_telemetry`."""
        return len(self._unread_snapshots)

    def skip_to_now(self) -> int:
        """Drop the queued snapshots (the next one returned is newer than anything seen so far);
        returns how many were dropped."""
        dropped = len(self._unread_snapshots)
        self._unread_snapshots.clear()
        return dropped

    @property
    def latest_telemetry(self) -> Telemetry | None:
        """The most recent snapshot (whether or not next_telemetry returned it)."""
        return self.assembler.latest if self.assembler else None

    # ------------------------------------------------------------------ handlers
    def _from_autopilot(self, msg: Any) -> bool:
        return msg.get_srcSystem() == self.system_id and msg.get_srcComponent() == self.autopilot_component

    def _on_attitude(self, msg: Any) -> None:
        if not self._from_autopilot(msg):
            return
        time_ms = getattr(msg, "time_boot_ms", None)
        if isinstance(time_ms, (int, float)) and self._last_attitude_ms is not None:
            if time_ms < self._last_attitude_ms - 1000:
                previous = self._last_attitude_ms
                self._last_attitude_ms = time_ms
                self.vehicle_time_s = time_ms / 1000.0
                raise VehicleRebooted(f"time_boot_ms went back from {previous} to {time_ms}: the vehicle rebooted")
            if time_ms <= self._last_attitude_ms:
                return  # duplicate or reordered sample
            self._attitude_period_ms = int(min(max(time_ms - self._last_attitude_ms, 1), 1000))
        if self.assembler is None:
            if isinstance(time_ms, (int, float)):
                self._advance_clock(time_ms)
            return
        snapshot = self.assembler.on_message(msg)
        if isinstance(time_ms, (int, float)) and math.isfinite(time_ms):
            self._last_attitude_ms = time_ms
            self._advance_clock(time_ms)
        if snapshot is not None:
            self._queue_snapshot(snapshot)

    def _queue_snapshot(self, snapshot: Telemetry) -> None:
        if self.autopilot is not None:
            snapshot = self.autopilot.on_snapshot(snapshot)
            self.assembler.latest = snapshot
        if len(self._unread_snapshots) == SNAPSHOT_QUEUE_MAX:
            self.snapshots_dropped += 1
            if self.snapshots_dropped == 1 or self.snapshots_dropped % 1000 == 0:
                log.warning("telemetry not read: %d old snapshots dropped", self.snapshots_dropped)
        self._unread_snapshots.append(snapshot)
        if self.overrides.pending:
            self._send_overrides()

    def _advance_clock(self, time_ms: float) -> None:
        time_s = time_ms / 1000.0
        if not math.isfinite(self.vehicle_time_s) or time_s > self.vehicle_time_s:
            self.vehicle_time_s = time_s
        if self.vehicle_time_s - self._last_heartbeat_sent >= self.timeouts.heartbeat_period_s:
            self.send_heartbeat()

    def _on_system_time(self, msg: Any) -> None:
        if self._from_autopilot(msg) and isinstance(msg.time_boot_ms, int):
            if self._last_attitude_ms is None or msg.time_boot_ms >= self._last_attitude_ms - 1000:
                self._advance_clock(msg.time_boot_ms)

    def _on_telemetry(self, msg: Any) -> None:
        if self.assembler is not None and msg.get_srcSystem() == self.system_id:
            snapshot = self.assembler.on_message(msg)  # ArduPilot: SERVO_OUTPUT_RAW completes a snapshot
            if snapshot is not None:
                self._queue_snapshot(snapshot)

    #: vehicle seconds a HEARTBEAT of another companion counts as "it is there"
    OTHER_COMPANION_S = 5.0

    def _on_heartbeat(self, msg: Any) -> None:
        if not self._from_autopilot(msg):
            self._note_other_companion(msg)
            return
        self.custom_mode = msg.custom_mode
        self.base_mode = msg.base_mode
        self._last_heartbeat_msg = msg
        self._heartbeat_count += 1
        if self.assembler is not None:
            self.assembler.on_message(msg)

    def _note_other_companion(self, msg: Any) -> None:
        """A HEARTBEAT from an onboard controller on our component id is another companion: a router
        never hands us our own messages back, and two companions on one vehicle share its system id
        (issue 9: two ``identify`` runs flew one vehicle at once and both wrote gains)."""
        if msg.get_srcComponent() == self.component and getattr(msg, "type", None) == MAV_TYPE_ONBOARD_CONTROLLER:
            self._other_companion = (msg.get_srcSystem(), msg.get_srcComponent(), self.vehicle_time_s)

    def other_companion(self) -> str | None:
        """Why no procedure may run now: another companion was heard within
        :data:`OTHER_COMPANION_S` of vehicle time (None: none was)."""
        seen = self._other_companion
        if seen is None:
            return None
        system, component, when = seen
        if math.isfinite(when) and math.isfinite(self.vehicle_time_s) and self.vehicle_time_s - when > self.OTHER_COMPANION_S:
            return None
        return (f"another companion (system {system}, component {component}) is on this vehicle's link: "
                "two would fly it at once")

    def _on_param_value(self, msg: Any) -> None:
        if msg.get_srcSystem() != self.system_id:
            return
        name = paramcodec.param_id_str(msg.param_id)
        self.param_types[name] = msg.param_type
        self.param_cache[name] = paramcodec.decode_value(msg.param_value, msg.param_type, self.int_encoding)
        self._param_events[name] += 1

    def _on_command_ack(self, msg: Any) -> None:
        if msg.get_srcSystem() != self.system_id:
            return
        target_system = getattr(msg, "target_system", 0)
        target_component = getattr(msg, "target_component", 0)
        if target_system not in (0, self.system_id) or target_component not in (0, self.component):
            return
        self._ack_count += 1
        self._acks[msg.command] = (msg.result, getattr(msg, "progress", 0) or 0, self._ack_count)
        awaited = self._awaiting_ack.pop(msg.command, None) is not None
        if msg.result not in (MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS):
            self.rejected_commands.append((self.vehicle_time_s, msg.command, msg.result))
            log.warning("vehicle answered command %d with result %d", msg.command, msg.result)
            if awaited:
                self._refusals.append(f"the vehicle refused command {msg.command} (MAV_RESULT {msg.result})")

    def _on_statustext(self, msg: Any) -> None:
        if msg.get_srcSystem() != self.system_id:
            return
        text = msg.text.decode("ascii", "replace") if isinstance(msg.text, bytes) else str(msg.text)
        text = text.split("\x00", 1)[0]
        self.statustexts.append((self.vehicle_time_s, msg.severity, text))
        self._statustext_count += 1
        log.debug("vehicle says [%d] %s", msg.severity, text)

    def _on_autopilot_version(self, msg: Any) -> None:
        if msg.get_srcSystem() == self.system_id:
            self.capabilities = int(msg.capabilities)

    def _on_command_long(self, msg: Any) -> None:
        if msg.target_system not in (0, self.system_id) or msg.target_component not in (0, self.component):
            return
        if MAV_CMD_USER_1 <= msg.command <= MAV_CMD_USER_5:
            sender = msg.get_srcSystem()
            if sender not in self.command_senders():
                # a procedure moves the vehicle: only the ground station (or an allowed system) starts one
                self._send_ack(msg.command, MAV_RESULT_DENIED, 0, sender, msg.get_srcComponent())
                self.status_text(f"command {msg.command} from system {sender} refused: not the ground station"[:50], 4)
                log.warning("COMMAND_LONG %d from system %d refused (ground station is %d, allowed %s)",
                            msg.command, sender, self.gcs_sysid, sorted(self.allowed_senders))
                return
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
            self._user_queue.append(UserCommand(msg.command, params, sender, msg.get_srcComponent()))
        elif msg.target_component == self.component:
            self._send_ack(msg.command, MAV_RESULT_UNSUPPORTED, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def command_senders(self) -> set[int]:
        """System ids whose procedure commands are obeyed: the ground station's and ``allowed_senders``."""
        return {self.gcs_sysid, *self.allowed_senders}

    # ================================================================== user commands
    def on_user_command(self, callback: Callable[[int, tuple[float, ...]], None] | None) -> None:
        """``callback(command_id, params)`` for COMMAND_LONG MAV_CMD_USER_1..5 aimed at our component
        (or broadcast); called from :meth:`next_telemetry`. Without a callback, such commands are
        answered UNSUPPORTED. ``last_user_command`` holds the sender for :meth:`send_command_ack`."""
        self._user_callback = callback

    def _deliver_user_commands(self) -> None:
        while self._user_queue:
            command = self._user_queue.popleft()
            self.last_user_command = command
            if self._user_callback is None:
                self._send_ack(command.command, MAV_RESULT_UNSUPPORTED, 0, command.source_system, command.source_component)
                continue
            try:
                self._user_callback(command.command, command.params)
            except Exception:  # a failing handler must not take the link down
                log.exception("user command %d handler failed", command.command)
                self._send_ack(command.command, MAV_RESULT_FAILED, 0, command.source_system, command.source_component)

    def send_command_ack(self, command: int, result: int, progress: int = 0, target_system: int = 0,
                         target_component: int = 0) -> None:
        """COMMAND_ACK (IN_PROGRESS with ``progress`` 0..100, ACCEPTED, FAILED ...). Target 0/0
        means the sender of the last user command with this id, or broadcast if none."""
        if target_system == 0 and target_component == 0 and self.last_user_command is not None \
                and self.last_user_command.command == command:
            target_system = self.last_user_command.source_system
            target_component = self.last_user_command.source_component
        self._send_ack(command, result, progress, target_system, target_component)

    def _send_ack(self, command: int, result: int, progress: int, target_system: int, target_component: int) -> None:
        self.master.mav.command_ack_send(command, result, progress, 0, target_system, target_component)

    # ================================================================== sending
    def send_heartbeat(self) -> None:
        """Our HEARTBEAT (onboard controller); sent automatically every vehicle second."""
        self.master.mav.heartbeat_send(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE)
        self._last_heartbeat_sent = self.vehicle_time_s if math.isfinite(self.vehicle_time_s) else -math.inf

    def _command_long(self, command: int, params: Sequence[float], *, confirmation: int = 0) -> int:
        """Send a COMMAND_LONG to the autopilot; returns the ack counter to wait from."""
        values = list(params) + [0.0] * (7 - len(params))
        self.master.mav.command_long_send(self.system_id, self.autopilot_component, command, confirmation, *values)
        return self._ack_count

    def send_setpoint(self, command: int, params: Sequence[float]) -> None:
        """A set-point COMMAND_LONG whose ACK is awaited in the background (see next_telemetry)."""
        self._command_long(command, params)
        now = self.vehicle_time_s if math.isfinite(self.vehicle_time_s) else 0.0
        self._awaiting_ack.setdefault(command, now)
        self._setpoint_sends[command] = (tuple(params), now, 1)

    def send_attitude_target(self, quaternion: Sequence[float], thrust: float, *, ignore_thrust: bool = False) -> None:
        """SET_ATTITUDE_TARGET: attitude from the quaternion, body rates ignored (type_mask 7, +64
        to ignore the thrust field)."""
        type_mask = 7 | (64 if ignore_thrust else 0)
        time_ms = int(self.vehicle_time_s * 1000) if math.isfinite(self.vehicle_time_s) else 0
        self.master.mav.set_attitude_target_send(time_ms & 0xFFFFFFFF, self.system_id, self.autopilot_component,
                                                 type_mask, [float(q) for q in quaternion], 0.0, 0.0, 0.0,
                                                 float(thrust))

    def send_gcs_heartbeat(self) -> None:
        """A HEARTBEAT as the ground station (its system id, type GCS): what a GCS failsafe watches."""
        mav = self.master.mav
        own = (mav.srcSystem, mav.srcComponent)
        mav.srcSystem, mav.srcComponent = self.gcs_sysid, self._gcs_heartbeat_component
        try:
            mav.heartbeat_send(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE)
        finally:
            mav.srcSystem, mav.srcComponent = own

    def servo_pwm(self) -> list[float]:
        """The latest SERVO_OUTPUT_RAW, outputs 1..16 in µs (empty before the first one)."""
        return list(self.assembler.servo_pwm) if self.assembler is not None else []

    def command(self, command: int, params: Sequence[float], *, retries: int = 2) -> int:
        """Send a COMMAND_LONG and wait (vehicle time) for its ACK; returns the MAV_RESULT.
        Raises CommandFailed when no ACK arrives after all tries."""
        for attempt in range(retries + 1):
            since = self._command_long(command, params, confirmation=attempt)
            if self._wait_until(lambda: self._acks.get(command, (0, 0, -1))[2] > since, self.timeouts.command_s):
                return self._acks[command][0]
        raise CommandFailed(f"no COMMAND_ACK for command {command}", command=command)

    def _send_overrides(self) -> None:
        values = self.overrides.channel_values()
        self._send_rc_override(values)

    def _send_rc_override(self, values: list[int]) -> None:
        """RC_CHANNELS_OVERRIDE from the vehicle's GCS system id (ArduPilot accepts it only from
        there, PROTOCOL.md), then back to our own identity."""
        mav = self.master.mav
        own_system = mav.srcSystem
        mav.srcSystem = self.gcs_sysid
        try:
            mav.rc_channels_override_send(self.system_id, self.autopilot_component, *values)
        finally:
            mav.srcSystem = own_system

    # ================================================================== commands
    def execute(self, commands: Sequence[Command]) -> None:
        """Carry out behaviour commands in order, through the autopilot's strategy
        (``companion.link.autopilots``). Set-points are sent without waiting; a refusal or a
        missing acknowledgement makes the next :meth:`next_telemetry` raise. SetMode and
        SetParameters block until verified and raise on failure."""
        for command in commands:
            if isinstance(command, OverrideActuator):
                self.autopilot.override(command.actuator, command.value)
            elif isinstance(command, ReleaseActuator):
                self.autopilot.release(command.actuator)
            elif isinstance(command, SetHeading):
                self.autopilot.set_heading(command.heading)
            elif isinstance(command, SetDepth):
                self.autopilot.set_depth(command.depth)
            elif isinstance(command, SetThrust):
                self.autopilot.set_thrust(command.thrust_ratio)
            elif isinstance(command, SetRollingMass):
                if self._profile().mass_servo is None:
                    raise ProfileError(f"profile {self._profile().name!r} has no rolling-mass servo")
                self.set_servo(self._profile().mass_servo, self._profile().angle_to_pwm(command.angle))
            elif isinstance(command, SetMode):
                self.set_mode(command.mode)
            elif isinstance(command, SetParameters):
                self.set_params(command.values)
            elif isinstance(command, StatusText):
                self.status_text(command.text, command.severity)
            elif isinstance(command, NamedValue):
                self.named_value(command.name, command.value)
            else:
                raise TypeError(f"unknown command {command!r}")

    def _profile(self) -> AutopilotProfile:
        if self.profile is None:
            raise ProfileError("no profile yet (still connecting)")
        return self.profile

    @property
    def mode(self) -> str:
        """Neutral name of the mode in the latest autopilot HEARTBEAT."""
        if self.custom_mode is None:
            return ""
        return self._profile().mode_name(self.custom_mode)

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & SAFETY_ARMED)

    def set_mode(self, neutral: str) -> None:
        """Switch mode and wait until the HEARTBEAT shows it (vehicle time, resending each try)."""
        target = self._profile().mode_number(neutral)
        tries = max(int(math.ceil(self.timeouts.mode_s / self.timeouts.command_s)), 1)
        for _attempt in range(tries):
            since_hb = self._heartbeat_count
            since_ack = self._command_long(MAV_CMD_DO_SET_MODE, (MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, target))

            def settled() -> bool:
                ack = self._acks.get(MAV_CMD_DO_SET_MODE)
                refused = ack is not None and ack[2] > since_ack and ack[0] not in (MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS)
                return refused or (self._heartbeat_count > since_hb and self.custom_mode == target)

            self._wait_until(settled, self.timeouts.command_s)
            ack = self._acks.get(MAV_CMD_DO_SET_MODE)
            if ack is not None and ack[2] > since_ack and ack[0] not in (MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS):
                raise ModeChangeFailed(f"vehicle refused mode {neutral!r} ({target}): result {ack[0]}")
            if self._heartbeat_count > since_hb and self.custom_mode == target:
                self.commanded_mode = neutral
                if self.autopilot is not None:
                    self.autopilot.mode_changed(neutral)
                return
        raise ModeChangeFailed(f"heartbeat did not show mode {neutral!r} ({target}) within {self.timeouts.mode_s:g} s")

    def arm(self, armed: bool = True) -> None:
        """Arm or disarm; verified by the ACK and then the HEARTBEAT's armed flag."""
        result = self.command(MAV_CMD_COMPONENT_ARM_DISARM, (1.0 if armed else 0.0,))
        if result != MAV_RESULT_ACCEPTED:
            raise CommandFailed(f"{'arm' if armed else 'disarm'} refused: result {result}",
                                command=MAV_CMD_COMPONENT_ARM_DISARM, result=result)
        since_hb = self._heartbeat_count
        if not self._wait_until(lambda: self._heartbeat_count > since_hb and self.armed == armed, self.timeouts.mode_s):
            raise ModeChangeFailed(f"heartbeat did not show armed={armed}")

    # ------------------------------------------------------------------ actuators
    def override(self, actuator: str, value: float, *, keep_alive: bool = True) -> None:
        """Drive ``actuator`` ("rudder"/"elevator"/"thrust"; rad or ratio) through RC override.
        With ``keep_alive`` it is refreshed at every snapshot until :meth:`release`; without, it
        is sent once and expires on the vehicle after its override timeout."""
        profile = self._profile()
        channel = profile.channel(actuator)
        pwm = profile.actuator_to_pwm(actuator, value)
        if keep_alive:
            changed = self.overrides.active.get(channel) != pwm
            self.overrides.hold(channel, pwm)
            if changed:  # unchanged values go out with the per-snapshot refresh only
                self._send_overrides()
        else:
            self.overrides.active.pop(channel, None)
            self._send_rc_override(single_shot(channel, pwm))

    def override_raw(self, channel_name: str, pwm: int) -> None:
        """Hold a raw PWM on the profile's channel ``channel_name`` (kept alive like an override)."""
        channel = self._profile().channel(channel_name)
        changed = self.overrides.active.get(channel) != pwm
        self.overrides.hold(channel, int(pwm))
        if changed:
            self._send_overrides()

    def release(self, actuator: str | None = None) -> None:
        """Give ``actuator`` (None = every overridden one) back to the autopilot."""
        if actuator is None:
            self.overrides.release_all()
        else:
            self.overrides.release(self._profile().channel(actuator))
        if self.overrides.pending:
            self._send_overrides()

    def set_servo(self, output: int, pwm: int, *, wait: bool = False) -> None:
        """DO_SET_SERVO on a spare output. With ``wait``, raise CommandFailed unless ACCEPTED."""
        if not wait:
            self._command_long(MAV_CMD_DO_SET_SERVO, (float(output), float(pwm)))
            return
        result = self.command(MAV_CMD_DO_SET_SERVO, (float(output), float(pwm)))
        if result != MAV_RESULT_ACCEPTED:
            raise CommandFailed(f"DO_SET_SERVO output {output} refused: result {result}",
                                command=MAV_CMD_DO_SET_SERVO, result=result)

    # ------------------------------------------------------------------ ground station
    def status_text(self, text: str, severity: int = 6) -> None:
        """STATUSTEXT, split into 50-character chunks (MAVLink 2 id/chunk_seq for multi-chunk)."""
        encoded = text.encode("ascii", "replace")
        chunks = [encoded[i:i + STATUSTEXT_CHUNK] for i in range(0, len(encoded), STATUSTEXT_CHUNK)] or [b""]
        message_id = 0
        if len(chunks) > 1:
            self._statustext_id = self._statustext_id % 65535 + 1
            message_id = self._statustext_id
        for seq, chunk in enumerate(chunks):
            self.master.mav.statustext_send(severity, chunk, message_id, seq)

    def named_value(self, name: str, value: float) -> None:
        """NAMED_VALUE_FLOAT for live graphs; ``name`` must be 1..10 printable ASCII characters."""
        validate_named_value_name(name)
        time_ms = int(self.vehicle_time_s * 1000) & 0xFFFFFFFF if math.isfinite(self.vehicle_time_s) else 0
        self.master.mav.named_value_float_send(time_ms, name.encode("ascii"), float(value))

    # ================================================================== parameters
    def _request_param(self, name: str) -> None:
        self.master.mav.param_request_read_send(self.system_id, self.autopilot_component, name.encode("ascii"), -1)

    def get_param(self, name: str, *, retries: int = 3) -> float:
        """Read one parameter by its autopilot name (PARAM_REQUEST_READ, retried); ParamTimeout."""
        paramcodec.validate_param_name(name)
        for _attempt in range(retries):
            since = self._param_events[name]
            self._request_param(name)
            if self._wait_until(lambda: self._param_events[name] > since, self.timeouts.param_try_s):
                return self.param_cache[name]
        raise ParamTimeout(f"no PARAM_VALUE for {name} after {retries} tries", name=name)

    def set_param(self, name: str, value: float, *, retries: int = 3) -> float:
        """Write one parameter by its autopilot name and return the echoed value.

        Trusted only when a PARAM_VALUE echo carries the same name and the float32-rounded value
        (integers: the same integer, through the vehicle's int encoding). ParamRefused when the
        echo carries another value, when the vehicle sends a STATUSTEXT warning naming the
        parameter, or for a non-finite value (refused locally, never sent); ParamTimeout when
        nothing answers after ``retries`` tries of ``param_try_s`` vehicle seconds each.
        """
        paramcodec.validate_param_name(name)
        if not math.isfinite(value):
            raise ParamRefused(f"{name}: non-finite value {value!r} refused locally (not sent)", name=name, value=value)
        if name not in self.param_types and self.int_encoding == "bytewise":
            self.get_param(name, retries=retries)  # the type decides the bytes we send
        param_type = self.param_types.get(name, paramcodec.REAL32)
        wire_value = paramcodec.encode_value(value, param_type, self.int_encoding)
        for _attempt in range(retries):
            since_param = self._param_events[name]
            since_text = self._statustext_count
            self.master.mav.param_set_send(self.system_id, self.autopilot_component, name.encode("ascii"),
                                           wire_value, param_type)
            state = {"mismatch": None, "refusal": None}

            def answered() -> bool:
                if self._param_events[name] > since_param:
                    echoed = self.param_cache[name]
                    if paramcodec.echo_matches(value, echoed, self.param_types.get(name, param_type)):
                        return True
                    state["mismatch"] = echoed
                state["refusal"] = self._refusal_text(name, self._statustext_count - since_text)
                return state["refusal"] is not None

            if self._wait_until(answered, self.timeouts.param_try_s) and state["refusal"] is None:
                return self.param_cache[name]
            if state["refusal"] is not None:
                raise ParamRefused(f"{name}={value!r} refused by the vehicle: {state['refusal']!r}", name=name,
                                   value=value, echoed=state["mismatch"])
            if state["mismatch"] is not None:
                raise ParamRefused(f"{name}={value!r} refused: the vehicle echoed {state['mismatch']!r}", name=name,
                                   value=value, echoed=state["mismatch"])
        raise ParamTimeout(f"no echo for {name}={value!r} after {retries} tries", name=name, value=value)

    def _refusal_text(self, name: str, new_count: int) -> str | None:
        """The newest STATUSTEXT warning (or worse) among the last ``new_count`` that names ``name``."""
        if new_count <= 0:
            return None
        recent = list(self.statustexts)[-min(new_count, len(self.statustexts)):]
        for _time, severity, text in reversed(recent):
            if severity <= MAV_SEVERITY_WARNING and name in text:
                return text
        return None

    def get_params(self, neutral_names: Iterable[str]) -> dict[str, float]:
        """Read parameters by neutral name (profile mapping and unit conversion applied)."""
        profile = self._profile()
        return {neutral: profile.to_neutral_value(neutral, self._read_neutral(neutral)) for neutral in neutral_names}

    def _read_neutral(self, neutral: str) -> float:
        candidates = self._profile().native_candidates(neutral)
        for native in candidates[:-1]:
            try:
                return self.get_param(native, retries=1)
            except ParamTimeout:
                continue
        return self.get_param(candidates[-1])

    def set_params(self, neutral_values: dict[str, float]) -> dict[str, float]:
        """Write parameters by neutral name; returns neutral name → confirmed value. Writes stop at
        the first failure (ParamRefused / ParamTimeout propagate)."""
        profile = self._profile()
        confirmed: dict[str, float] = {}
        for neutral, value in neutral_values.items():
            native = profile.native_param(neutral)
            echoed = self.set_param(native, profile.to_native_value(neutral, value))
            confirmed[neutral] = profile.to_neutral_value(neutral, echoed)
        return confirmed


def _raise_on_stream_end(master: Any, endpoint: str) -> None:
    """A TCP peer that closed or reset the connection is link loss (LinkLost, which the runner's
    abort and the restore's bounded retries handle), not pymavlink's print-and-reconnect loop on
    stdout (it spun at 100 % CPU and spoiled ``--json`` output)."""
    def lost(what: str):
        def handler(*_args) -> None:
            raise LinkLost(f"{endpoint}: {what}")
        return handler

    if hasattr(master, "handle_eof"):
        master.handle_eof = lost("the vehicle closed the TCP connection")
    if hasattr(master, "handle_disconnect"):
        master.handle_disconnect = lost("the TCP connection was reset")


def validate_named_value_name(name: str) -> str:
    """NAMED_VALUE_FLOAT.name: 1..10 printable ASCII characters (ValueError otherwise)."""
    if not isinstance(name, str) or not 1 <= len(name) <= NAMED_VALUE_MAX or not name.isascii() \
            or not name.isprintable():
        raise ValueError(f"invalid NAMED_VALUE_FLOAT name {name!r} (1..{NAMED_VALUE_MAX} printable ASCII characters)")
    return name
