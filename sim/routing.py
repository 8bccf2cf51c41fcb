"""The simulator's clients: the transport, what arrives from whom, and what goes where
(docs/PROTOCOL.md, "Transport").

Transports are pymavlink's (``udpin:``, ``udpout:``, ``tcpin:``). ``udpin:`` serves every client
that has sent at least one datagram (pymavlink's multi-client UDP server) and routes messages
between them like an autopilot; ``tcpin:`` serves several clients at once the same way
(sim/tcp_clients.py) and is lossless: the caller lets vehicle time wait for a client that falls
behind (:meth:`Clients.backlogged`). A new client hears a HEARTBEAT at once. All frames of one tick
go out in one datagram/write (:meth:`Clients.send_together`, the hot loop's largest saving).

Arrivals are parsed into :attr:`Clients.inbox` with where they came from (UDP address or
:class:`TcpClient`); applying them is the caller's (under lockstep, only at the limit).
"""
from __future__ import annotations

import collections
import logging
import os
import select
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable

# MAVLink 2 framing must be chosen before pymavlink's dialect module is first imported (this is
# pymavlink's own switch, also used by MAVProxy).
os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from sim.frame_parser import ResyncParser  # noqa: E402
from sim.tcp_clients import TcpClient, TcpClients  # noqa: E402

log = logging.getLogger(__name__)
mavlink = mavutil.mavlink

UDP_CLIENT_TIMEOUT_S = 30.0  # wall seconds: a silent UDP client is dropped if others remain
TCP_LISTEN_BACKLOG = 8  # connections the kernel queues before the simulator accepts them


@dataclass
class Traffic:
    """Counters of the endpoint's traffic (the exit ``STATS`` line's)."""

    sent: int = 0  # frames packed for sending
    received: int = 0  # messages applied (the caller counts them)
    bad: int = 0  # unparseable input, BAD_DATA and input a handler failed on


def addressed_to(msg: Any, system_id: int, component_field: bool = True) -> bool:
    """Whether a message is for the autopilot ``system_id``: its target system is ours or a
    broadcast, and (``component_field``) its target component the autopilot's or a broadcast."""
    target_system = getattr(msg, "target_system", 0)
    if target_system not in (0, system_id):
        return False
    if component_field:
        target_component = getattr(msg, "target_component", 0)
        if target_component not in (0, mavlink.MAV_COMP_ID_AUTOPILOT1):
            return False
    return True


