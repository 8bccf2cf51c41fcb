"""A tiny ArduPilot-style autopilot in process (real MAVLink 2 bytes both ways, no sockets) and a
:class:`VehicleLink` connected to it: the fixture of the link's and the trail's unit tests."""
from __future__ import annotations

import collections
import os

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from companion.link import param_codec as pc  # noqa: E402
from companion.link.snapshot import DepthSensor  # noqa: E402
from companion.link.vehicle import LinkTimeouts, VehicleLink  # noqa: E402


def wire(msg, src: int = 1, comp: int = 1):
    """``msg`` as the link would receive it: packed by a sender with that identity and decoded."""
    sender = mavlink.MAVLink(None, srcSystem=src, srcComponent=comp)
    return mavlink.MAVLink(None).decode(bytearray(msg.pack(sender)))


class FakeAutopilot:
    """Stands in for pymavlink's mavfile: decodes what the link sends (real MAVLink 2 bytes),
    answers like a tiny ArduPilot-style autopilot, and streams one ATTITUDE every 50 ms of
    vehicle time whenever the link asks for a message and none is queued."""

    def __init__(self) -> None:
        self.mav = mavlink.MAVLink(self, srcSystem=1, srcComponent=191)  # the link's sender
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self.queue: collections.deque = collections.deque()
        self.sent: list = []
        self.time_ms = 10_000
        self.params = {"HDG_P": (0.6, pc.REAL32), "SYSID_MYGCS": (255.0, pc.INT16), "RC_OVR_TIME": (3.0, pc.REAL32)}
        self.echo_instead: dict[str, float] = {}  # name -> value echoed instead of the written one
        self.silent_params: set[str] = set()
        self.encoding = "cast"
        self.custom_mode = 19
        self.silent = False
        self.reply_lag_ticks = 0

    # -- mavfile surface used by VehicleLink
    def write(self, buf) -> None:
        for msg in self._parser.parse_buffer(bytes(buf)) or []:
            self.sent.append(msg)
            self._answer(msg)

    def recv_match(self, blocking=True, timeout=None, **_):
        if self.silent:
            return None
        if not self.queue:
            self.tick()
        return self.queue.popleft()

    def tick(self) -> None:
        self.time_ms += 50
        self.emit(mavlink.MAVLink_attitude_message(self.time_ms, 0.0, 0.0, 0.1, 0.0, 0.0, 0.01))

    def close(self) -> None:
        pass

    # -- autopilot behaviour
    def emit(self, msg, src: int = 1, comp: int = 1) -> None:
        self.queue.append(wire(msg, src, comp))

    def _param_value(self, name: str) -> None:
        for _ in range(self.reply_lag_ticks):  # telemetry keeps flowing before the answer
            self.tick()
        value, param_type = self.params[name]
        on_wire = pc.encode_value(value, param_type, self.encoding)
        self.emit(mavlink.MAVLink_param_value_message(name.encode(), on_wire, param_type, len(self.params), 0))

    def _answer(self, msg) -> None:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_READ":
            name = pc.param_id_str(msg.param_id)
            if name in self.params:
                self._param_value(name)
        elif kind == "PARAM_SET":
            name = pc.param_id_str(msg.param_id)
            if name in self.silent_params:
                return
            if name not in self.params:
                self.emit(mavlink.MAVLink_statustext_message(4, f"Unknown parameter {name}".encode()))
                return
            param_type = self.params[name][1]
            value = pc.decode_value(msg.param_value, param_type, self.encoding)
            self.params[name] = (self.echo_instead.get(name, value), param_type)
            self._param_value(name)
        elif kind == "COMMAND_LONG":
            if msg.command == 176:
                self.custom_mode = int(msg.param2)
                self.emit(mavlink.MAVLink_heartbeat_message(12, 3, 1, self.custom_mode, 4, 3))
            self.emit(mavlink.MAVLink_command_ack_message(msg.command, 0, 0, 0, msg.get_srcSystem(),
                                                          msg.get_srcComponent()))

    def sent_of(self, kind: str) -> list:
        return [m for m in self.sent if m.get_type() == kind]


@pytest.fixture
def fake_link():
    fake = FakeAutopilot()
    # the fake answers synchronously (no lag), so a try needs no minimum wall time
    link = VehicleLink(fake, system_id=1, autopilot_component=1, component=191,
                       timeouts=LinkTimeouts(min_try_wall_s=0.0))
    link.setup(None, {}, DepthSensor())
    link.skip_to_now()  # snapshots queued during set-up
    return fake, link
