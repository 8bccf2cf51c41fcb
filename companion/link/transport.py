"""The MAVLink connection to one autopilot: open, receive and dispatch, send, reconnect (SPEC C1).

:class:`Transport` is the only owner of pymavlink's connection object. Everything else in the
link is handed a transport and uses three things of it: :meth:`Transport.on` to be called with
every message of a type, :meth:`Transport.pump` to receive and dispatch one message, and
:attr:`Transport.mav` (pymavlink's encoder) to send. Identity is set explicitly on every frame
(SPEC C1: system id of the vehicle, component 191); :meth:`Transport.send_as` sends one message
under another identity (an ArduPilot RC override must come from the ground station's id).

The wall clock appears here only as the guard of blocking socket reads and of (re)connection
attempts; every timer of the product runs on vehicle time (``companion.link.clock``).
"""
from __future__ import annotations

import contextlib
import io
import logging
import os
import sys
import time
from collections import defaultdict
from typing import Any, Callable

from companion.link.errors import EndpointError, HeartbeatTimeout, LinkLost
from companion.link.frame_loss import FrameLoss, frame_check, next_whole_frame

log = logging.getLogger(__name__)

MAV_TYPE_GCS = 6
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4

Handler = Callable[[Any], None]


class _LogLines(io.TextIOBase):
    """A text stream whose lines become debug log records."""

    def __init__(self, logger: logging.Logger) -> None:
        self.logger = logger

    def write(self, text: str) -> int:
        if text.strip():
            self.logger.debug("pymavlink: %s", text.strip())
        return len(text)


def open_connection(endpoint: str, *, system_id: int, component: int, dialect: str,
                    signing_key: bytes | None = None, retries: int | None = None) -> Any:
    """pymavlink's connection to ``endpoint`` (any of its connection strings), with link loss
    reported as :class:`LinkLost` instead of pymavlink's print-and-reconnect loop. EndpointError
    when it cannot be opened."""
    from pymavlink import mavutil

    # MAVLink 2 is needed for signing and the servo9+ extension fields; pymavlink chooses the wire
    # version through this process-wide variable, so it is set before the dialect is loaded
    os.environ.setdefault("MAVLINK20", "1")
    mavutil.set_dialect(dialect)
    options = {} if retries is None else {"retries": retries}
    try:
        # pymavlink prints its TCP retries ("Connection refused sleeping") to stdout: they go to the
        # log instead, so stdout holds only what the command prints (its --json stays parseable)
        with contextlib.redirect_stdout(_LogLines(log)):
            master = mavutil.mavlink_connection(endpoint, source_system=system_id, source_component=component,
                                                robust_parsing=True, **options)
    except OSError as exc:  # refused TCP connection, missing serial device (SerialException), bad address
        raise EndpointError(f"cannot open {endpoint}: {exc}") from exc
    if signing_key is not None:
        master.setup_signing(signing_key, sign_outgoing=True)
    _raise_on_stream_end(master, endpoint)
    return master


def await_autopilot_heartbeat(master: Any, timeout_s: float, endpoint: str, *, signed: bool = False) -> Any:
    """The first HEARTBEAT of an autopilot (not a ground station, not a companion), beaconing our
    own HEARTBEAT once a second meanwhile so a ``udpout:`` peer learns our address; HeartbeatTimeout
    after ``timeout_s`` of wall clock (no vehicle clock exists before the vehicle answers). ``signed``:
    we sign, and a signed link drops every unsigned frame: the timeout then says so."""
    deadline = time.monotonic() + timeout_s
    next_beacon = 0.0
    while True:
        now = time.monotonic()
        if now >= deadline:
            hint = ("; with a signing key only frames signed with the same key are accepted: is the vehicle "
                    "signing, with this key?") if signed else ""
            raise HeartbeatTimeout(f"no autopilot HEARTBEAT on {endpoint} within {timeout_s:g} s (wall clock){hint}")
        if now >= next_beacon:
            master.mav.heartbeat_send(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE)
            next_beacon = now + 1.0
        msg = master.recv_match(type="HEARTBEAT", blocking=True, timeout=min(0.25, deadline - now))
        if msg is not None and msg.autopilot != MAV_AUTOPILOT_INVALID and msg.type not in (
                MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER):
            return msg


