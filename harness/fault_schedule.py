"""Triggered link faults: what may go wrong with a frame, when it starts and how long it lasts;
the vocabulary shared by the TCP fault proxy (``harness.fault_proxy``) and the UDP relay
(``harness.udp_relay``).

A :class:`Fault` (drop, delay, duplicate, reorder, corrupt, cut) starts at its :class:`Trigger` —
the K-th frame of one kind that one side sent, counted from :meth:`FaultSchedule.arm` — and is
bounded in count (``frames``) and time (``window_s``). :class:`FaultSchedule` keeps the count of
every trigger, starts the faults, says which fault (if any) takes a frame, and records what each
fault did (:attr:`FaultSchedule.events`). What a fault *does* to a frame is the transport's: the
schedule only decides. It is not thread-safe: its owner calls it under its own lock.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable, Iterable

from harness.mavlink_frames import Frame

log = logging.getLogger(__name__)

__all__ = ["BOTH", "FAULT_KINDS", "TO_COMPANION", "TO_VEHICLE", "ActiveFault", "Fault", "FaultEvent",
           "FaultSchedule", "Trigger", "overtaken", "timed_delay"]

FAULT_KINDS = ("drop", "delay", "duplicate", "reorder", "corrupt", "cut")
TO_VEHICLE = "to_vehicle"
TO_COMPANION = "to_companion"
BOTH = "both"
DIRECTIONS = (TO_VEHICLE, TO_COMPANION)


@dataclass(frozen=True)
class Trigger:
    """When a fault starts: at the ``nth`` frame the companion sent (``direction`` to_vehicle) or
    the vehicle sent (to_companion) that is a ``message`` (None: any frame; nth 0: at once when the
    schedule is armed), narrowed to one COMMAND_LONG ``command``, one PARAM_SET ``param`` or a
    STATUSTEXT containing ``text``; the fault then starts ``after`` frames (of either direction)
    later. With ``distinct`` a frame that repeats the previous one of its kind (a PARAM_SET of the
    same name and value, a COMMAND_LONG with the same command and parameters: a retry or a
    set-point sent twice) is not counted, so a phase is found even after earlier faults caused
    retries. Counted from :meth:`FaultSchedule.arm`."""

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
    to at most ``frames`` frames within ``window_s`` wall seconds of the trigger.

    ``delay`` holds a frame until ``hold_frames`` later frames of its direction have passed or
    ``max_hold_s`` wall seconds went by, whichever comes first (a large ``hold_frames`` makes it a
    delay in time only: :func:`timed_delay`). ``reorder`` holds it until the next frame of its
    direction has passed — the next one that ``partner`` matches, when given (:func:`overtaken`) —
    or ``max_hold_s`` went by."""

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
    partner: Trigger | None = None  # reorder: the frame it goes after (None: the next of its direction)

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r} ({', '.join(FAULT_KINDS)})")
        if self.direction not in (TO_VEHICLE, TO_COMPANION, BOTH):
            raise ValueError(f"unknown direction {self.direction!r}")
        if self.frames < 1 or self.window_s <= 0 or self.cut_s < 0 or self.max_hold_s < 0:
            raise ValueError("a fault is bounded: frames >= 1, window_s > 0, cut_s >= 0, max_hold_s >= 0")

    def applies_to(self, frame: Frame, direction: str) -> bool:
        return (self.direction in (BOTH, direction)) and (not self.messages or frame.name in self.messages)

    def describe(self) -> str:
        if self.kind == "cut":
            how = "closed, reconnect" if self.reconnect else "silent"
            return f"cut {self.cut_s:g} s ({how}) at {self.trigger.describe()}"
        which = "/".join(self.messages) or "any frame"
        timed = f" by {self.max_hold_s * 1000:g} ms" if self.kind == "delay" and self.hold_frames >= TIMED_HOLD else ""
        if self.kind == "reorder" and self.partner is not None:
            timed = f" after the next {self.partner.describe().split(' ', 1)[1]}"
        return f"{self.kind}{timed} {self.frames} x {which} ({self.direction}) from {self.trigger.describe()}"


#: a delay whose ``hold_frames`` is at least this is a delay in wall time only
TIMED_HOLD = 1_000_000


def timed_delay(trigger: Trigger, delay_s: float, *, messages: tuple[str, ...] = (), frames: int = 1,
                direction: str = TO_VEHICLE) -> Fault:
    """Hold the ``frames`` frames from ``trigger`` on (of ``messages``, travelling ``direction``) for
    ``delay_s`` wall seconds each, whatever passes meanwhile: e.g. the 3rd DO_CHANGE_SPEED 80 ms
    late, so that a later set-point can overtake it."""
    return Fault("delay", trigger, direction=direction, messages=messages, frames=frames,
                 window_s=max(2.0, 2 * delay_s), hold_frames=TIMED_HOLD, max_hold_s=delay_s)


