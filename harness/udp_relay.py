"""A user-space UDP relay on loopback that puts a lossy, jittery, rate-capped link between the
companion and the vehicle, and the fault proxy's triggered faults on top (``netem`` without root).

Topology: the simulator listens ``udpin:127.0.0.1:<sim port>`` and answers the last addresses that
sent to it; the relay binds a loopback port of its own (port 0: the OS picks it) and the companion
connects ``udpout:127.0.0.1:<relay port>`` (:attr:`UdpRelay.endpoint`). What the companion sends
goes to the simulator from the relay's upstream socket; what the simulator sends goes to the last
address the companion sent from. Everything runs in one thread, every queue is bounded.

Each datagram, in order:

1. **triggered faults, on frames** (``harness.fault_schedule``; a datagram may hold several MAVLink
   frames): ``drop`` removes the frame, ``corrupt`` flips one of its bytes, ``duplicate`` repeats it,
   ``delay`` holds it until ``hold_frames`` later frames of its direction passed or ``max_hold_s``
   went by (:func:`harness.fault_schedule.timed_delay`: wall time only; the held frame then travels
   as a datagram of its own), ``reorder`` swaps it with the next frame (or goes right after the next frame its ``partner``
   matches), a ``cut`` drops every frame
   for ``cut_s`` (over UDP there is no connection to close: a closing cut is silent too);
2. **link conditions, on whole datagrams** (``harness.link_conditions``, per direction): loss, the
   rate cap's bounded queue (excess dropped), then delay + jitter; datagrams are delivered in the
   order of their delivery times, so jitter above the interval between datagrams reorders them;
   explicit reordering holds a datagram until the next one was delivered; duplication delivers it
   twice.

What was delivered is recorded (``harness.delivery_log``: the RC overrides and COMMAND_LONGs the
vehicle last received, ATTITUDE samples out of vehicle-time order; what was sent, before any fault,
likewise in :attr:`UdpRelay.received`) and counted per direction
(:meth:`UdpRelay.stats`: datagrams received, delivered, lost, dropped by the rate cap, duplicated,
delivered out of arrival order, ATTITUDE samples lost).

Deterministic: the fate of the k-th datagram a direction hands to the link stage (lost,
duplicated, reordered, its delay; a frame released by a triggered delay or reorder counts as one
more) is a function of the seed, the direction and k (``FateDraws``); a triggered fault starts at
the same frame of the companion's traffic; the rate cap's departure times follow from arrival times.
Each datagram is timed from its arrival in the kernel (``SO_TIMESTAMPNS``), not from when the relay
happened to read it, so a relay descheduled for a while on a busy machine does not add its own delay
or turn its backlog into reordering (the longest such lag is reported: ``max_read_lag_ms``).
**Not deterministic**: arrival times themselves (the simulator's pacing and the OS's scheduling of
three processes), hence which frames share the k-th datagram of the companion's direction, whether a
jittered datagram overtakes its neighbour (it depends on their wall-clock spacing), which datagrams
the rate cap drops, when a wall-time hold or window ends, and the wake-up latency of this thread
(sub-millisecond on an idle machine; a few ms under load or when the process holding the relay is
busy in Python: the GIL; :mod:`harness.relay_process` runs the relay in a process of its own). Nothing
on the loopback itself loses datagrams unless a receive buffer overflows (the relay asks for 4 MB
buffers; :meth:`UdpRelay.socket_drops` counts what the kernel dropped at each socket on the way).
"""
from __future__ import annotations

import collections
import heapq
import itertools
import logging
import random
import selectors
import socket
import struct
import threading
import time
from dataclasses import dataclass, field

from harness.delivery_log import DeliveryLog
from harness.fault_proxy import per_direction
from harness.fault_schedule import TO_COMPANION, TO_VEHICLE, FaultSchedule, ScheduledFaults, Trigger
from harness.link_conditions import FateDraws, LinkConditions, TokenBucket
from harness.mavlink_frames import Frame, split_datagram

log = logging.getLogger(__name__)

__all__ = ["LinkConditions", "UdpRelay"]