class Clients:
    """One listening endpoint and the clients it serves.

    ``greeting`` builds the HEARTBEAT a new client hears at once (even while vehicle time waits for
    a lockstep companion, when no tick, no stream, would send one); ``on_tcp_drop`` hears of a TCP
    client that left (the lockstep companion may be the one).
    """

    def __init__(self, listen: str, signing_key: bytes | None, greeting: Callable[[], Any],
                 on_tcp_drop: Callable[[TcpClient], None]) -> None:
        self.listen = listen
        self._signing_key = signing_key
        self._greeting = greeting
        self._on_tcp_drop = on_tcp_drop
        self.conn: mavutil.mavfile | None = None
        self._tcp_mode = listen.startswith("tcpin:")
        self._tcp: TcpClients | None = None  # the accepted TCP clients (tcpin: only)
        self.traffic = Traffic()
        # parsed input not yet applied, with where it came from (UDP address or TcpClient): under
        # lockstep what follows the acknowledgement that moves the limit waits for the next limit
        self.inbox: collections.deque[tuple[Any, object]] = collections.deque()

    # ------------------------------------------------------------------ the endpoint
    def open(self, system_id: int) -> None:
        self.conn = mavutil.mavlink_connection(
            self.listen,
            source_system=system_id,
            source_component=mavlink.MAV_COMP_ID_AUTOPILOT1,
            udp_timeout=UDP_CLIENT_TIMEOUT_S,
        )
        self.conn.mav.robust_parsing = True
        if self._signing_key is not None:
            # as an autopilot with signing enabled: outgoing frames signed, unsigned input dropped
            self.conn.setup_signing(self._signing_key, sign_outgoing=True)
        if self._tcp_mode:
            self.conn.listen.listen(TCP_LISTEN_BACKLOG)  # pymavlink listens with a backlog of 1
            self._tcp = TcpClients(self.conn.listen, self._client_parser, on_drop=self._on_tcp_drop)

    def _client_parser(self) -> ResyncParser:
        """A MAVLink parser of one TCP client's bytes, sharing the endpoint's signing state, that
        resynchronises after a damaged frame (sim/frame_parser.py: a serial link bridged to the port
        loses bytes, and in lockstep nothing would come to complete a false frame)."""
        mav = self.conn.mav
        parser = type(mav)(None, srcSystem=mav.srcSystem, srcComponent=mav.srcComponent)
        parser.robust_parsing = True
        parser.signing = mav.signing
        return ResyncParser(parser)

    def set_system_id(self, system_id: int) -> None:
        """SYSID_THISMAV changed: what is sent from now on carries it."""
        if self.conn is not None:
            self.conn.mav.srcSystem = system_id

    def bound_endpoint(self) -> str:
        """The listen endpoint with the port actually bound (``…:0`` asks the OS for a free one)."""
        listen = self.listen
        sock = None
        if self.conn is not None:
            sock = self.conn.listen if self._tcp_mode else getattr(self.conn, "port", None)
        if sock is None or not listen.startswith(("udpin:", "tcpin:")):
            return listen
        try:
            host, port = sock.getsockname()[:2]
        except OSError:
            return listen
        return f"{listen.split(':', 1)[0]}:{host}:{port}"

    def close(self) -> None:
        if self._tcp is not None:
            self._tcp.close()
        if self.conn is not None:
            try:
                self.conn.close()
            except OSError:
                pass
            self.conn = None

    @property
    def dropped(self) -> int:
        """Frames dropped for TCP clients that could not take them."""
        return self._tcp.dropped if self._tcp is not None else 0

    # ------------------------------------------------------------------ incoming
    def receive(self) -> bool:
        """Read what has arrived, parse it and queue the messages in the inbox with their origin
        (UDP address or TcpClient); False when nothing arrived. New clients are greeted."""
        conn = self.conn
        if conn is None:
            return False
        if self._tcp is not None:
            for client in self._tcp.accept():
                self._greet(client)
            received = self._tcp.receive()
            for client, data in received:
                self._parse(client.parser, data, client)
            return bool(received)
        try:
            data, sender = conn.port.recvfrom(65535)
        except (BlockingIOError, InterruptedError):
            return False
        except OSError as exc:  # e.g. ECONNREFUSED reported for an earlier datagram
            log.debug("recv failed: %s", exc)
            return False
        if getattr(conn, "udp_server", False):  # pymavlink's client list, used by conn.write
            new = sender not in conn.clients
            conn.clients.add(sender)
            conn.clients_last_alive[sender] = time.time()
            if new:
                self._greet(sender)
        self._parse(conn.mav, data, sender)
        # A frame never spans UDP datagrams: drop a partial tail so that garbage from one client
        # cannot swallow the next datagram (of any client).
        conn.mav.buf = bytearray()
        conn.mav.buf_index = 0
        return True

    def _parse(self, parser: Any, data: bytes, origin: object) -> None:
        try:
            messages = parser.parse_buffer(data) or []
        except Exception as exc:  # malformed input must never stop the simulator
            self.traffic.bad += 1
            log.debug("unparseable input (%s)", exc)
            messages = []
        self.inbox.extend((msg, origin) for msg in messages)

    def _greet(self, client: object) -> None:
        """A HEARTBEAT for a client just heard from, at once."""
        frame = self.pack(self._greeting())
        if frame is None:
            return
        if isinstance(client, TcpClient):
            self._tcp.send(frame, only=client)
            return
        try:
            self.conn.port.sendto(frame, client)
        except OSError as exc:
            log.debug("heartbeat to %s failed: %s", client, exc)

    def route(self, msg: Any, origin: object, system_id: int) -> None:
        """Forward a client's message to the other clients unless it was for the autopilot only.

        This is what an autopilot's MAVLink routing does for a GCS and a companion computer on
        different links: the companion's STATUSTEXT/NAMED_VALUE_FLOAT reach the GCS, and a GCS's
        COMMAND_LONG to component 191 reaches the companion.
        """
        if msg.get_type() == "BAD_DATA":
            return
        if self._tcp is not None:
            if len(self._tcp.clients) < 2:
                return
        else:
            clients = getattr(self.conn, "clients", None)
            if not clients or len(clients) < 2 or origin is None:
                return
        target_system = getattr(msg, "target_system", 0)
        target_component = getattr(msg, "target_component", 0)
        if target_system == system_id and target_component == mavlink.MAV_COMP_ID_AUTOPILOT1:
            return
        frame = msg.get_msgbuf()
        if self._tcp is not None:
            self._tcp.send(bytes(frame), exclude=origin)
            return
        for client in list(clients):
            if client != origin:
                try:
                    self.conn.port.sendto(frame, client)
                except OSError as exc:
                    log.debug("forward to %s failed: %s", client, exc)

    # ------------------------------------------------------------------ outgoing
    def pack(self, msg: Any) -> bytes | None:
        """One packed frame (what MAVLink.send does, minus the write: pack and sequence number)."""
        if self.conn is None:
            return None
        encoder = self.conn.mav
        try:
            frame = msg.pack(encoder)
        except Exception as exc:  # a value out of a field's range must not stop the simulator
            log.warning("cannot pack %s: %s", msg.get_type(), exc)
            return None
        encoder.seq = (encoder.seq + 1) % 256
        self.traffic.sent += 1
        return frame

    def send(self, msg: Any) -> None:
        """Send a message to every client."""
        frame = self.pack(msg)
        if frame is not None:
            self._write(frame)

    def send_together(self, messages: Iterable[Any | None]) -> None:
        """Send messages (None: nothing) packed into ONE datagram / TCP write.

        MAVLink allows several frames per UDP datagram (ArduPilot does the same); one system call
        per tick instead of one per message is the largest saving of the hot loop, for the
        simulator and for every client.
        """
        batch = bytearray()
        try:
            for msg in messages:
                frame = self.pack(msg) if msg is not None else None
                if frame is not None:
                    batch += frame
        finally:
            self._write(bytes(batch))

    def _write(self, data: bytes) -> None:
        if not data or self.conn is None:
            return
        if self._tcp is not None:
            self._tcp.send(data)  # every client; lossless, flow-controlled (sim/tcp_clients.py)
            return
        try:
            self.conn.write(data)  # pymavlink: sendto every known UDP client
        except (OSError, ValueError) as exc:
            log.debug("write failed: %s", exc)

    # ------------------------------------------------------------------ waiting
    def backlogged(self) -> bool:
        """A TCP client is behind (vehicle time must wait for it); never for UDP."""
        if self._tcp is None:
            return False
        self._tcp.flush()  # whatever a full socket left queued, even when no new frame follows
        return self._tcp.backlogged()

    def wait_readable(self, timeout: float) -> None:
        """Wait for input, or (TCP) for a client's socket to take frames still queued for it."""
        pending: list[int] = []
        if self._tcp is not None:
            fds = self._tcp.fds()
            pending = self._tcp.pending_fds()
        else:
            fds = [self.conn.fd] if self.conn is not None and self.conn.fd is not None else []
        try:
            if fds:
                select.select(fds, pending, [], timeout)
            else:
                time.sleep(timeout)
        except (OSError, ValueError):
            time.sleep(timeout)

    def wait_writable(self, timeout: float) -> None:
        """Wait (at most ``timeout``) for a backlogged TCP client's socket to take more."""
        fds = self._tcp.writable_fds() if self._tcp is not None else []
        try:
            if fds:
                select.select([], fds, [], timeout)
        except (OSError, ValueError):
            pass