class Transport:
    """One autopilot's connection, its identities, and the handlers of each message type."""

    def __init__(self, master: Any, *, system_id: int, autopilot_component: int, component: int,
                 endpoint: str | None = None, signing_key: bytes | None = None, dialect: str = "common") -> None:
        self._master = master
        self.system_id = system_id
        self.autopilot_component = autopilot_component
        self.component = component
        self.endpoint = endpoint
        self.dialect = dialect
        self._signing_key = signing_key
        self._handlers: dict[str, list[Handler]] = defaultdict(list)
        self._reconnect_listeners: list[Callable[[], None]] = []
        self.last_rx_wall = time.monotonic()
        self.reconnects = 0  # connections opened again after the vehicle closed or reset one
        # the vehicle's frames lost on the link (sequence gaps) and discarded as corrupt (frame_loss)
        self.frame_loss = FrameLoss()
        # the vehicle time of the autopilot's latest frame that carries one (whatever its type): what
        # a stalled lockstep link knows of the vehicle's clock when the samples themselves were lost
        self.heard_time_ms: int | None = None

    @property
    def signing(self) -> bool:
        """This link signs what it sends (a MAVLink 2 signing key was given)."""
        return self._signing_key is not None

    # ------------------------------------------------------------------ receiving
    def on(self, message_type: str, handler: Handler) -> None:
        """Call ``handler(msg)`` for every received message of ``message_type``, in registration order."""
        self._handlers[message_type].append(handler)

    def pump(self, wall_timeout_s: float) -> Any:
        """Receive and dispatch one message (None when nothing arrived within the wall timeout)."""
        msg = self._master.recv_match(blocking=True, timeout=max(wall_timeout_s, 0.0))
        if msg is None:
            return None
        self.last_rx_wall = time.monotonic()
        self._count_frame(msg)
        for handler in self._handlers.get(msg.get_type(), ()):
            handler(msg)
        return msg

    def _count_frame(self, msg: Any) -> None:
        """The link's frame counts (``companion.link.frame_loss``): what the parser discarded, and the
        sequence number of every frame from the vehicle's system but not our own component."""
        if msg.get_type() == "BAD_DATA":
            raw = getattr(msg, "data", None)
            self.frame_loss.discarded(len(raw) if raw is not None else 0)
            return
        seq = getattr(msg, "get_seq", None)
        if seq is None or not self.from_vehicle(msg) or msg.get_srcComponent() == self.component:
            return
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.get_type().startswith("UNKNOWN"):  # not CRC-checked: maybe a damaged frame
            self.frame_loss.unchecked_frame(sender, seq())
            return
        self.frame_loss.frame(sender, seq())
        stamp = getattr(msg, "time_boot_ms", None)
        if isinstance(stamp, int) and sender[1] == self.autopilot_component:
            self.heard_time_ms = stamp

    def from_vehicle(self, msg: Any) -> bool:
        """Sent by the vehicle's system (any of its components)."""
        return msg.get_srcSystem() == self.system_id

    def from_autopilot(self, msg: Any) -> bool:
        """Sent by the autopilot component itself."""
        return msg.get_srcSystem() == self.system_id and msg.get_srcComponent() == self.autopilot_component

    def aimed_at_us(self, target_system: int, target_component: int) -> bool:
        """A message for our system (or broadcast) and our component (or broadcast)."""
        return target_system in (0, self.system_id) and target_component in (0, self.component)

    # ------------------------------------------------------------------ sending
    @property
    def mav(self) -> Any:
        """pymavlink's encoder: ``transport.mav.<message>_send(...)`` sends one message as us."""
        return self._master.mav

    def send_as(self, system_id: int, component: int, send: Callable[[Any], None]) -> None:
        """``send(mav)`` with another source identity for that one message, then ours again."""
        mav = self._master.mav
        own = (mav.srcSystem, mav.srcComponent)
        mav.srcSystem, mav.srcComponent = system_id, component
        try:
            send(mav)
        finally:
            mav.srcSystem, mav.srcComponent = own

    def command_long(self, command: int, params: tuple[float, ...] | list[float], *, confirmation: int = 0) -> None:
        """COMMAND_LONG to the autopilot (missing parameters are 0)."""
        values = list(params) + [0.0] * (7 - len(params))
        self._master.mav.command_long_send(self.system_id, self.autopilot_component, command, confirmation, *values)

    @property
    def bytes_received(self) -> int:
        """Bytes received on this connection so far (pymavlink's count)."""
        count = getattr(self._master.mav, "total_bytes_received", 0)
        return count if isinstance(count, int) else 0  # 0: not pymavlink's parser

    @property
    def unparsed_bytes(self) -> int:
        """Bytes received but not yet parsed into messages (how far the reader lags the stream)."""
        mav = self._master.mav
        buffer, index = getattr(mav, "buf", None), getattr(mav, "buf_index", 0)
        if not isinstance(buffer, (bytes, bytearray)) or not isinstance(index, int):
            return 0  # not pymavlink's parser
        return len(buffer) - index

    def resynchronise(self) -> bool:
        """Part of a frame waits in pymavlink's parser while nothing more arrives (a lockstep link
        stalled after a radio lost bytes of it): pymavlink trusts the damaged frame's length byte and
        would take the next frames' bytes as its own, so frames that did arrive whole stay hidden
        behind it. Move the parser on to the first whole frame after its start that passes its checks
        (``frame_loss.next_whole_frame``; the bytes skipped are counted as discarded); True when one
        was found (the next :meth:`pump` returns it), False when there is none (it is left waiting)."""
        mav = self._master.mav
        buffer, index = getattr(mav, "buf", None), getattr(mav, "buf_index", 0)
        if not isinstance(buffer, bytearray) or not isinstance(index, int) or len(buffer) - index < 2:
            return False
        offset = next_whole_frame(bytes(buffer[index:]), frame_check(sys.modules[type(mav).__module__]))
        if offset is None:
            return False
        mav.buf_index = index + offset
        self.frame_loss.discarded(offset)
        log.debug("resynchronised after a damaged frame: %d bytes skipped", offset)
        return True

    def record_to(self, path: str) -> Any:
        """Write every received frame to a telemetry log (tlog) at ``path``; returns the open file."""
        self._master.setup_logfile(path)
        return self._master.logfile

    # ------------------------------------------------------------------ connection
    def on_reconnect(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` after every successful :meth:`reconnect` (streams, lockstep...)."""
        self._reconnect_listeners.append(listener)

    @property
    def can_reconnect(self) -> bool:
        """Only a TCP client connection can be opened again (a UDP or serial link never closes)."""
        return self.endpoint is not None and hasattr(self._master, "destination_addr")

    def reconnect(self, timeout_s: float) -> bool:
        """Open the TCP connection again after the vehicle closed or reset it, trying for
        ``timeout_s`` of wall clock until the autopilot's HEARTBEAT arrives on a new connection;
        that heartbeat is dispatched like any other, then the reconnect listeners run. False when
        the vehicle did not come back; everything the link knows is kept either way."""
        endpoint = self.endpoint
        if endpoint is None or not self.can_reconnect:
            return False
        deadline = time.monotonic() + timeout_s
        try:
            self._master.close()
        except OSError:
            pass
        while time.monotonic() < deadline:
            try:  # retries=0: one attempt, never pymavlink's print-and-sleep loop
                master = open_connection(endpoint, system_id=self.system_id, component=self.component,
                                         dialect=self.dialect, signing_key=self._signing_key, retries=0)
            except (OSError, EndpointError):
                time.sleep(0.2)
                continue
            try:
                heartbeat = await_autopilot_heartbeat(master, max(deadline - time.monotonic(), 0.1), endpoint)
            except (HeartbeatTimeout, LinkLost):
                master.close()
                continue
            self._master = master
            self.reconnects += 1
            self.frame_loss.forget_senders()  # a new connection numbers its frames afresh
            self.last_rx_wall = time.monotonic()
            for handler in self._handlers.get("HEARTBEAT", ()):
                handler(heartbeat)
            for listener in self._reconnect_listeners:
                listener()
            log.warning("reconnected to %s", self.endpoint)
            return True
        log.error("%s did not come back within %.0f s", self.endpoint, timeout_s)
        return False

    def close(self) -> None:
        self._master.close()


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