TICK_S = 0.002  # the loop's longest sleep (held frames, swaps, window ends), wall clock
READS_PER_WAKE = 256  # datagrams read from one socket per wake-up (bounded)
MAX_SCHEDULED = 20000  # datagrams waiting for their delivery time, both directions (bounded)
SOCKET_BUFFER = 4 * 1024 * 1024
TRACE_MAX = 20000  # planned deliveries kept with ``trace`` (bounded)
#: the kernel's arrival time of each datagram (Linux; elsewhere the time it was read is used)
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35 if hasattr(socket, "SO_REUSEPORT") else None)
MAX_READ_LAG_S = 30.0  # an arrival time further back than this is not believed (a step of the wall clock)


@dataclass(order=True)
class _Due:
    """A datagram waiting for its delivery time."""

    at: float
    order: int
    direction: str = field(compare=False)
    index: int = field(compare=False)  # its arrival number in its direction
    data: bytes = field(compare=False)


@dataclass(eq=False)
class _Direction:
    """One direction of the relay: its conditions, its draws, its holds and its counters."""

    name: str
    conditions: LinkConditions
    draws: FateDraws
    bucket: TokenBucket | None = None
    held: list = field(default_factory=list)  # triggered delay: [release count, release wall, index, frame]
    swap: Frame | None = None  # triggered reorder: the frame that goes after the next one
    swap_until: float = 0.0
    swap_partner: Trigger | None = None  # ... the next one this matches (None: any)
    link_swap: list = field(default_factory=list)  # link reorder: [until, index, data], after the next delivery
    forwarded: int = 0  # frames past the triggered faults
    arrived: int = 0  # datagrams received
    highest_delivered: int = -1
    counts: dict = field(default_factory=lambda: dict.fromkeys(
        ("received", "delivered", "lost", "rate_dropped", "duplicated", "reordered", "out_of_order",
         "attitude_lost", "bytes_delivered", "unroutable", "max_read_lag_ms"), 0))
    first_delivery: float | None = None
    last_delivery: float | None = None

    def __post_init__(self) -> None:
        c = self.conditions
        if c.rate_bytes_s is not None:
            self.bucket = TokenBucket(c.rate_bytes_s, c.burst_bytes, c.queue_bytes)


