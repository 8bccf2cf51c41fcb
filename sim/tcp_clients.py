"""The simulator's TCP clients: several at once, as an autopilot serves a GCS and a companion on
different ports and MAVProxy serves several outputs.

Every connected client gets the whole stream (heartbeats, telemetry, replies), has its own MAVLink
parser (a frame never spans two clients' bytes) and its own queue of whole frames not yet accepted
by its socket (a partial send would corrupt its stream).

Flow control (docs/PROTOCOL.md, "Transport"): TCP here is lossless. A client more than
``HIGH_WATER`` bytes behind makes vehicle time wait for it. With several clients, one that has not
read anything for ``STALL_S`` wall seconds (an idle or hung viewer) must not freeze the vehicle for
the others: it becomes *lossy* (whole frames dropped while it is behind, logged once) until it has
caught up. A lone client is never made lossy: it is the only consumer and vehicle time waits for it.
"""
from __future__ import annotations

import logging
import socket
import time
from dataclasses import dataclass, field
from typing import Any, Callable

log = logging.getLogger(__name__)

KERNEL_BUFFER = 32 * 1024  # SO_SNDBUF of an accepted client: bounds how far it lags behind vehicle time
HIGH_WATER = 16 * 1024  # bytes queued for a client before the physics waits for it
MAX_QUEUE = 4 * 1024 * 1024  # never queue more for one client (frames beyond it are dropped whole)
STALL_S = 2.0  # wall seconds without progress before a client among several becomes lossy


@dataclass(eq=False)
class TcpClient:
    """One accepted connection: its socket, parser and queue of whole frames."""

    sock: socket.socket
    address: tuple
    parser: Any  # a pymavlink MAVLink object: this client's own frame parser
    out: bytearray = field(default_factory=bytearray)
    stalled_since: float | None = None  # wall time the queue stopped draining (None: draining)
    lossy: bool = False
    dropped: int = 0

    @property
    def name(self) -> str:
        return f"{self.address[0]}:{self.address[1]}"


class TcpClients:
    """The accepted clients of one listening socket (``listen`` is pymavlink's ``tcpin`` socket)."""

    def __init__(self, listen: socket.socket, make_parser: Callable[[], Any],
                 on_drop: Callable[[TcpClient], None] | None = None) -> None:
        self.listen = listen
        self._make_parser = make_parser
        self._on_drop = on_drop  # told when a client goes (the lockstep companion may be the one)
        self.clients: list[TcpClient] = []
        self.dropped = 0  # frames dropped for clients that were behind (lossy or over MAX_QUEUE)

    # ------------------------------------------------------------------ connections
    def accept(self) -> list[TcpClient]:
        """Accept every pending connection; returns the new clients."""
        new = []
        while True:
            try:
                sock, address = self.listen.accept()
            except (BlockingIOError, InterruptedError):
                return new
            except OSError as exc:
                log.debug("accept failed: %s", exc)
                return new
            sock.setsockopt(socket.SOL_TCP, socket.TCP_NODELAY, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, KERNEL_BUFFER)
            sock.setblocking(False)
            client = TcpClient(sock, address, self._make_parser())
            self.clients.append(client)
            new.append(client)
            log.info("TCP client connected from %s (%d connected)", client.name, len(self.clients))

    def drop(self, client: TcpClient) -> None:
        """Forget a client that closed, reset or failed."""
        if client not in self.clients:
            return
        self.clients.remove(client)
        try:
            client.sock.close()
        except OSError:
            pass
        log.info("TCP client %s disconnected (%d connected)", client.name, len(self.clients))
        if self._on_drop is not None:
            self._on_drop(client)

    def close(self) -> None:
        for client in list(self.clients):
            self.drop(client)

    def fds(self) -> list[int]:
        """File descriptors to wait on for input: the listening socket and every client."""
        return [self.listen.fileno(), *(c.sock.fileno() for c in self.clients)]

    # ------------------------------------------------------------------ input
    def receive(self) -> list[tuple[TcpClient, bytes]]:
        """What each client has sent since the last call (clients that closed are dropped)."""
        received = []
        for client in list(self.clients):
            try:
                data = client.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                data = b""
            if not data:
                self.drop(client)
                continue
            received.append((client, data))
        return received

    # ------------------------------------------------------------------ output
    def send(self, data: bytes, only: TcpClient | None = None, exclude: TcpClient | None = None) -> None:
        """Queue whole frames for every client (or ``only`` one, or all but ``exclude``) and flush."""
        for client in list(self.clients):
            if (only is not None and client is not only) or client is exclude:
                continue
            if len(client.out) + len(data) > MAX_QUEUE or (client.lossy and len(client.out) > HIGH_WATER):
                client.dropped += 1
                self.dropped += 1
                continue
            client.out += data
            self._flush(client)

    def flush(self) -> None:
        """Hand every client's queued frames to its socket, as far as it takes them. Called on every
        turn of the main loop: a queue left behind by a full socket must drain even when no new
        frame follows (in lockstep nothing does until the companion has read it: a deadlock)."""
        for client in list(self.clients):
            if client.out:
                self._flush(client)

    def _flush(self, client: TcpClient) -> None:
        while client.out:
            try:
                sent = client.sock.send(client.out)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self.drop(client)
                return
            del client.out[:sent]

    def backlogged(self, now: float | None = None) -> bool:
        """True while a lossless client is more than HIGH_WATER behind (vehicle time waits for it).

        Among several clients, one that has not drained for STALL_S wall seconds becomes lossy."""
        now = time.monotonic() if now is None else now
        waiting = False
        for client in list(self.clients):
            if len(client.out) <= HIGH_WATER:
                client.stalled_since = None
                if client.lossy and not client.out:
                    client.lossy = False
                    log.info("TCP client %s caught up (%d frames dropped while it was stalled)", client.name,
                             client.dropped)
                continue
            before = len(client.out)
            self._flush(client)
            if client not in self.clients or len(client.out) <= HIGH_WATER:
                continue
            if len(client.out) < before or client.stalled_since is None:
                client.stalled_since = now  # the last time it made progress
            if client.lossy:
                continue
            if len(self.clients) > 1 and now - client.stalled_since >= STALL_S:
                client.lossy = True
                log.warning("TCP client %s has read nothing for %.0f s: dropping its frames while it is behind, "
                            "so the other clients keep their vehicle", client.name, STALL_S)
                continue
            waiting = True
        return waiting

    def writable_fds(self) -> list[int]:
        """Sockets of lossless clients with frames queued (to wait until one can take more)."""
        return [c.sock.fileno() for c in self.clients if c.out and not c.lossy]

    def pending_fds(self) -> list[int]:
        """Sockets of every client with frames queued (a wait for input must also wake to send them)."""
        return [c.sock.fileno() for c in self.clients if c.out]
