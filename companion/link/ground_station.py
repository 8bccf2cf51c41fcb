"""The companion as seen by the ground station: its heartbeat, its reports, the commands it obeys.

SPEC C1: a HEARTBEAT every vehicle second as an onboard controller (component 191); STATUSTEXT for
progress and warnings (split into 50-character chunks, MAVLink 2 id/chunk_seq); NAMED_VALUE_FLOAT
for live estimates; COMMAND_LONG ``MAV_CMD_USER_1..5`` aimed at the companion, queued and handed to
a callback from the telemetry loop, answered with COMMAND_ACK. A procedure moves the vehicle, so
only the ground station's system id (``gcs_sysid``) or an allowed one may start one. Another
companion heard on the link (an onboard controller on our component id) is reported: two must not
fly one vehicle at once. Listeners (:meth:`GroundStation.on_report`) see every report as it is
sent, e.g. the status page of ``companion run``.
"""
from __future__ import annotations

import collections
import logging
import math
from dataclasses import dataclass
from typing import Any, Callable

from companion.link.clock import VehicleClock
from companion.link.transport import (MAV_AUTOPILOT_INVALID, MAV_STATE_ACTIVE, MAV_TYPE_ONBOARD_CONTROLLER,
                                      Transport)

log = logging.getLogger(__name__)

MAV_CMD_USER_1, MAV_CMD_USER_5 = 31010, 31014
MAV_RESULT_DENIED, MAV_RESULT_UNSUPPORTED, MAV_RESULT_FAILED = 2, 3, 4
STATUSTEXT_CHUNK = 50
NAMED_VALUE_MAX = 10


@dataclass(frozen=True)
class Report:
    """One report sent to the ground station, as listeners see it: ``kind`` is ``"text"``
    (STATUSTEXT: ``text``, ``severity``), ``"value"`` (NAMED_VALUE_FLOAT: ``name``, ``value``) or
    ``"ack"`` (COMMAND_ACK: ``command``, ``result``, ``progress``); ``time_s`` is vehicle time."""

    kind: str
    time_s: float
    text: str = ""
    severity: int = 6
    name: str = ""
    value: float = 0.0
    command: int = 0
    result: int = 0
    progress: int = 0


@dataclass(frozen=True)
class UserCommand:
    """A COMMAND_LONG MAV_CMD_USER_1..5 aimed at the companion, queued for the callback."""

    command: int
    params: tuple[float, ...]
    source_system: int
    source_component: int


def validate_named_value_name(name: str) -> str:
    """NAMED_VALUE_FLOAT.name: 1..10 printable ASCII characters (ValueError otherwise)."""
    if not isinstance(name, str) or not 1 <= len(name) <= NAMED_VALUE_MAX or not name.isascii() \
            or not name.isprintable():
        raise ValueError(f"invalid NAMED_VALUE_FLOAT name {name!r} (1..{NAMED_VALUE_MAX} printable ASCII characters)")
    return name