class UdpRelay(ScheduledFaults):
    """The relay (module docstring). ``with UdpRelay(sim.port, seed=3, conditions=LinkConditions(
    loss=0.02)) as relay:`` … the companion connects to ``relay.endpoint``; :meth:`arm` starts a
    schedule of triggered faults as on the TCP proxy; :meth:`stats` says what the link did."""

    transport = "udp"

    def __init__(self, vehicle_port: int, *, seed: int = 0, host: str = "127.0.0.1", max_faults: int = 64,
                 conditions: LinkConditions | dict[str, LinkConditions] | None = None, trace: bool = False) -> None:
        self.vehicle_address = (host, vehicle_port)
        self.conditions = per_direction(conditions)
        self.rng = random.Random(seed)  # the byte a corruption flips
        self._directions = {name: _Direction(name, c, FateDraws(c, seed * 2 + number))
                            for number, (name, c) in enumerate(self.conditions.items())}
        self._companion_side = self._socket(host)
        self._vehicle_side = self._socket(host)
        self.port = self._companion_side.getsockname()[1]
        self._vehicle_port = self._vehicle_side.getsockname()[1]
        self.companion_address: tuple[str, int] | None = None  # the last address the companion sent from
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._companion_side, selectors.EVENT_READ, TO_VEHICLE)
        self._selector.register(self._vehicle_side, selectors.EVENT_READ, TO_COMPANION)
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="udp-relay", daemon=True)
        self._faults = FaultSchedule(max_faults)  # no on_closing_cut: a UDP cut is silent
        self._due: list[_Due] = []
        self._order = itertools.count()
        self.delivered = DeliveryLog()  # what left the relay
        self.received = DeliveryLog()  # what came in, before any fault or condition (what was sent)
        self.vehicle_time_ms: int | None = None
        self.connections = 0  # companion addresses seen (a new source port is a new "connection")
        self.kernel_drops: dict[str, int] = {}  # socket_drops() when the relay closed
        #: with ``trace``: (direction, arrival number, arrival, planned delivery) of each datagram past
        #: the loss and the rate cap, monotonic clock (what the link meant to do, whatever the scheduling)
        self.planned: collections.deque | None = collections.deque(maxlen=TRACE_MAX) if trace else None
        self._closed = False

    @staticmethod
    def _socket(host: str) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for option in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, option, SOCKET_BUFFER)
            except OSError:
                pass  # the kernel's limit applies
        if SO_TIMESTAMPNS is not None:
            try:
                sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            except OSError:
                pass  # then the time a datagram is read stands for its arrival
        sock.bind((host, 0))
        sock.setblocking(False)
        return sock

    # ------------------------------------------------------------------ lifecycle
    @property
    def endpoint(self) -> str:
        """The companion's connection string."""
        return f"udpout:127.0.0.1:{self.port}"

    def start(self) -> "UdpRelay":
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread and close both sockets (what was still in flight is lost); the kernel's
        drop counts of the sockets on the way are kept (:attr:`kernel_drops`)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        self.kernel_drops = self.socket_drops()
        self._selector.close()
        self._companion_side.close()
        self._vehicle_side.close()

    def __enter__(self) -> "UdpRelay":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ schedule (ScheduledFaults)
    def acks(self) -> list[tuple[float, int, int]]:
        """The COMMAND_ACKs delivered to the companion: (wall, command, result)."""
        with self._lock:
            return list(self.delivered.acks)

    def pending(self) -> int:
        """Datagrams and frames still held or in flight."""
        with self._lock:
            return len(self._due) + sum(len(d.held) + len(d.link_swap) + (d.swap is not None)
                                        for d in self._directions.values())

    def drain(self, timeout_s: float = 1.0) -> bool:
        """Wait (at most ``timeout_s``) until nothing is held or in flight; True when so."""
        deadline = time.monotonic() + timeout_s
        while self.pending() and time.monotonic() < deadline and self._thread.is_alive():
            time.sleep(TICK_S)
        return not self.pending()

    def socket_drops(self) -> dict[str, int]:
        """Datagrams the kernel dropped at each loopback socket on the way because its receive buffer
        was full (Linux: /proc/net/udp; {} elsewhere): the relay's two, the companion's, the vehicle's.
        Such losses happen before the relay sees a datagram, so they are not in :meth:`stats`."""
        ports = {"relay companion side": self.port, "relay vehicle side": self._vehicle_port,
                 "vehicle": self.vehicle_address[1]}
        if self.companion_address is not None:
            ports["companion"] = self.companion_address[1]
        return _udp_drops(ports)

    def stats(self) -> dict[str, dict]:
        """Per direction: datagrams received, delivered, lost, dropped by the rate cap, duplicated,
        reordered on purpose, delivered out of arrival order, ATTITUDE frames lost; bytes delivered
        and the delivery rate (bytes/s between the first and the last delivery)."""
        with self._lock:
            out = {}
            for name, d in self._directions.items():
                counts = dict(d.counts)
                span = (d.last_delivery or 0.0) - (d.first_delivery or 0.0)
                counts["rate_bytes_s"] = counts["bytes_delivered"] / span if span > 0 else None
                out[name] = counts
            out[TO_COMPANION]["attitude_delivered"] = self.delivered.attitude_delivered
            out[TO_COMPANION]["attitude_out_of_order"] = self.delivered.attitude_out_of_order
        out["kernel_drops"] = self.kernel_drops if self._stop.is_set() else self.socket_drops()
        out["companion_addresses"] = self.connections
        return out

    # ------------------------------------------------------------------ the loop
    def _loop(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                timeout = self._sleep(time.monotonic())
            for key, _ in self._selector.select(timeout):
                self._read(key.fileobj, key.data)
            with self._lock:
                self._tick(time.monotonic())

    def _sleep(self, now: float) -> float:
        if self._due:
            return max(0.0, min(TICK_S, self._due[0].at - now))
        return TICK_S

    def _read(self, sock: socket.socket, direction: str) -> None:
        """Read what arrived; each datagram is timed by its arrival in the kernel, so that a relay
        read late (a busy machine) still delays and jitters each datagram from when it arrived. One
        offset between the two clocks per batch keeps the kernel's order exactly."""
        offset = time.time() - time.monotonic()
        for _ in range(READS_PER_WAKE):
            try:
                data, ancillary, _flags, sender = sock.recvmsg(65535, 64)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. ECONNREFUSED for an earlier datagram to a closed port
                log.debug("udp relay: receive on the %s side failed: %s", direction, exc)
                return
            arrival, lag = _arrival(ancillary, offset)
            with self._lock:
                if direction == TO_VEHICLE and sender != self.companion_address:
                    self.companion_address = sender
                    self.connections += 1
                d = self._directions[direction]
                d.counts["max_read_lag_ms"] = max(d.counts["max_read_lag_ms"], round(lag * 1000.0, 1))
                self._datagram(d, data, arrival)

    # ------------------------------------------------------------------ one datagram: faults on frames
    def _datagram(self, d: _Direction, data: bytes, now: float) -> None:
        index = d.arrived
        d.arrived += 1
        d.counts["received"] += 1
        out = bytearray()
        for item in split_datagram(data):
            if isinstance(item, Frame):
                self._frame(d, item, index, out, now)
            else:
                out += item
        if out:
            self._link(d, bytes(out), index, now)

    def _frame(self, d: _Direction, frame: Frame, index: int, out: bytearray, now: float) -> None:
        self.received.note(frame, d.name, now)
        self._faults.see(frame, d.name, now)
        if d.name == TO_COMPANION:
            stamp = frame.time_boot_ms()
            if stamp is not None:
                self.vehicle_time_ms = stamp
        if self._faults.silenced(now):
            self._faults.record(self._faults.cut_index(), "cut", d.name, frame.name, now)
            return
        fault = self._faults.fault_for(frame, d.name, now)
        if fault is None:
            self._emit(d, frame.raw, out, now, frame)
            return
        kind = fault.fault.kind
        if kind == "corrupt":
            self._emit(d, frame.corrupted(self.rng), out, now)
        elif kind == "duplicate":
            self._emit(d, frame.raw, out, now, frame)
            self._emit(d, frame.raw, out, now, frame)
        elif kind == "delay":
            d.held.append([d.forwarded + fault.fault.hold_frames, now + fault.fault.max_hold_s, index, frame])
        elif kind == "reorder":
            if d.swap is not None:  # two in a row: the earlier one goes now, after this one
                self._emit(d, frame.raw, out, now, frame)
                return
            d.swap, d.swap_until, d.swap_partner = frame, now + fault.fault.max_hold_s, fault.fault.partner
        # drop: nothing goes

    def _emit(self, d: _Direction, raw: bytes, out: bytearray, now: float, frame: Frame | None = None) -> None:
        """A frame past the faults joins the datagram being built; a swapped frame follows it (the
        partner it waits for, if it has one), and frames held for a count of frames join it when
        their count is reached."""
        out += raw
        d.forwarded += 1
        if d.swap is not None and (d.swap_partner is None or (frame is not None and d.swap_partner.matches(frame))):
            swapped, d.swap = d.swap, None
            self._emit(d, swapped.raw, out, now, swapped)
        while d.held and d.forwarded >= d.held[0][0]:
            held = d.held.pop(0)[3]
            self._emit(d, held.raw, out, now, held)

    # ------------------------------------------------------------------ one datagram: the link
    def _link(self, d: _Direction, data: bytes, index: int, now: float) -> None:
        fate = d.draws.next()
        if fate.lost:
            d.counts["lost"] += 1
            d.counts["attitude_lost"] += _attitudes(data, d.name)
            return
        departure = now if d.bucket is None else d.bucket.admit(len(data), now)
        if departure is None:
            d.counts["rate_dropped"] += 1
            d.counts["attitude_lost"] += _attitudes(data, d.name)
            return
        at = departure + fate.delay_s
        if self.planned is not None:
            self.planned.append((d.name, index, now, at))
        if fate.reorder:
            d.counts["reordered"] += 1
            d.link_swap.append([at + d.conditions.reorder_max_s, index, data])
            return
        self._schedule(d, at, index, data)
        if fate.duplicate:
            d.counts["duplicated"] += 1
            self._schedule(d, at, index, data)

    def _schedule(self, d: _Direction, at: float, index: int, data: bytes) -> None:
        if len(self._due) >= MAX_SCHEDULED:
            d.counts["lost"] += 1  # bounded: a link this far behind loses what does not fit
            return
        heapq.heappush(self._due, _Due(at, next(self._order), d.name, index, data))

    # ------------------------------------------------------------------ delivery
    def _tick(self, now: float) -> None:
        self._faults.tick(now)
        for d in self._directions.values():
            if d.swap is not None and now >= d.swap_until:  # nothing came after it in time
                out = bytearray()
                swapped, d.swap = d.swap, None
                self._emit(d, swapped.raw, out, now, swapped)
                self._link(d, bytes(out), d.arrived - 1, now)
            while d.held and now >= d.held[0][1]:  # held in wall time: goes as a datagram of its own
                _count, _wall, index, frame = d.held.pop(0)
                out = bytearray()
                self._emit(d, frame.raw, out, now, frame)
                self._link(d, bytes(out), index, now)
            for entry in [e for e in d.link_swap if now >= e[0]]:  # nothing followed it in time
                d.link_swap.remove(entry)
                self._deliver(d, entry[2], entry[1], now)
        while self._due and self._due[0].at <= now:
            due = heapq.heappop(self._due)
            d = self._directions[due.direction]
            self._deliver(d, due.data, due.index, now)
            while d.link_swap:  # held back on purpose: it goes after this one
                _until, index, data = d.link_swap.pop(0)
                self._deliver(d, data, index, now)

    def _deliver(self, d: _Direction, data: bytes, index: int, now: float) -> None:
        if d.name == TO_VEHICLE:
            sock, address = self._vehicle_side, self.vehicle_address
        else:
            sock, address = self._companion_side, self.companion_address
        if address is None:
            d.counts["unroutable"] += 1
            return
        try:
            sock.sendto(data, address)
        except OSError as exc:  # the peer's port closed (ECONNREFUSED) or a full buffer: lost
            log.debug("udp relay: send %s failed: %s", d.name, exc)
            d.counts["lost"] += 1
            return
        d.counts["delivered"] += 1
        d.counts["bytes_delivered"] += len(data)
        if d.first_delivery is None:
            d.first_delivery = now
        d.last_delivery = now
        if index < d.highest_delivered:
            d.counts["out_of_order"] += 1
        else:
            d.highest_delivered = index
        for item in split_datagram(data):
            if isinstance(item, Frame):
                self.delivered.note(item, d.name, now)


def _arrival(ancillary: list, offset: float) -> tuple[float, float]:
    """(arrival on the monotonic clock, how long before now) from a datagram's SO_TIMESTAMPNS
    (``offset``: the wall clock minus the monotonic one); now when there is none."""
    now = time.monotonic()
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= 16:
            seconds, nanoseconds = struct.unpack_from("qq", data)
            arrival = seconds + nanoseconds * 1e-9 - offset
            lag = now - arrival
            if -0.001 <= lag <= MAX_READ_LAG_S:
                return min(arrival, now), max(lag, 0.0)
    return now, 0.0


def _udp_drops(ports: dict[str, int]) -> dict[str, int]:
    """The ``drops`` column of /proc/net/udp for the sockets bound to ``ports`` (by name) on loopback
    or on any address (an unbound ``udpout:`` socket is bound to 0.0.0.0 by its first send)."""
    wanted = {f"{host}:{port:04X}": name for name, port in ports.items() for host in ("0100007F", "00000000")}
    found: dict[str, int] = {}
    try:
        with open("/proc/net/udp", encoding="ascii") as table:
            next(table, None)
            for line in table:
                fields = line.split()
                if len(fields) > 12 and fields[1] in wanted:
                    found[wanted[fields[1]]] = found.get(wanted[fields[1]], 0) + int(fields[-1])
    except (OSError, ValueError):
        return {}
    return found


def _attitudes(data: bytes, direction: str) -> int:
    """ATTITUDE frames in a datagram travelling to the companion (what a lost one costs the estimator)."""
    if direction != TO_COMPANION:
        return 0
    return sum(1 for item in split_datagram(data) if isinstance(item, Frame) and item.name == "ATTITUDE")
