"""A MAVLink-aware TCP proxy that injects link faults between the companion and the vehicle
(the fault-injection suite).

The proxy listens on a loopback port (bound to port 0: the OS picks it) and opens one upstream TCP
connection to the vehicle (the simulator's ``tcpin`` port) for each companion that connects. It
runs in its own thread, splits both byte streams into whole MAVLink frames
(``harness.mavlink_frames``) and forwards them, except where a :class:`Fault` is active
(``harness.fault_schedule``):

``drop``       the frame is not forwarded;
``delay``      the frame is held until ``hold_frames`` later frames of the same direction have
               passed (a delay in stream position, deterministic on a lockstep link), or at most
               ``max_hold_s`` of wall clock;
``duplicate``  the frame is forwarded twice;
``reorder``    the frame swaps places with the next frame of the same direction (with a
               ``partner``: goes right after the next frame the partner matches), or goes after
               ``max_hold_s`` if none follows;
``corrupt``    one payload byte is flipped, so the receiver's CRC check discards the frame;
``cut``        the link goes down for ``cut_s`` wall seconds: with ``reconnect`` the connections are
               closed (the companion sees EOF, must reconnect, and is accepted again once the cut is
               over), without it every frame of both directions is dropped while the sockets stay
               open (a radio dropout).

A fault starts at its :class:`Trigger` — the K-th frame of one kind the companion sent
(RC_CHANNELS_OVERRIDE, PARAM_SET, COMMAND_LONG with a given command, STATUSTEXT with a given text
...), counted from :meth:`FaultProxy.arm` — and is bounded in count (``frames``) and time
(``window_s``). Which frames fired is recorded (:attr:`FaultProxy.events`), so a test can say
what it exercised and a bench can tabulate it. The schedule is a list given by the caller; a
seeded :class:`random.Random` only picks the byte a ``corrupt`` flips, so a run is a function of
its schedule and seed.

Link conditions (``harness.link_conditions``) per direction: a **byte-rate cap** (a token bucket
in front of a bounded queue: frames that do not fit are dropped, whole, as a radio modem drops what
its buffer cannot hold; the proxy keeps reading, so the vehicle is not slowed by TCP flow control)
and a fixed delay. Loss, jitter, reordering and duplication are datagram conditions: the UDP relay
(``harness.udp_relay``) has them.

The proxy also keeps what the vehicle was told, at the moment each frame left it
(``harness.delivery_log``): the last RC override value on each channel
(:meth:`FaultProxy.held_overrides`), the last parameters of each COMMAND_LONG, and the vehicle time
of the latest sample it saw. Everything stays on loopback.
"""
from __future__ import annotations

import collections
import logging
import random
import selectors
import socket
import threading
import time
from dataclasses import dataclass, field

from harness.delivery_log import DeliveryLog
from harness.fault_schedule import (BOTH, FAULT_KINDS, TO_COMPANION, TO_VEHICLE, Fault, FaultEvent, FaultSchedule, ScheduledFaults,
                                    Trigger, overtaken, timed_delay)
from harness.link_conditions import LinkConditions, TokenBucket
from harness.mavlink_frames import MESSAGE_IDS, Frame, split_frames

log = logging.getLogger(__name__)

__all__ = ["BOTH", "FAULT_KINDS", "MESSAGE_IDS", "TO_COMPANION", "TO_VEHICLE", "Fault", "FaultEvent", "FaultProxy",
           "Frame", "LinkConditions", "Trigger", "overtaken", "per_direction", "split_frames", "timed_delay"]

#: bytes queued for one side before the proxy stops reading the other (back-pressure: the vehicle's
#: own flow control then holds it back, so a slow companion lags no more than on a direct link)
HIGH_WATER = 16 * 1024
TICK_S = 0.005  # the loop's housekeeping period (held frames, cut ends), wall clock


def per_direction(conditions: LinkConditions | dict[str, LinkConditions] | None) -> dict[str, LinkConditions]:
    """``conditions`` for each direction: one for both, a dict by direction, or None (clean)."""
    if conditions is None:
        return {TO_VEHICLE: LinkConditions(), TO_COMPANION: LinkConditions()}
    if isinstance(conditions, LinkConditions):
        return {TO_VEHICLE: conditions, TO_COMPANION: conditions}
    unknown = set(conditions) - {TO_VEHICLE, TO_COMPANION}
    if unknown:
        raise ValueError(f"link conditions by direction: {TO_VEHICLE} and/or {TO_COMPANION}, not {sorted(unknown)}")
    return {d: conditions.get(d, LinkConditions()) for d in (TO_VEHICLE, TO_COMPANION)}