class GroundStation:
    """Our heartbeat, status texts and live values, and the ground station's commands to us."""

    #: vehicle seconds a HEARTBEAT of another companion counts as "it is there"
    OTHER_COMPANION_S = 5.0

    def __init__(self, transport: Transport, clock: VehicleClock) -> None:
        self.transport = transport
        self.clock = clock
        self.gcs_sysid: int = 255  # the vehicle's ground station (read from its parameters at connect)
        self.allowed_senders: set[int] = set()  # more system ids allowed to start procedures
        self.last_user_command: UserCommand | None = None
        self._callback: Callable[[int, tuple[float, ...]], None] | None = None
        self._queue: collections.deque[UserCommand] = collections.deque()
        self._statustext_id = 0
        self._last_heartbeat_sent = -math.inf
        self._other_companion: tuple[int, int, float] | None = None  # (system, component, vehicle time)
        self._report_listeners: list[Callable[[Report], None]] = []
        transport.on("COMMAND_LONG", self._on_command_long)
        transport.on("HEARTBEAT", self._on_heartbeat)
        clock.on_tick(self._heartbeat_due)

    # ------------------------------------------------------------------ sending
    def send_heartbeat(self) -> None:
        """Our HEARTBEAT (onboard controller); sent automatically every vehicle second."""
        self.transport.mav.heartbeat_send(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE)
        now = self.clock.vehicle_time_s
        self._last_heartbeat_sent = now if math.isfinite(now) else -math.inf

    def _heartbeat_due(self, now_s: float) -> None:
        if now_s - self._last_heartbeat_sent >= self.clock.timeouts.heartbeat_period_s:
            self.send_heartbeat()

    def status_text(self, text: str, severity: int = 6) -> None:
        """STATUSTEXT, split into 50-character chunks (MAVLink 2 id/chunk_seq for multi-chunk)."""
        encoded = text.encode("ascii", "replace")
        chunks = [encoded[i:i + STATUSTEXT_CHUNK] for i in range(0, len(encoded), STATUSTEXT_CHUNK)] or [b""]
        message_id = 0
        if len(chunks) > 1:
            self._statustext_id = self._statustext_id % 65535 + 1
            message_id = self._statustext_id
        for seq, chunk in enumerate(chunks):
            self.transport.mav.statustext_send(severity, chunk, message_id, seq)
        self._tell(Report("text", self.clock.vehicle_time_s, text=text, severity=severity))

    def named_value(self, name: str, value: float) -> None:
        """NAMED_VALUE_FLOAT for live graphs; ``name`` must be 1..10 printable ASCII characters."""
        validate_named_value_name(name)
        now = self.clock.vehicle_time_s
        time_ms = int(now * 1000) & 0xFFFFFFFF if math.isfinite(now) else 0
        self.transport.mav.named_value_float_send(time_ms, name.encode("ascii"), float(value))
        self._tell(Report("value", now, name=name, value=float(value)))

    def send_command_ack(self, command: int, result: int, progress: int = 0, target_system: int = 0,
                         target_component: int = 0) -> None:
        """COMMAND_ACK (IN_PROGRESS with ``progress`` 0..100, ACCEPTED, FAILED ...). Target 0/0
        means the sender of the last user command with this id, or broadcast if none."""
        if target_system == 0 and target_component == 0 and self.last_user_command is not None \
                and self.last_user_command.command == command:
            target_system = self.last_user_command.source_system
            target_component = self.last_user_command.source_component
        self._ack(command, result, progress, target_system, target_component)

    def _ack(self, command: int, result: int, progress: int, target_system: int, target_component: int) -> None:
        self.transport.mav.command_ack_send(command, result, progress, 0, target_system, target_component)
        self._tell(Report("ack", self.clock.vehicle_time_s, command=command, result=result, progress=progress))

    def on_report(self, listener: Callable[[Report], None]) -> None:
        """Call ``listener(report)`` after each STATUSTEXT, NAMED_VALUE_FLOAT and COMMAND_ACK we send
        (:class:`Report`). A listener only watches: one that raises is logged and never stops a report."""
        self._report_listeners.append(listener)

    def _tell(self, report: Report) -> None:
        for listener in self._report_listeners:
            try:
                listener(report)
            except Exception as exc:  # noqa: BLE001 - a watcher must never break the link
                log.debug("report listener failed: %s", exc, exc_info=True)

    # ------------------------------------------------------------------ user commands
    def command_senders(self) -> set[int]:
        """System ids whose procedure commands are obeyed: the ground station's and ``allowed_senders``."""
        return {self.gcs_sysid, *self.allowed_senders}

    def on_user_command(self, callback: Callable[[int, tuple[float, ...]], None] | None) -> None:
        """``callback(command_id, params)`` for COMMAND_LONG MAV_CMD_USER_1..5 aimed at our component
        (or broadcast), called from :meth:`deliver`. Without a callback, such commands are answered
        UNSUPPORTED. ``last_user_command`` holds the sender for :meth:`send_command_ack`."""
        self._callback = callback

    def inject(self, command: UserCommand) -> None:
        """Queue a user command as if it had arrived (a local caller starting a procedure)."""
        self._queue.append(command)

    def _on_command_long(self, msg: Any) -> None:
        if not self.transport.aimed_at_us(msg.target_system, msg.target_component):
            return
        if MAV_CMD_USER_1 <= msg.command <= MAV_CMD_USER_5:
            sender = msg.get_srcSystem()
            if sender not in self.command_senders():
                # a procedure moves the vehicle: only the ground station (or an allowed system) starts one
                self._ack(msg.command, MAV_RESULT_DENIED, 0, sender, msg.get_srcComponent())
                self.status_text(f"command {msg.command} from system {sender} refused: not the ground station"[:50], 4)
                log.warning("COMMAND_LONG %d from system %d refused (ground station is %d, allowed %s)",
                            msg.command, sender, self.gcs_sysid, sorted(self.allowed_senders))
                return
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
            self._queue.append(UserCommand(msg.command, params, sender, msg.get_srcComponent()))
        elif msg.target_component == self.transport.component:
            self._ack(msg.command, MAV_RESULT_UNSUPPORTED, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def deliver(self) -> None:
        """Hand the queued user commands to the callback (a failing handler answers FAILED)."""
        while self._queue:
            command = self._queue.popleft()
            self.last_user_command = command
            if self._callback is None:
                self._ack(command.command, MAV_RESULT_UNSUPPORTED, 0, command.source_system, command.source_component)
                continue
            try:
                self._callback(command.command, command.params)
            except Exception:  # a failing handler must not take the link down
                log.exception("user command %d handler failed", command.command)
                self._ack(command.command, MAV_RESULT_FAILED, 0, command.source_system, command.source_component)

    # ------------------------------------------------------------------ other companions
    def _on_heartbeat(self, msg: Any) -> None:
        """A HEARTBEAT from an onboard controller on our component id is another companion: a router
        never hands us our own messages back, and two companions on one vehicle share its system id."""
        if self.transport.from_autopilot(msg):
            return
        if msg.get_srcComponent() == self.transport.component and getattr(msg, "type", None) == MAV_TYPE_ONBOARD_CONTROLLER:
            self._other_companion = (msg.get_srcSystem(), msg.get_srcComponent(), self.clock.vehicle_time_s)

    def other_companion(self) -> str | None:
        """Why no procedure may run now: another companion was heard within
        :data:`OTHER_COMPANION_S` of vehicle time (None: none was)."""
        seen = self._other_companion
        if seen is None:
            return None
        system, component, when = seen
        now = self.clock.vehicle_time_s
        if math.isfinite(when) and math.isfinite(now) and now - when > self.OTHER_COMPANION_S:
            return None
        return (f"another companion (system {system}, component {component}) is on this vehicle's link: "
                "two would fly it at once")
