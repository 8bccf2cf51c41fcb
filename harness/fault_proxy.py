"""A MAVLink-aware TCP proxy that injects link faults between the companion and the vehicle
(the fault-injection suite).

The proxy listens on a loopback port (bound to port 0: the OS picks it) and opens one upstream TCP
connection to the vehicle (the simulator's ``tcpin`` port) for each companion that connects. It
runs in its own thread, splits both byte streams into whole MAVLink frames (v2 on magic 0xFD, v1 on
0xFE, the length byte and the signature flag; no full decode on the hot path) and forwards them,
except where a :class:`Fault` is active:

``drop``       the frame is not forwarded;
``delay``      the frame is held until ``hold_frames`` later frames of the same direction have
               passed (a delay in stream position, deterministic on a lockstep link), or at most
               ``max_hold_s`` of wall clock;
``duplicate``  the frame is forwarded twice;
``reorder``    the frame swaps places with the next frame of the same direction (or goes after
               ``max_hold_s`` if none follows);
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

The proxy also keeps what the vehicle was told: the last RC override value *delivered* on each
channel (:meth:`FaultProxy.held_overrides`), and the vehicle time of the latest sample it saw.
Everything stays on loopback; the proxy never decodes more than a few header and payload fields.
"""
from __future__ import annotations

import logging
import random
import selectors
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Iterable

log = logging.getLogger(__name__)

__all__ = ["FAULT_KINDS", "Fault", "FaultEvent", "FaultProxy", "Frame", "Trigger", "split_frames"]

FAULT_KINDS = ("drop", "delay", "duplicate", "reorder", "corrupt", "cut")
TO_VEHICLE = "to_vehicle"
TO_COMPANION = "to_companion"
BOTH = "both"

MAGIC_V2, MAGIC_V1 = 0xFD, 0xFE
V2_OVERHEAD, V1_OVERHEAD, SIGNATURE_LEN = 12, 8, 13
INCOMPAT_SIGNED = 0x01

#: message ids the proxy looks into (common dialect numbers)
MESSAGE_IDS = {"HEARTBEAT": 0, "SYSTEM_TIME": 2, "SET_MODE": 11, "PARAM_REQUEST_READ": 20, "PARAM_VALUE": 22,
               "PARAM_SET": 23, "ATTITUDE": 30, "SERVO_OUTPUT_RAW": 36, "RC_CHANNELS_OVERRIDE": 70,
               "COMMAND_LONG": 76, "COMMAND_ACK": 77, "SET_ATTITUDE_TARGET": 82, "STATUSTEXT": 253}
MESSAGE_NAMES = {number: name for name, number in MESSAGE_IDS.items()}
#: full (untruncated) payload lengths of the messages whose fields are read
PAYLOAD_LENGTHS = {"COMMAND_LONG": 33, "PARAM_SET": 23, "RC_CHANNELS_OVERRIDE": 38, "STATUSTEXT": 54,
                   "ATTITUDE": 28, "SYSTEM_TIME": 12}
RC_RELEASE_LOW, RC_IGNORE_LOW, RC_RELEASE_HIGH = 0, 65535, 65534
#: bytes queued for one side before the proxy stops reading the other (back-pressure: the vehicle's
#: own flow control then holds it back, so a slow companion lags no more than on a direct link)
HIGH_WATER = 16 * 1024
TICK_S = 0.005  # the loop's housekeeping period (held frames, cut ends), wall clock


