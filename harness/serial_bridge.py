"""A serial radio link between the companion and the simulator: a pseudo-terminal pair whose slave the
companion opens as a serial port (``/dev/pts/N,57600``), bridged to the simulator's TCP port through
a radio modem model in each direction (the serial-link test, ``tests/test_serial_link.py``).

The pty's slave is put in raw mode at 57600 baud (termios); the bridge holds the master and, in a
thread of its own, moves bytes between it and one TCP connection to the simulator (``tcpin``), opened
when the companion's first bytes arrive: a serial port is flushed when it is opened (pyserial), so
the simulator's greeting HEARTBEAT would be lost if it came earlier, and a lockstep simulator waiting
at t = 0 sends no other. Each direction is a :class:`RadioDirection`, the model of one half of a pair
of telemetry radios:

1. **the radio's buffer**: bytes enter in chunks of at most ``chunk_bytes`` and wait in a buffer of
   ``buffer_bytes``; a chunk that does not fit is dropped (``bytes_overflow``), as a radio modem
   drops what its buffer cannot hold. They leave it at ``rate_bytes_s`` (5760 B/s: 57600 baud, ten
   bits a byte), through :class:`harness.link_conditions.TokenBucket`;
2. **the air**: a seeded fraction ``byte_loss`` of the bytes is lost (``bytes_lost``), in runs of
   ``loss_burst_bytes`` on average (a radio loses whole air packets: runs uniform in
   1 … 2·mean − 1; 1 loses bytes one by one). Which bytes are lost is a function of the seed, the
   direction and the byte's position in the stream alone (:class:`ByteLoss`), never of timing.

Each direction splits what enters it into MAVLink frames (``harness.mavlink_frames``) and counts the
frames that entered whole (``frames_in``) and those that lost at least one byte (``frames_hit``, and
by message name): the frames the radio spoiled, to compare with what the receiver reports.

Not deterministic: which chunks a full buffer drops depends on when bytes arrive (in lockstep the
simulator sends one attitude period at a time and the buffer rarely fills); how the stream is cut
into chunks depends on the reads. Everything stays on loopback and in this process.
"""
from __future__ import annotations

import collections
import errno
import fcntl
import logging
import math
import os
import random
import selectors
import socket
import termios
import threading
import time
import tty
from dataclasses import dataclass

from harness.fault_schedule import TO_COMPANION, TO_VEHICLE
from harness.link_conditions import TokenBucket
from harness.mavlink_frames import Frame, split_frames

log = logging.getLogger(__name__)

__all__ = ["BAUD", "ByteLoss", "RadioConditions", "RadioDirection", "SerialBridge", "open_serial_pty"]

BAUD = 57600
#: termios speed constants by baud rate
_SPEEDS = {9600: termios.B9600, 19200: termios.B19200, 38400: termios.B38400, 57600: termios.B57600,
           115200: termios.B115200}
MAX_WAIT_S = 0.05  # the loop's longest sleep when nothing is due (wall clock)


@dataclass(frozen=True)
class RadioConditions:
    """One direction of a telemetry radio (module docstring): a byte rate, a buffer that drops what
    does not fit, and bytes lost on the air in runs."""

    rate_bytes_s: float = BAUD / 10.0
    byte_loss: float = 0.0
    loss_burst_bytes: int = 32
    buffer_bytes: int = 2048
    chunk_bytes: int = 64

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_bytes_s) and self.rate_bytes_s > 0):
            raise ValueError(f"RadioConditions.rate_bytes_s must be a finite number > 0, not {self.rate_bytes_s!r}")
        if not 0.0 <= self.byte_loss < 1.0:
            raise ValueError(f"RadioConditions.byte_loss is a fraction in [0, 1), not {self.byte_loss!r}")
        for name in ("loss_burst_bytes", "buffer_bytes", "chunk_bytes"):
            if getattr(self, name) < 1:
                raise ValueError(f"RadioConditions.{name} must be >= 1")

    def describe(self) -> str:
        loss = (f", {100 * self.byte_loss:g} % of bytes lost in runs of {self.loss_burst_bytes} on average"
                if self.byte_loss else "")
        return f"{self.rate_bytes_s:g} B/s, buffer {self.buffer_bytes} B{loss}"