@dataclass(eq=False)
class _Pipe:
    """One direction of one session: the socket it reads, the socket it writes, their buffers."""

    source: socket.socket
    sink: socket.socket
    direction: str
    conditions: LinkConditions = field(default_factory=LinkConditions)
    pending: bytearray = field(default_factory=bytearray)  # bytes read, not yet a whole frame
    out: bytearray = field(default_factory=bytearray)  # bytes to write to ``sink``
    held: list = field(default_factory=list)  # [release_at_count, release_at_wall, bytes] (delay)
    swap: Frame | None = None  # reorder: the frame that goes after the next one
    swap_until: float = 0.0  # ... or goes anyway at this wall time (nothing followed it)
    swap_partner: Trigger | None = None  # ... the next one this matches (None: any)
    forwarded: int = 0  # frames forwarded in this direction
    paced: collections.deque = field(default_factory=collections.deque)  # (release wall, raw, frame | None)
    bucket: TokenBucket | None = None

    def __post_init__(self) -> None:
        c = self.conditions
        if c.rate_bytes_s is not None:
            self.bucket = TokenBucket(c.rate_bytes_s, c.burst_bytes, c.queue_bytes)

    @property
    def conditioned(self) -> bool:
        return self.bucket is not None or self.conditions.delay_s > 0


@dataclass(eq=False)
class _Session:
    """One companion connection and its upstream connection to the vehicle."""

    companion: socket.socket
    vehicle: socket.socket
    conditions: dict[str, LinkConditions]
    events: dict = field(default_factory=dict)  # role -> selector events registered (0: none)
    up: _Pipe = field(init=False)
    down: _Pipe = field(init=False)

    def __post_init__(self) -> None:
        self.up = _Pipe(self.companion, self.vehicle, TO_VEHICLE, self.conditions[TO_VEHICLE])
        self.down = _Pipe(self.vehicle, self.companion, TO_COMPANION, self.conditions[TO_COMPANION])


