"""MAVLink's command protocol on the simulated autopilot (docs/PROTOCOL.md, "Commands").

COMMAND_LONG and COMMAND_INT are executed, acknowledged with COMMAND_ACK, and what a command asked
for (REQUEST_MESSAGE, AUTOPILOT_CAPABILITIES, GET_MESSAGE_INTERVAL) is sent after the
acknowledgement, in ArduPilot's order. SET_MODE is acknowledged like a command; RC_CHANNELS_OVERRIDE
is taken from the ground station SYSID_MYGCS only, without a reply.
"""
from __future__ import annotations

import logging
import math
from typing import Any, Callable, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim.autopilot import Autopilot, Result
from sim.params import ParamTable
from sim.routing import addressed_to
from sim.streams import STREAM_ORDER, StreamScheduler
from sim.telemetry import autopilot_version

log = logging.getLogger(__name__)

#: what MAV_CMD_REQUEST_MESSAGE may ask for
REQUESTABLE = frozenset(STREAM_ORDER + (mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,))


class CommandHost(Protocol):
    """What the protocol needs of the autopilot it serves (``SimServer``)."""

    params: ParamTable
    autopilot: Autopilot
    streams: StreamScheduler
    tick: int

    def send(self, msg: Any) -> None: ...

    def build(self, msg_id: int) -> Any | None:
        """One message of the streamed set (or AUTOPILOT_VERSION) from the current state."""

    def schedule_reboot(self) -> int:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: start a reboot; a MAV_RESULT."""


class CommandProtocol:
    """The handlers of the command messages, by message type (:attr:`handlers`)."""

    def __init__(self, host: CommandHost) -> None:
        self._host = host
        self._after_ack: list[Any] = []  # replies a command asked for, sent after its COMMAND_ACK
        self.handlers: dict[str, Callable[[Any], None]] = {
            "SET_MODE": self.set_mode,
            "RC_CHANNELS_OVERRIDE": self.rc_override,
            "COMMAND_LONG": self.command_long,
            "COMMAND_INT": self.command_int,
        }

    def _system_id(self) -> int:
        return int(self._host.params["SYSID_THISMAV"])

    def set_mode(self, msg: Any) -> None:
        if msg.target_system not in (0, self._system_id()):
            return
        result = Result.FAILED
        if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            result = self._host.autopilot.set_mode(int(msg.custom_mode))
        self._ack(msg, mavlink.MAVLINK_MSG_ID_SET_MODE, result)

    def rc_override(self, msg: Any) -> None:
        if not addressed_to(msg, self._system_id()):
            return
        channels = [msg.chan1_raw, msg.chan2_raw, msg.chan3_raw]
        if not self._host.autopilot.rc_override(msg.get_srcSystem(), channels):
            log.debug("RC override from system %d ignored (SYSID_MYGCS %d)",
                      msg.get_srcSystem(), int(self._host.params["SYSID_MYGCS"]))

    def command_long(self, msg: Any) -> None:
        if not addressed_to(msg, self._system_id()):
            return
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._answer(msg, params)

    def command_int(self, msg: Any) -> None:
        if not addressed_to(msg, self._system_id()):
            return
        params = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
        self._answer(msg, params)

    def _answer(self, msg: Any, params: tuple) -> None:
        """Execute, ACK, then send what the command asked for (ArduPilot's order)."""
        self._after_ack = []
        result = self._command(msg.command, params, msg)
        self._ack(msg, msg.command, result)
        for reply in self._after_ack:
            self._host.send(reply)
        self._after_ack = []

    def _ack(self, msg: Any, command: int, result: int) -> None:
        self._host.send(
            mavlink.MAVLink_command_ack_message(
                command, int(result), 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )

    def _command(self, command: int, p: tuple, msg: Any) -> int:
        """Execute one COMMAND_LONG/COMMAND_INT; returns a MAV_RESULT (PROTOCOL.md Commands)."""
        host = self._host
        ap = host.autopilot
        if not all(math.isfinite(v) for v in p[:4]):
            return Result.DENIED
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            return ap.arm(p[0] >= 0.5)
        if command == mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN and int(p[0]) == 1:
            return host.schedule_reboot()
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            if not int(p[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return Result.FAILED
            return ap.set_mode(int(p[1]))
        if command == mavlink.MAV_CMD_DO_SET_SERVO:
            return ap.set_servo(int(p[0]), p[1])
        if command == mavlink.MAV_CMD_CONDITION_YAW:
            relative = p[3] != 0
            heading = math.radians(p[0])
            if relative and p[2] < 0:
                heading = -heading
            return ap.set_heading(heading, relative=relative)
        if command == mavlink.MAV_CMD_DO_CHANGE_ALTITUDE:
            return ap.set_depth(-p[0])
        if command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            if p[2] < 0:  # −1 = no change
                return Result.ACCEPTED
            return ap.set_thrust(p[2] / 100.0)
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            built = host.build(int(p[0])) if int(p[0]) in REQUESTABLE else None
            if built is None:
                return Result.DENIED
            self._after_ack.append(built)
            return Result.ACCEPTED
        if command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._after_ack.append(autopilot_version(self._system_id()))
            return Result.ACCEPTED
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            known = host.streams.set_interval(int(p[0]), p[1], host.tick)
            return Result.ACCEPTED if known else Result.DENIED
        if command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            interval = host.streams.interval_us(int(p[0]))
            if interval is None:
                return Result.DENIED
            self._after_ack.append(mavlink.MAVLink_message_interval_message(int(p[0]), interval))
            return Result.ACCEPTED
        log.info("unsupported command %d from %d/%d", command, msg.get_srcSystem(),
                 msg.get_srcComponent())
        return Result.UNSUPPORTED