class ByteLoss:
    """Which bytes of one direction's stream the air loses: runs of lost bytes separated by gaps
    drawn from a seeded :class:`random.Random`, by position in the stream (module docstring). The
    gaps are geometric with the mean that makes the lost fraction ``fraction``."""

    def __init__(self, fraction: float, mean_run: int, seed: int) -> None:
        self.fraction = fraction
        self.mean_run = mean_run
        self.rng = random.Random(seed)
        # mean gap G between runs of mean length B: B / (G + B) = fraction; gaps geometric on 0, 1, ...
        self._p = 1.0 / (mean_run * (1.0 - fraction) / fraction + 1.0) if fraction > 0 else 0.0
        self._position = 0  # the next byte's position
        self._run_start = self._run_end = -1  # [start, end) of the next (or current) run
        if fraction > 0:
            self._draw_run(0)

    def _draw_run(self, after: int) -> None:
        u = self.rng.random()
        gap = int(math.floor(math.log(1.0 - u) / math.log(1.0 - self._p))) if self._p < 1.0 else 0
        length = self.rng.randint(1, 2 * self.mean_run - 1)
        self._run_start = after + gap
        self._run_end = self._run_start + length

    def mask(self, size: int) -> bytearray:
        """1 for each of the next ``size`` bytes that is lost, 0 for each that goes through."""
        out = bytearray(size)
        if self.fraction <= 0:
            self._position += size
            return out
        start, end = self._position, self._position + size
        while self._run_start < end:
            lo, hi = max(self._run_start, start), min(self._run_end, end)
            if hi > lo:
                out[lo - start:hi - start] = b"\x01" * (hi - lo)
            if self._run_end > end:
                break
            self._draw_run(self._run_end)
        self._position = end
        return out


class RadioDirection:
    """One direction of the radio (module docstring): :meth:`take` what arrives, :meth:`release` what
    has crossed by a given time. Pure: no I/O, time is passed in."""

    def __init__(self, name: str, conditions: RadioConditions, seed: int) -> None:
        self.name = name
        self.conditions = conditions
        self.loss = ByteLoss(conditions.byte_loss, conditions.loss_burst_bytes, seed)
        self.bucket = TokenBucket(conditions.rate_bytes_s, conditions.chunk_bytes, conditions.buffer_bytes)
        self._air: collections.deque[tuple[float, bytes]] = collections.deque()  # (arrival, bytes kept)
        self._pending = bytearray()  # bytes not yet split into whole frames, with ...
        self._pending_mask = bytearray()  # ... 1 where the byte did not get through
        self.counts: dict[str, int] = {"bytes_in": 0, "bytes_overflow": 0, "bytes_lost": 0, "bytes_delivered": 0,
                                       "frames_in": 0, "frames_hit": 0}
        self.hit_by_name: collections.Counter[str] = collections.Counter()

    def take(self, data: bytes, now: float) -> None:
        """Bytes arriving from the sender at ``now``: through the buffer and onto the air."""
        self.counts["bytes_in"] += len(data)
        lost = self.loss.mask(len(data))
        dropped = bytearray(lost)
        step = self.conditions.chunk_bytes
        for offset in range(0, len(data), step):
            chunk, chunk_lost = data[offset:offset + step], lost[offset:offset + step]
            departure = self.bucket.admit(len(chunk), now)
            if departure is None:  # the buffer is full: the whole chunk is dropped
                self.counts["bytes_overflow"] += len(chunk)
                dropped[offset:offset + len(chunk)] = b"\x01" * len(chunk)
                continue
            self.counts["bytes_lost"] += sum(chunk_lost)
            kept = bytes(b for b, gone in zip(chunk, chunk_lost) if not gone)
            self._air.append((departure + len(chunk) / self.conditions.rate_bytes_s, kept))
        self._count_frames(data, dropped)

    def _count_frames(self, data: bytes, dropped: bytearray) -> None:
        self._pending += data
        self._pending_mask += dropped
        items, rest = split_frames(self._pending)
        consumed = len(self._pending) - len(rest)
        position = 0
        for item in items:
            size = len(item.raw) if isinstance(item, Frame) else len(item)
            if isinstance(item, Frame):
                self.counts["frames_in"] += 1
                if any(self._pending_mask[position:position + size]):
                    self.counts["frames_hit"] += 1
                    self.hit_by_name[item.name] += 1
            position += size
        del self._pending[:consumed]
        del self._pending_mask[:consumed]

    def next_release(self) -> float | None:
        """When the next bytes reach the far end (None: nothing on the air)."""
        return self._air[0][0] if self._air else None

    def release(self, now: float) -> bytes:
        """The bytes that have reached the far end by ``now``, in order."""
        out = bytearray()
        while self._air and self._air[0][0] <= now:
            out += self._air.popleft()[1]
        self.counts["bytes_delivered"] += len(out)
        return bytes(out)

    def stats(self) -> dict:
        """The counts, the fraction of bytes dropped (overflow and air) and the frames hit by name."""
        counts = dict(self.counts)
        dropped = counts["bytes_overflow"] + counts["bytes_lost"]
        counts["bytes_dropped"] = dropped
        counts["byte_drop_fraction"] = dropped / counts["bytes_in"] if counts["bytes_in"] else 0.0
        counts["frame_hit_fraction"] = counts["frames_hit"] / counts["frames_in"] if counts["frames_in"] else 0.0
        counts["frames_hit_by_name"] = dict(self.hit_by_name)
        return counts