def overtaken(trigger: Trigger, partner: Trigger, *, messages: tuple[str, ...] = (), max_hold_s: float = 2.0,
              direction: str = TO_VEHICLE) -> Fault:
    """The frame at ``trigger`` is delivered right after the next frame ``partner`` matches (at most
    ``max_hold_s`` late): e.g. the last thrust set-point of a procedure arriving after its restore's,
    whatever the wall-clock gap between the two."""
    return Fault("reorder", trigger, direction=direction, messages=messages, frames=1,
                 window_s=max(2.0, max_hold_s), max_hold_s=max_hold_s, partner=partner)


@dataclass
class FaultEvent:
    """What a fault did to one frame (or, for a cut, to the link)."""

    fault: int  # index in the schedule
    kind: str
    direction: str
    message: str
    wall_s: float  # since the schedule was armed


@dataclass
class ActiveFault:
    """A fault that has started: its index in the schedule, when, and how many frames it took."""

    index: int
    fault: Fault
    started: float
    affected: int = 0

    def open(self, now: float) -> bool:
        if self.fault.kind == "cut":
            return now - self.started < self.fault.cut_s
        return self.affected < self.fault.frames and now - self.started < self.fault.window_s


class FaultSchedule:
    """The armed faults, their trigger counts and what they did (module docstring).

    ``on_closing_cut(now)`` is called when a cut with ``reconnect`` starts (the TCP proxy closes its
    connections then); without it (UDP has no connection to close) such a cut is silent too."""

    def __init__(self, max_faults: int = 64, on_closing_cut: Callable[[float], None] | None = None) -> None:
        self.max_faults = max_faults
        self.on_closing_cut = on_closing_cut
        self.faults: list[Fault] = []
        self._waiting: list[int] = []  # indices of faults not triggered yet
        self._active: list[ActiveFault] = []
        self._counts: dict[tuple[int, str], int] = {}  # (fault index, direction) -> matching frames seen
        self._deferred: dict[int, int] = {}  # fault index -> frame number (both directions) it starts at
        self._last_request: dict[tuple[str, object], bytes] = {}  # (message, name/command) -> last values
        self._armed_at: float | None = None
        self._start_now: list[int] = []  # faults to trigger at the next tick (nth 0)
        self.cut_until = 0.0  # a closing cut: no connection is accepted before this (wall clock)
        self.silent_until = 0.0  # a silent cut: every frame is dropped before this
        self.events: list[FaultEvent] = []
        self.triggered: dict[int, float] = {}  # fault index -> wall seconds after arm
        self.frames_seen = {TO_VEHICLE: 0, TO_COMPANION: 0}
        self.message_counts: dict[tuple[str, str], int] = {}  # (direction, message) -> frames seen since arm

    # ------------------------------------------------------------------ arming
    def arm(self, faults: Iterable[Fault], now: float | None = None) -> None:
        """Replace the schedule and start counting triggers from now (at most ``max_faults``)."""
        faults = list(faults)
        if len(faults) > self.max_faults:
            raise ValueError(f"at most {self.max_faults} faults per schedule (bounded), not {len(faults)}")
        self.faults = faults
        self._waiting = list(range(len(faults)))
        self._active = []
        self._counts = {}
        self._deferred = {}
        self.events = []
        self.triggered = {}
        self.message_counts = {}
        self._armed_at = time.monotonic() if now is None else now
        self._start_now = [i for i in self._waiting if faults[i].trigger.nth == 0]

    def disarm(self) -> None:
        """No further fault starts; active ones end."""
        self._waiting = []
        self._active = []
        self._deferred = {}
        self._start_now = []
        self.silent_until = 0.0
        self.cut_until = 0.0

    # ------------------------------------------------------------------ frames
    def see(self, frame: Frame, direction: str, now: float) -> None:
        """Count ``frame`` (travelling ``direction``) and start the faults it triggers."""
        self.frames_seen[direction] += 1
        total = self.frames_seen[TO_VEHICLE] + self.frames_seen[TO_COMPANION]
        for index, start in list(self._deferred.items()):
            if total >= start:
                del self._deferred[index]
                self._trigger(index, now)
        key = (direction, frame.name)
        self.message_counts[key] = self.message_counts.get(key, 0) + 1
        self._check_triggers(frame, direction, now)

    def silenced(self, now: float) -> bool:
        """A silent cut is on: every frame is dropped."""
        return now < self.silent_until

    def fault_for(self, frame: Frame, direction: str, now: float) -> ActiveFault | None:
        """The active fault that takes ``frame`` (None: it passes untouched); the hit is recorded."""
        for active in self._active:
            if active.fault.kind != "cut" and active.open(now) and active.fault.applies_to(frame, direction):
                self.record(active.index, active.fault.kind, direction, frame.name, now)
                active.affected += 1
                return active
        return None

    def cut_index(self) -> int:
        active = [a.index for a in self._active if a.fault.kind == "cut"]
        return active[0] if active else -1

    def record(self, index: int, kind: str, direction: str, message: str, now: float) -> None:
        self.events.append(FaultEvent(index, kind, direction, message, now - (self._armed_at or now)))

    def tick(self, now: float) -> None:
        """Start the faults due at once; forget the ones that ended."""
        for index in self._start_now:
            self._trigger(index, now)
        self._start_now = []
        self._active = [a for a in self._active if a.open(now)]

    # ------------------------------------------------------------------ reporting
    def fired(self, index: int) -> int:
        """Frames (or link cuts) fault ``index`` affected."""
        return sum(1 for event in self.events if event.fault == index)

    def summary(self) -> list[dict]:
        """Per scheduled fault: its description, whether it triggered and how many frames it hit."""
        return [{"fault": fault.describe(), "kind": fault.kind, "triggered": index in self.triggered,
                 "affected": self.fired(index)} for index, fault in enumerate(self.faults)]

    def count(self, message: str, direction: str = TO_VEHICLE) -> int:
        """Frames of ``message`` seen travelling ``direction`` since :meth:`arm`."""
        return self.message_counts.get((direction, message), 0)

    # ------------------------------------------------------------------ triggers
    def _check_triggers(self, frame: Frame, direction: str, now: float) -> None:
        signature = frame.signature() if direction == TO_VEHICLE else None
        repeat = False
        if signature is not None:
            repeat = self._last_request.get(signature[:2]) == signature[2]
            self._last_request[signature[:2]] = signature[2]
        for index in list(self._waiting):
            trigger = self.faults[index].trigger
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
        fault = self.faults[index]
        self.triggered[index] = now - (self._armed_at or now)
        log.info("fault: %s", fault.describe())
        if fault.kind != "cut":
            self._active.append(ActiveFault(index, fault, now))
        elif fault.reconnect and self.on_closing_cut is not None:
            self.cut_until = now + fault.cut_s
            self.record(index, "cut", BOTH, "link closed", now)
            self.on_closing_cut(now)
        else:
            self.silent_until = now + fault.cut_s
            self._active.append(ActiveFault(index, fault, now))