# ====================================================================== frames
@dataclass(frozen=True)
class Frame:
    """One whole MAVLink frame as it travels, with the few header fields the proxy needs."""

    raw: bytes
    msgid: int
    header_len: int  # bytes before the payload
    payload_len: int

    @property
    def name(self) -> str:
        return MESSAGE_NAMES.get(self.msgid, f"MSG_{self.msgid}")

    def payload(self) -> bytes:
        """The payload, zero-padded to its full length (MAVLink 2 truncates trailing zeros)."""
        body = self.raw[self.header_len:self.header_len + self.payload_len]
        full = PAYLOAD_LENGTHS.get(self.name, len(body))
        return body + bytes(max(0, full - len(body)))

    def command(self) -> int | None:
        """COMMAND_LONG's command id (None for other messages)."""
        return struct.unpack_from("<H", self.payload(), 28)[0] if self.name == "COMMAND_LONG" else None

    def param_id(self) -> str | None:
        """PARAM_SET's parameter name (None for other messages)."""
        if self.name != "PARAM_SET":
            return None
        return self.payload()[6:22].split(b"\x00", 1)[0].decode("ascii", "replace")

    def text(self) -> str | None:
        """STATUSTEXT's text (None for other messages)."""
        if self.name != "STATUSTEXT":
            return None
        return self.payload()[1:51].split(b"\x00", 1)[0].decode("ascii", "replace")

    def time_boot_ms(self) -> int | None:
        """The vehicle time of an ATTITUDE or SYSTEM_TIME frame (None for others)."""
        if self.name == "ATTITUDE":
            return struct.unpack_from("<I", self.payload(), 0)[0]
        if self.name == "SYSTEM_TIME":
            return struct.unpack_from("<I", self.payload(), 8)[0]
        return None

    def rc_channels(self) -> list[int] | None:
        """RC_CHANNELS_OVERRIDE's 18 channel values, channel 1 first (None for other messages)."""
        if self.name != "RC_CHANNELS_OVERRIDE":
            return None
        values = struct.unpack("<8HBB10H", self.payload())
        return list(values[:8]) + list(values[10:])

    def signature(self) -> tuple[str, object, bytes] | None:
        """What makes a PARAM_SET or COMMAND_LONG the same request again (a retry): its name or
        command and its values (a COMMAND_LONG's confirmation counter left out); None for others."""
        if self.name == "PARAM_SET":
            return self.name, self.param_id(), self.payload()
        if self.name == "COMMAND_LONG":
            return self.name, self.command(), self.payload()[:30]
        return None

    def corrupted(self, rng: random.Random) -> bytes:
        """The frame with one payload (or checksum) byte flipped: its CRC no longer matches."""
        raw = bytearray(self.raw)
        end = self.header_len + self.payload_len + 2  # payload and checksum, never the header
        raw[rng.randrange(self.header_len, end)] ^= 0xFF
        return bytes(raw)


def split_frames(buffer: bytearray) -> tuple[list[Frame | bytes], bytearray]:
    """Whole frames (and runs of bytes that start no frame) from ``buffer``, and what is left (an
    incomplete frame). Garbage between frames is passed on as bytes, untouched."""
    out: list[Frame | bytes] = []
    pos = 0
    size = len(buffer)
    while pos < size:
        start = _next_magic(buffer, pos)
        if start < 0:
            out.append(bytes(buffer[pos:]))
            return out, bytearray()
        if start > pos:
            out.append(bytes(buffer[pos:start]))
        frame_len = _frame_length(buffer, start)
        if frame_len is None or start + frame_len > size:
            return out, bytearray(buffer[start:])
        header = 10 if buffer[start] == MAGIC_V2 else 6
        msgid = (int.from_bytes(buffer[start + 7:start + 10], "little") if buffer[start] == MAGIC_V2
                 else buffer[start + 5])
        out.append(Frame(bytes(buffer[start:start + frame_len]), msgid, header, buffer[start + 1]))
        pos = start + frame_len
    return out, bytearray()


def _next_magic(buffer: bytearray, pos: int) -> int:
    v2, v1 = buffer.find(MAGIC_V2, pos), buffer.find(MAGIC_V1, pos)
    candidates = [i for i in (v2, v1) if i >= 0]
    return min(candidates) if candidates else -1


def _frame_length(buffer: bytearray, start: int) -> int | None:
    """Length of the frame starting at ``start`` (None until enough of its header arrived)."""
    if buffer[start] == MAGIC_V2:
        if len(buffer) - start < 3:
            return None
        signed = buffer[start + 2] & INCOMPAT_SIGNED
        return V2_OVERHEAD + buffer[start + 1] + (SIGNATURE_LEN if signed else 0)
    if len(buffer) - start < 2:
        return None
    return V1_OVERHEAD + buffer[start + 1]


# ====================================================================== schedule
@dataclass(frozen=True)
class Trigger:
    """When a fault starts: at the ``nth`` frame the companion sent (``direction`` to_vehicle) or
    the vehicle sent (to_companion) that is a ``message`` (None: any frame; nth 0: at once when the
    proxy is armed), narrowed to one COMMAND_LONG ``command``, one PARAM_SET ``param`` or a
    STATUSTEXT containing ``text``; the fault then starts ``after`` frames (of either direction)
    later. With ``distinct`` a frame that repeats the previous one of its kind (a PARAM_SET of the
    same name and value, a COMMAND_LONG with the same command and parameters: a retry or a
    set-point sent twice) is not counted, so a phase is found even after earlier faults caused
    retries. Counted from :meth:`FaultProxy.arm`."""

    message: str | None = None
    nth: int = 1
    command: int | None = None
    param: str | None = None
    text: str | None = None
    direction: str = TO_VEHICLE
    after: int = 0
    distinct: bool = False

    def matches(self, frame: Frame) -> bool:
        if self.message is not None and frame.name != self.message:
            return False
        if self.command is not None and frame.command() != self.command:
            return False
        if self.param is not None and frame.param_id() != self.param:
            return False
        return self.text is None or self.text in (frame.text() or "")

    def describe(self) -> str:
        if self.nth == 0:
            return "at once"
        what = ("distinct " if self.distinct else "") + (self.message or "frame")
        detail = (f" {self.command}" if self.command is not None else f" {self.param}" if self.param
                  else f" '{self.text}'" if self.text else "")
        return (f"{_ordinal(self.nth)} {what}{detail}" + (" from the vehicle" if self.direction == TO_COMPANION else "")
                + (f" +{self.after} frames" if self.after else ""))