def open_serial_pty(baud: int = BAUD) -> tuple[int, int, str]:
    """A pseudo-terminal pair, the slave raw at ``baud``: (master fd, slave fd, slave path)."""
    if baud not in _SPEEDS:
        raise ValueError(f"baud rate {baud} is not one of {sorted(_SPEEDS)}")
    master, slave = os.openpty()
    tty.setraw(slave)
    attrs = termios.tcgetattr(slave)
    attrs[4] = attrs[5] = _SPEEDS[baud]  # ispeed, ospeed
    termios.tcsetattr(slave, termios.TCSANOW, attrs)
    flags = fcntl.fcntl(master, fcntl.F_GETFL)
    fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
    return master, slave, os.ttyname(slave)


class SerialBridge:
    """The pty pair bridged to the simulator's TCP port through a radio each way (module docstring).
    ``with SerialBridge(sim.port, conditions=RadioConditions(byte_loss=0.02), seed=1) as bridge:`` …
    the companion connects ``bridge.endpoint``; :meth:`stats` says what each direction dropped.
    ``conditions``: one for both directions or a dict by direction (``to_vehicle``, ``to_companion``)."""

    def __init__(self, vehicle_port: int, *, conditions: RadioConditions | dict[str, RadioConditions] | None = None,
                 seed: int = 0, host: str = "127.0.0.1", baud: int = BAUD) -> None:
        by_direction = conditions if isinstance(conditions, dict) else {
            TO_VEHICLE: conditions or RadioConditions(), TO_COMPANION: conditions or RadioConditions()}
        unknown = set(by_direction) - {TO_VEHICLE, TO_COMPANION}
        if unknown:
            raise ValueError(f"radio conditions by direction: {TO_VEHICLE} and/or {TO_COMPANION}, "
                             f"not {sorted(unknown)}")
        self.baud = baud
        self.vehicle_address = (host, vehicle_port)
        # one seed per direction, so the bytes lost in one do not depend on the other's traffic
        self.up = RadioDirection(TO_VEHICLE, by_direction.get(TO_VEHICLE, RadioConditions()), seed * 2 + 1)
        self.down = RadioDirection(TO_COMPANION, by_direction.get(TO_COMPANION, RadioConditions()), seed * 2 + 2)
        self.master_fd = self.slave_fd = -1
        self.device = ""
        self._sock: socket.socket | None = None
        self._to_vehicle = bytearray()  # released by the radio, not yet written to the socket
        self._to_pty = bytearray()  # released by the radio, not yet written to the pty
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="serial-bridge", daemon=True)
        self.vehicle_closed = False

    # ------------------------------------------------------------------ lifecycle
    @property
    def endpoint(self) -> str:
        """The companion's connection string: the pty's slave and the baud rate."""
        return f"{self.device},{self.baud}"

    def start(self) -> "SerialBridge":
        """Open the pty pair and start the thread (the simulator is connected at the companion's
        first bytes)."""
        self.master_fd, self.slave_fd, self.device = open_serial_pty(self.baud)
        self._thread.start()
        log.info("serial bridge %s <-> %s:%d (%s up, %s down)", self.device, *self.vehicle_address,
                 self.up.conditions.describe(), self.down.conditions.describe())
        return self

    def close(self) -> None:
        """Stop the thread, close the connection and the pty pair."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        self._close_fds()

    def _close_fds(self) -> None:
        for fd in (self.master_fd, self.slave_fd):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.master_fd = self.slave_fd = -1

    def __enter__(self) -> "SerialBridge":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def stats(self) -> dict[str, dict]:
        """Per direction: bytes in, dropped by the full buffer and lost on the air, delivered; frames
        in and frames that lost a byte (:meth:`RadioDirection.stats`)."""
        with self._lock:
            return {TO_VEHICLE: self.up.stats(), TO_COMPANION: self.down.stats()}

    # ------------------------------------------------------------------ the loop
    def _loop(self) -> None:
        selector = selectors.DefaultSelector()
        selector.register(self.master_fd, selectors.EVENT_READ, "pty")
        try:
            while not self._stop.is_set():
                for key, _ in selector.select(self._sleep(time.monotonic())):
                    if key.data == "pty":
                        self._read_pty()
                    elif not self._read_vehicle():
                        selector.unregister(self._sock)
                if self._sock is None and self.up.counts["bytes_in"] and not self.vehicle_closed:
                    self._connect(selector)
                with self._lock:
                    now = time.monotonic()
                    self._to_vehicle += self.up.release(now)
                    self._to_pty += self.down.release(now)
                self._flush()
        finally:
            selector.close()

    def _sleep(self, now: float) -> float:
        with self._lock:
            due = [t for t in (self.up.next_release(), self.down.next_release()) if t is not None]
        if self._to_pty or (self._to_vehicle and self._sock is not None and not self.vehicle_closed):
            return 0.002  # a write was refused: try again soon
        return min([MAX_WAIT_S] + [max(t - now, 0.0) for t in due])

    def _connect(self, selector: selectors.BaseSelector) -> None:
        """The companion spoke: connect to the simulator (which greets with a HEARTBEAT)."""
        try:
            sock = socket.create_connection(self.vehicle_address, timeout=5.0)
        except OSError as exc:
            log.warning("serial bridge: the simulator is not reachable (%s)", exc)
            self.vehicle_closed = True
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        selector.register(sock, selectors.EVENT_READ, "vehicle")
        log.info("serial bridge: the companion spoke, connected to the simulator")

    def _read_pty(self) -> None:
        try:
            data = os.read(self.master_fd, 4096)
        except BlockingIOError:
            return
        except OSError as exc:  # EIO: no slave open (we hold one, so only while closing)
            if exc.errno != errno.EIO:
                raise
            return
        if data:
            with self._lock:
                self.up.take(data, time.monotonic())

    def _read_vehicle(self) -> bool:
        """Read the simulator's bytes; False once it closed the connection."""
        try:
            data = self._sock.recv(65536)
        except BlockingIOError:
            return True
        except OSError as exc:
            log.warning("serial bridge: the simulator's connection failed (%s)", exc)
            data = b""
        if not data:
            self.vehicle_closed = True
            log.warning("serial bridge: the simulator closed the connection")
            return False
        with self._lock:
            self.down.take(data, time.monotonic())
        return True

    def _flush(self) -> None:
        if self._to_pty:
            try:
                written = os.write(self.master_fd, self._to_pty)
            except BlockingIOError:  # the companion is not reading: the bytes wait (the tty's buffer is full)
                written = 0
            del self._to_pty[:written]
        if self._to_vehicle and self._sock is not None and not self.vehicle_closed:
            try:
                sent = self._sock.send(self._to_vehicle)
            except BlockingIOError:
                sent = 0
            except OSError:
                self.vehicle_closed = True
                return
            del self._to_vehicle[:sent]


def add_radio_arguments(parser) -> None:
    """A bench's radio options: ``--loss``, ``--burst`` and ``--seeds`` (see :func:`radio_from`)."""
    parser.add_argument("--loss", type=float, default=0.02, help="fraction of bytes lost on the air (default 0.02)")
    parser.add_argument("--burst", type=int, default=32, help="mean run of bytes lost together (1: one by one)")
    parser.add_argument("--seeds", default="1,2,3", help="radio seeds, comma-separated (default 1,2,3)")


def radio_from(args) -> tuple[RadioConditions, list[int]]:
    """The radio each way at 57600 baud with the options of :func:`add_radio_arguments`, and the seeds."""
    conditions = RadioConditions(rate_bytes_s=BAUD / 10.0, byte_loss=args.loss, loss_burst_bytes=args.burst)
    return conditions, [int(s) for s in args.seeds.split(",") if s.strip()]