def _ordinal(n: int) -> str:
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


class ScheduledFaults:
    """What a link in the middle (the TCP proxy, the UDP relay) says of its triggered faults: the
    schedule armed, what happened, and the commands it delivered. A mixin: the class holds
    ``_lock``, ``_faults`` (a :class:`FaultSchedule`), ``received`` and ``delivered`` (its
    delivery records: what the companion sent, what reached the vehicle)."""

    def arm(self, faults: Iterable[Fault]) -> None:
        """Replace the schedule and start counting triggers from now (at most ``max_faults``)."""
        with self._lock:
            self._faults.arm(faults)

    def disarm(self) -> None:
        """No further fault starts; active ones end; held frames go out at the next chance."""
        with self._lock:
            self._faults.disarm()

    @property
    def schedule(self) -> list[Fault]:
        return list(self._faults.faults)

    @property
    def events(self) -> list[FaultEvent]:
        return self._faults.events

    @property
    def triggered(self) -> dict[int, float]:
        return self._faults.triggered

    @property
    def delivered_commands(self) -> dict[int, tuple[float, ...]]:
        """COMMAND_LONG id -> the parameters last delivered to the vehicle."""
        return self.delivered.commands

    def fired(self, index: int) -> int:
        """Frames (or link cuts) fault ``index`` affected."""
        return self._faults.fired(index)

    def summary(self) -> list[dict]:
        """Per scheduled fault: its description, whether it triggered and how many frames it hit."""
        with self._lock:
            return self._faults.summary()

    def count(self, message: str, direction: str = TO_VEHICLE) -> int:
        """Frames of ``message`` seen travelling ``direction`` since :meth:`arm`."""
        return self._faults.count(message, direction)

    def held_overrides(self) -> dict[int, int]:
        """Channels whose last RC override delivered to the vehicle holds a value (not a release)."""
        with self._lock:
            return self.delivered.held_overrides()

    def history(self, command: int, *, sent: bool = False) -> list:
        """The COMMAND_LONGs ``command`` delivered to the vehicle, in the order it received them
        (``sent``: in the order the companion sent them, before any fault or condition)."""
        with self._lock:
            return (self.received if sent else self.delivered).history(command)