@dataclass(frozen=True)
class Fault:
    """One fault: ``kind`` (:data:`FAULT_KINDS`) from ``trigger`` on, applied to frames travelling
    ``direction`` (to_vehicle, to_companion or both) whose message is in ``messages`` (empty: any),
    to at most ``frames`` frames within ``window_s`` wall seconds of the trigger."""

    kind: str
    trigger: Trigger = Trigger(nth=0)
    direction: str = BOTH
    messages: tuple[str, ...] = ()
    frames: int = 5
    window_s: float = 2.0
    hold_frames: int = 20  # delay: later frames of the same direction that pass first
    max_hold_s: float = 0.5  # delay, reorder: wall-clock bound of a hold
    cut_s: float = 1.0  # cut: how long the link is down
    reconnect: bool = True  # cut: close the connections (True) or drop everything while open (False)

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r} ({', '.join(FAULT_KINDS)})")
        if self.direction not in (TO_VEHICLE, TO_COMPANION, BOTH):
            raise ValueError(f"unknown direction {self.direction!r}")
        if self.frames < 1 or self.window_s <= 0 or self.cut_s < 0:
            raise ValueError("a fault is bounded: frames >= 1, window_s > 0, cut_s >= 0")

    def applies_to(self, frame: Frame, direction: str) -> bool:
        return (self.direction in (BOTH, direction)) and (not self.messages or frame.name in self.messages)

    def describe(self) -> str:
        if self.kind == "cut":
            how = "closed, reconnect" if self.reconnect else "silent"
            return f"cut {self.cut_s:g} s ({how}) at {self.trigger.describe()}"
        which = "/".join(self.messages) or "any frame"
        return f"{self.kind} {self.frames} x {which} ({self.direction}) from {self.trigger.describe()}"


@dataclass
class FaultEvent:
    """What a fault did to one frame (or, for a cut, to the link)."""

    fault: int  # index in the schedule
    kind: str
    direction: str
    message: str
    wall_s: float  # since the proxy was armed


@dataclass
class _Active:
    index: int
    fault: Fault
    started: float
    affected: int = 0

    def open(self, now: float) -> bool:
        if self.fault.kind == "cut":
            return now - self.started < self.fault.cut_s
        return self.affected < self.fault.frames and now - self.started < self.fault.window_s


@dataclass(eq=False)
class _Pipe:
    """One direction of one session: the socket it reads, the socket it writes, their buffers."""

    source: socket.socket
    sink: socket.socket
    direction: str
    pending: bytearray = field(default_factory=bytearray)  # bytes read, not yet a whole frame
    out: bytearray = field(default_factory=bytearray)  # bytes to write to ``sink``
    held: list = field(default_factory=list)  # [release_at_count, release_at_wall, bytes] (delay)
    swap: Frame | None = None  # reorder: the frame that goes after the next one
    swap_until: float = 0.0  # ... or goes anyway at this wall time (nothing followed it)
    forwarded: int = 0  # frames forwarded in this direction


@dataclass(eq=False)
class _Session:
    """One companion connection and its upstream connection to the vehicle."""

    companion: socket.socket
    vehicle: socket.socket
    events: dict = field(default_factory=dict)  # role -> selector events registered (0: none)
    up: _Pipe = field(init=False)
    down: _Pipe = field(init=False)

    def __post_init__(self) -> None:
        self.up = _Pipe(self.companion, self.vehicle, TO_VEHICLE)
        self.down = _Pipe(self.vehicle, self.companion, TO_COMPANION)