# ====================================================================== the proxy
class FaultProxy(ScheduledFaults):
    """The proxy (module docstring). ``with FaultProxy(vehicle_port, seed=3) as proxy:`` …
    ``proxy.endpoint`` is what the companion connects to; :meth:`arm` starts counting triggers
    with a schedule of faults; :meth:`summary` says what fired. ``conditions``: a rate cap and a
    fixed delay, for both directions or by direction (:func:`per_direction`)."""

    transport = "tcp"

    def __init__(self, vehicle_port: int, *, seed: int = 0, host: str = "127.0.0.1", max_faults: int = 64,
                 conditions: LinkConditions | dict[str, LinkConditions] | None = None) -> None:
        self.vehicle_address = (host, vehicle_port)
        self.conditions = per_direction(conditions)
        for direction, condition in self.conditions.items():
            if condition.random:
                raise ValueError(f"the TCP proxy applies a rate cap and a fixed delay only ({direction}: "
                                 f"{condition.describe()}): loss, jitter, reordering and duplication are the "
                                 "UDP relay's (harness.udp_relay), or a fault schedule's")
        self.rng = random.Random(seed)
        self.max_faults = max_faults
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((host, 0))
        self._listener.listen(8)
        self._listener.setblocking(False)
        self.port = self._listener.getsockname()[1]
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ, None)
        self._lock = threading.RLock()  # the loop thread and the caller (arm, summary) share the state
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="fault-proxy", daemon=True)
        self._sessions: list[_Session] = []
        self._faults = FaultSchedule(max_faults, on_closing_cut=self._close_all)
        self._listening = True  # the listener is registered (not during a closing cut)
        self.connections = 0
        self.vehicle_time_ms: int | None = None
        self.delivered = DeliveryLog()  # what left the proxy
        self.received = DeliveryLog()  # what came in, before any fault (what was sent)
        self.rate_dropped = {TO_VEHICLE: 0, TO_COMPANION: 0}  # frames the rate cap's full queue dropped

    # ------------------------------------------------------------------ lifecycle
    @property
    def endpoint(self) -> str:
        """The companion's connection string."""
        return f"tcp:127.0.0.1:{self.port}"

    def start(self) -> "FaultProxy":
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread and close every socket."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        with self._lock:
            for session in list(self._sessions):
                self._close_session(session)
        self._selector.close()
        self._listener.close()

    def __enter__(self) -> "FaultProxy":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ schedule (ScheduledFaults)
    @property
    def frames_seen(self) -> dict[str, int]:
        return self._faults.frames_seen

    @property
    def message_counts(self) -> dict[tuple[str, str], int]:
        return self._faults.message_counts

    def pending(self) -> int:
        """Frames still held, paced or waiting to be written."""
        with self._lock:
            return sum(len(p.held) + (p.swap is not None) + len(p.paced) + bool(p.out)
                       for s in self._sessions for p in (s.up, s.down))

    def drain(self, timeout_s: float = 1.0) -> bool:
        """Wait (at most ``timeout_s``) until nothing is held or in flight; True when so."""
        deadline = time.monotonic() + timeout_s
        while self.pending() and time.monotonic() < deadline and self._thread.is_alive():
            time.sleep(TICK_S)
        return not self.pending()

    def stats(self) -> dict[str, dict]:
        """Per direction: frames delivered and dropped by the rate cap's full queue."""
        with self._lock:
            return {d: {"delivered": self.delivered.frames[d], "rate_dropped": self.rate_dropped[d]}
                    for d in (TO_VEHICLE, TO_COMPANION)}

    # ------------------------------------------------------------------ the loop
    def _loop(self) -> None:
        while not self._stop.is_set():
            for key, events in self._selector.select(TICK_S):
                if key.data is None:
                    self._accept()
                else:
                    self._service(key.data, events)
            with self._lock:
                self._tick(time.monotonic())

    def _accept(self) -> None:
        try:
            companion, _ = self._listener.accept()
        except BlockingIOError:
            return
        try:
            vehicle = socket.create_connection(self.vehicle_address, timeout=5.0)
        except OSError as exc:
            log.warning("fault proxy: vehicle not reachable (%s)", exc)
            companion.close()
            return
        for sock in (companion, vehicle):
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        session = _Session(companion, vehicle, self.conditions)
        with self._lock:
            self._sessions.append(session)
            self.connections += 1
            self._interest(session)
        log.info("fault proxy: companion connected (%d so far)", self.connections)

    def _service(self, side: tuple["_Session", str], events: int) -> None:
        session, role = side
        with self._lock:
            if session not in self._sessions:
                return
            reading = session.up if role == "companion" else session.down
            if events & selectors.EVENT_READ:
                try:
                    data = reading.source.recv(65536)
                except BlockingIOError:
                    data = None
                except OSError:
                    data = b""
                if data == b"":
                    self._close_session(session)
                    return
                if data:
                    self._take(reading, data, time.monotonic())
            self._flush(session)

    def _interest(self, session: "_Session") -> None:
        """Read a socket unless what it feeds is backed up (the vehicle's own flow control then
        holds it back, as on a direct connection); write it while bytes wait for it."""
        if session not in self._sessions:
            return
        for sock, role, reading, writing in ((session.companion, "companion", session.up, session.down),
                                             (session.vehicle, "vehicle", session.down, session.up)):
            events = (selectors.EVENT_READ if len(reading.out) < HIGH_WATER else 0) | \
                (selectors.EVENT_WRITE if writing.out else 0)
            registered = session.events.get(role)
            if events == registered:
                continue
            if registered:
                if events:
                    self._selector.modify(sock, events, (session, role))
                else:
                    self._selector.unregister(sock)
            elif events:
                self._selector.register(sock, events, (session, role))
            session.events[role] = events

    def _take(self, pipe: _Pipe, data: bytes, now: float) -> None:
        pipe.pending += data
        items, pipe.pending = split_frames(pipe.pending)
        for item in items:
            if isinstance(item, Frame):
                self._frame(pipe, item, now)
            else:
                self._egress(pipe, item, None, now)

    # ------------------------------------------------------------------ one frame
    def _frame(self, pipe: _Pipe, frame: Frame, now: float) -> None:
        direction = pipe.direction
        self.received.note(frame, direction, now)
        self._faults.see(frame, direction, now)
        if direction == TO_COMPANION:
            stamp = frame.time_boot_ms()
            if stamp is not None:
                self.vehicle_time_ms = stamp
        if self._faults.silenced(now):
            self._faults.record(self._faults.cut_index(), "cut", direction, frame.name, now)
            return
        fault = self._faults.fault_for(frame, direction, now)
        if fault is None:
            self._forward(pipe, frame.raw, frame)
            return
        kind = fault.fault.kind
        if kind == "drop":
            return
        if kind == "corrupt":
            self._forward(pipe, frame.corrupted(self.rng), None)
        elif kind == "duplicate":
            self._forward(pipe, frame.raw, frame)
            self._forward(pipe, frame.raw, frame)
        elif kind == "delay":
            pipe.held.append([pipe.forwarded + fault.fault.hold_frames, now + fault.fault.max_hold_s, frame])
        elif kind == "reorder":
            if pipe.swap is not None:  # two in a row: the earlier one goes now, after this one
                self._forward(pipe, frame.raw, frame)
                return
            pipe.swap, pipe.swap_until, pipe.swap_partner = frame, now + fault.fault.max_hold_s, fault.fault.partner

    def _forward(self, pipe: _Pipe, raw: bytes, frame: Frame | None) -> None:
        now = time.monotonic()
        self._egress(pipe, raw, frame, now)
        pipe.forwarded += 1
        if pipe.swap is not None and frame is not pipe.swap and (
                pipe.swap_partner is None or (frame is not None and pipe.swap_partner.matches(frame))):
            swapped, pipe.swap = pipe.swap, None
            self._forward(pipe, swapped.raw, swapped)
        self._release_held(pipe, now)

    def _egress(self, pipe: _Pipe, raw: bytes, frame: Frame | None, now: float) -> None:
        """Past the faults: onto the socket, or through the rate cap and the delay first."""
        if not pipe.conditioned:
            self._deliver(pipe, raw, frame, now)
            return
        departure = now if pipe.bucket is None else pipe.bucket.admit(len(raw), now)
        if departure is None:
            self.rate_dropped[pipe.direction] += 1
            return
        pipe.paced.append((departure + pipe.conditions.delay_s, raw, frame))

    def _deliver(self, pipe: _Pipe, raw: bytes, frame: Frame | None, now: float) -> None:
        pipe.out += raw
        if frame is not None:
            self.delivered.note(frame, pipe.direction, now)

    def _release_held(self, pipe: _Pipe, now: float) -> None:
        while pipe.held and (pipe.forwarded >= pipe.held[0][0] or now >= pipe.held[0][1]):
            _count, _wall, frame = pipe.held.pop(0)
            self._forward(pipe, frame.raw, frame)

    def _release_paced(self, pipe: _Pipe, now: float) -> None:
        while pipe.paced and pipe.paced[0][0] <= now:
            _at, raw, frame = pipe.paced.popleft()
            self._deliver(pipe, raw, frame, now)

    # ------------------------------------------------------------------ cuts
    def _close_all(self, _now: float) -> None:
        """A closing cut: every connection closes; new ones wait in the backlog until it ends."""
        for session in list(self._sessions):
            self._close_session(session)
        if self._listening:
            self._selector.unregister(self._listener)
            self._listening = False

    # ------------------------------------------------------------------ housekeeping
    def _tick(self, now: float) -> None:
        self._faults.tick(now)
        if not self._listening and now >= self._faults.cut_until:
            self._selector.register(self._listener, selectors.EVENT_READ, None)
            self._listening = True
        for session in self._sessions:
            for pipe in (session.up, session.down):
                self._release_held(pipe, now)
                if pipe.swap is not None and now >= pipe.swap_until:
                    swapped, pipe.swap = pipe.swap, None  # nothing came after it in time: let it go
                    self._forward(pipe, swapped.raw, swapped)
                self._release_paced(pipe, now)
        for session in list(self._sessions):
            self._flush(session)

    def _flush(self, session: _Session) -> None:
        if session not in self._sessions:
            return
        for pipe in (session.up, session.down):
            if not pipe.out:
                continue
            try:
                sent = pipe.sink.send(pipe.out)
            except BlockingIOError:
                sent = 0
            except OSError:
                self._close_session(session)
                return
            del pipe.out[:sent]
        self._interest(session)

    def _close_session(self, session: _Session) -> None:
        if session not in self._sessions:
            return
        self._sessions.remove(session)
        for sock, role in ((session.companion, "companion"), (session.vehicle, "vehicle")):
            if session.events.get(role):
                self._selector.unregister(sock)
            try:
                sock.close()
            except OSError:
                pass