# ====================================================================== the proxy
class FaultProxy:
    """The proxy (module docstring). ``with FaultProxy(vehicle_port, seed=3) as proxy:`` …
    ``proxy.endpoint`` is what the companion connects to; :meth:`arm` starts counting triggers
    with a schedule of faults; :meth:`summary` says what fired."""

    def __init__(self, vehicle_port: int, *, seed: int = 0, host: str = "127.0.0.1",
                 max_faults: int = 64) -> None:
        self.vehicle_address = (host, vehicle_port)
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
        self._schedule: list[Fault] = []
        self._waiting: list[int] = []  # indices of faults not triggered yet
        self._active: list[_Active] = []
        self._counts: dict[tuple[int, str], int] = {}  # (fault index, direction) -> matching frames seen
        self._deferred: dict[int, int] = {}  # fault index -> frame number (both directions) it starts at
        self._last_request: dict[tuple[str, object], bytes] = {}  # (message, name/command) -> last values
        self._armed_at: float | None = None
        self._cut_until = 0.0  # no connection is accepted before this (wall clock)
        self._silent_until = 0.0  # every frame is dropped before this
        self._listening = True  # the listener is registered (not during a closing cut)
        self._start_now: list[int] = []  # faults to trigger at the next tick (nth 0)
        self.events: list[FaultEvent] = []
        self.triggered: dict[int, float] = {}  # fault index -> wall seconds after arm
        self.frames_seen = {TO_VEHICLE: 0, TO_COMPANION: 0}
        self.message_counts: dict[tuple[str, str], int] = {}  # (direction, message) -> frames seen since arm
        self.connections = 0
        self.vehicle_time_ms: int | None = None
        self.delivered_commands: dict[int, tuple[float, ...]] = {}  # COMMAND_LONG id -> params last delivered
        self._overrides: dict[int, int] = {}  # channel -> last delivered value (release removes it)

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

    # ------------------------------------------------------------------ schedule
    def arm(self, faults: Iterable[Fault]) -> None:
        """Replace the schedule and start counting triggers from now (at most ``max_faults``)."""
        faults = list(faults)
        if len(faults) > self.max_faults:
            raise ValueError(f"at most {self.max_faults} faults per schedule (bounded), not {len(faults)}")
        with self._lock:
            self._schedule = faults
            self._waiting = list(range(len(faults)))
            self._active = []
            self._counts = {}
            self._deferred = {}
            self.events = []
            self.triggered = {}
            self.message_counts = {}
            self._armed_at = time.monotonic()
            self._start_now = [i for i in self._waiting if faults[i].trigger.nth == 0]

    def disarm(self) -> None:
        """No further fault starts; active ones end; held frames go out at the next chance."""
        with self._lock:
            self._waiting = []
            self._active = []
            self._deferred = {}
            self._start_now = []
            self._silent_until = 0.0
            self._cut_until = 0.0

    @property
    def schedule(self) -> list[Fault]:
        return list(self._schedule)

    def fired(self, index: int) -> int:
        """Frames (or link cuts) fault ``index`` affected."""
        return sum(1 for event in self.events if event.fault == index)

    def summary(self) -> list[dict]:
        """Per scheduled fault: its description, whether it triggered and how many frames it hit."""
        return [{"fault": fault.describe(), "kind": fault.kind, "triggered": index in self.triggered,
                 "affected": self.fired(index)} for index, fault in enumerate(self._schedule)]

    def count(self, message: str, direction: str = TO_VEHICLE) -> int:
        """Frames of ``message`` seen travelling ``direction`` since :meth:`arm`."""
        return self.message_counts.get((direction, message), 0)

    def held_overrides(self) -> dict[int, int]:
        """Channels whose last RC override delivered to the vehicle holds a value (not a release)."""
        with self._lock:
            return dict(self._overrides)

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
        session = _Session(companion, vehicle)
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
                pipe.out += item

    # ------------------------------------------------------------------ one frame
    def _frame(self, pipe: _Pipe, frame: Frame, now: float) -> None:
        direction = pipe.direction
        self.frames_seen[direction] += 1
        total = self.frames_seen[TO_VEHICLE] + self.frames_seen[TO_COMPANION]
        for index, start in list(self._deferred.items()):
            if total >= start:
                del self._deferred[index]
                self._trigger(index, now)
        key = (direction, frame.name)
        self.message_counts[key] = self.message_counts.get(key, 0) + 1
        if direction == TO_COMPANION:
            stamp = frame.time_boot_ms()
            if stamp is not None:
                self.vehicle_time_ms = stamp
        self._check_triggers(frame, direction, now)
        if now < self._silent_until:
            self._record(self._cut_index(), "cut", direction, frame.name, now)
            return
        fault = self._fault_for(frame, direction, now)
        if fault is None:
            self._forward(pipe, frame.raw, frame)
            return
        self._record(fault.index, fault.fault.kind, direction, frame.name, now)
        fault.affected += 1
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
            pipe.swap, pipe.swap_until = frame, now + fault.fault.max_hold_s

    def _forward(self, pipe: _Pipe, raw: bytes, frame: Frame | None) -> None:
        pipe.out += raw
        pipe.forwarded += 1
        if frame is not None and pipe.direction == TO_VEHICLE and frame.name == "RC_CHANNELS_OVERRIDE":
            self._note_override(frame)
        if frame is not None and pipe.direction == TO_VEHICLE and frame.name == "COMMAND_LONG":
            self.delivered_commands[frame.command()] = struct.unpack_from("<7f", frame.payload(), 0)
        if pipe.swap is not None and frame is not pipe.swap:
            swapped, pipe.swap = pipe.swap, None
            self._forward(pipe, swapped.raw, swapped)
        self._release_held(pipe, time.monotonic())

    def _release_held(self, pipe: _Pipe, now: float) -> None:
        while pipe.held and (pipe.forwarded >= pipe.held[0][0] or now >= pipe.held[0][1]):
            _count, _wall, frame = pipe.held.pop(0)
            self._forward(pipe, frame.raw, frame)

    def _note_override(self, frame: Frame) -> None:
        for channel, value in enumerate(frame.rc_channels() or [], start=1):
            ignore = value == RC_IGNORE_LOW if channel <= 8 else value in (0, RC_IGNORE_LOW)
            release = value == RC_RELEASE_LOW if channel <= 8 else value == RC_RELEASE_HIGH
            if release:
                self._overrides.pop(channel, None)
            elif not ignore:
                self._overrides[channel] = value

    # ------------------------------------------------------------------ triggers
    def _check_triggers(self, frame: Frame, direction: str, now: float) -> None:
        signature = frame.signature() if direction == TO_VEHICLE else None
        repeat = False
        if signature is not None:
            repeat = self._last_request.get(signature[:2]) == signature[2]
            self._last_request[signature[:2]] = signature[2]
        for index in list(self._waiting):
            trigger = self._schedule[index].trigger
            if trigger.nth == 0 or trigger.direction != direction or not trigger.matches(frame):
                continue
            if trigger.distinct and repeat:
                continue
            key = (index, direction)
            self._counts[key] = self._counts.get(key, 0) + 1
            if self._counts[key] >= trigger.nth:
                if trigger.after:
                    self._waiting.remove(index)
                    self._deferred[index] = (self.frames_seen[TO_VEHICLE] + self.frames_seen[TO_COMPANION]
                                             + trigger.after)
                else:
                    self._trigger(index, now)

    def _trigger(self, index: int, now: float) -> None:
        if index in self._waiting:
            self._waiting.remove(index)
        elif index in self.triggered:
            return
        fault = self._schedule[index]
        self.triggered[index] = now - (self._armed_at or now)
        log.info("fault proxy: %s", fault.describe())
        if fault.kind != "cut":
            self._active.append(_Active(index, fault, now))
            return
        if fault.reconnect:
            self._cut_until = now + fault.cut_s
            self._record(index, "cut", BOTH, "link closed", now)
            for session in list(self._sessions):
                self._close_session(session)
            if self._listening:  # connections wait in the backlog until the cut ends
                self._selector.unregister(self._listener)
                self._listening = False
        else:
            self._silent_until = now + fault.cut_s
            self._active.append(_Active(index, fault, now))

    def _cut_index(self) -> int:
        active = [a.index for a in self._active if a.fault.kind == "cut"]
        return active[0] if active else -1

    def _fault_for(self, frame: Frame, direction: str, now: float) -> _Active | None:
        for active in self._active:
            if active.fault.kind != "cut" and active.open(now) and active.fault.applies_to(frame, direction):
                return active
        return None

    def _record(self, index: int, kind: str, direction: str, message: str, now: float) -> None:
        self.events.append(FaultEvent(index, kind, direction, message, now - (self._armed_at or now)))

    # ------------------------------------------------------------------ housekeeping
    def _tick(self, now: float) -> None:
        for index in self._start_now:
            self._trigger(index, now)
        self._start_now = []
        if not self._listening and now >= self._cut_until:
            self._selector.register(self._listener, selectors.EVENT_READ, None)
            self._listening = True
        self._active = [a for a in self._active if a.open(now)]
        for session in self._sessions:
            for pipe in (session.up, session.down):
                self._release_held(pipe, now)
                if pipe.swap is not None and now >= pipe.swap_until:
                    swapped, pipe.swap = pipe.swap, None  # nothing came after it in time: let it go
                    self._forward(pipe, swapped.raw, swapped)
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


def _ordinal(n: int) -> str:
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"
