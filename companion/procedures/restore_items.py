"""How one item of a restore is put back and confirmed (SPEC C1, §4: "leaves the autopilot as it
found it").

* A parameter is written back only if it changed (every write costs a flash write), and trusted
  only when echoed (the link's parameter protocol).
* A set-point is confirmed by the vehicle's **state**, never by its COMMAND_ACK alone: an
  acknowledgement carries only the command id, so two set-points of one command cannot be told
  apart, and over a link that delays and reorders, the procedure's last set-point can arrive after
  the restore's and win (measured over UDP with jitter: the result said ``completed`` while the
  vehicle kept 100 % thrust). After the acknowledgement the state the autopilot reports (the thrust
  output, the heading target it holds, the rolling-mass servo) must show the value for a window
  that covers what may still be in flight: :data:`CONFIRM_VEHICLE_S` of vehicle time *and* three
  times the longest command round trip seen on this link (at least :data:`CONFIRM_MIN_WALL_S` of
  wall clock: a delay on the link is wall-clock time, whatever the vehicle clock does; none in
  lockstep, where our simulator applies messages in the order they were sent). A value
  that leaves it meanwhile was overtaken: the set-point is sent again and the window restarts,
  :data:`CONFIRM_RESENDS` times at most.
* A lost link is reconnected where it can be (a TCP connection), bounded.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Callable

from companion.link.port import VehiclePort
from companion.interface import Command, Telemetry

log = logging.getLogger(__name__)

#: tries per restore item; a lost link is not retried (each try would wait out its timeout)
RESTORE_TRIES = 3
#: reconnections one restore may make (a link that keeps dropping is not chased for ever)
RESTORE_RECONNECTS = 2
CONFIRM_VEHICLE_S = 0.5  # vehicle seconds a set-point must be seen held
CONFIRM_MIN_WALL_S = 0.3  # and at least this much wall clock (what is in flight on the link)
CONFIRM_TIMEOUT_S = 6.0  # vehicle seconds to see it at all (a rolling mass lags ~0.5 s per e-fold)
CONFIRM_RESENDS = 2


class NotConfirmed(RuntimeError):
    """The vehicle acknowledged a set-point but its state does not show it."""


@dataclass(frozen=True)
class StateCheck:
    """What a set-point looks like in telemetry: ``read`` gives the reported value, ``target`` is
    what must be seen within ``tolerance`` (``angular``: compared on the circle)."""

    what: str
    read: Callable[[Telemetry], float]
    target: float
    tolerance: float
    angular: bool = False

    def error(self, telemetry: Telemetry) -> float:
        value = self.read(telemetry)
        if not math.isfinite(value):
            return math.nan
        difference = value - self.target
        if self.angular:
            difference = math.remainder(difference, 2.0 * math.pi)
        return abs(difference)

    def describe(self, telemetry: Telemetry | None) -> str:
        value = self.read(telemetry) if telemetry is not None else math.nan
        return f"{self.what} reads {value:.3f} (wanted {self.target:.3f} ± {self.tolerance:g})"


def set_and_confirm(link: VehiclePort, command: Command, check: StateCheck | None) -> None:
    """Send one set-point, wait for its acknowledgement, then for the vehicle's state to show it
    (module docstring). Without a check (nothing reports it) the acknowledgement is all there is."""
    _send_acknowledged(link, command)
    if check is None:
        return
    resends = 0
    while True:
        try:
            _hold_seen(link, check)
            return
        except _Overtaken as exc:
            if resends >= CONFIRM_RESENDS:
                raise NotConfirmed(f"{check.what}: overtaken {resends + 1} times: {exc}") from None
            resends += 1
            log.warning("%s was overtaken (%s): sent again", check.what, exc)
            _send_acknowledged(link, command)


def _send_acknowledged(link: VehiclePort, command: Command) -> None:
    link.execute([command])
    link.await_setpoints()


class _Overtaken(RuntimeError):
    """The state showed the set-point, then left it: something sent earlier arrived later."""


def _in_flight_wall_s(link: VehiclePort) -> float:
    """How long (wall clock) something sent before may still be on its way. Nothing on a lockstep
    link: our simulator applies every message it received before the one that moves its clock, in
    order, so nothing sent before the restore can land after it."""
    if link.clock.lockstep:
        return 0.0
    round_trip = link.commands.max_round_trip_s or 0.0
    return max(CONFIRM_MIN_WALL_S, 3.0 * round_trip)


def _hold_seen(link: VehiclePort, check: StateCheck) -> None:
    """Return once ``check`` holds for the confirmation window; _Overtaken if it stops holding,
    NotConfirmed if it is not seen within :data:`CONFIRM_TIMEOUT_S`."""
    link.skip_to_now()  # snapshots queued before the command say nothing about it
    first = link.next_telemetry()
    start_vehicle, start_wall, held_since, held_wall = first.time_s, time.monotonic(), None, 0.0
    wall_needed = _in_flight_wall_s(link)
    telemetry = first
    while True:
        error = check.error(telemetry)
        if math.isfinite(error) and error <= check.tolerance:
            if held_since is None:
                held_since, held_wall = telemetry.time_s, time.monotonic()
            if telemetry.time_s - held_since >= CONFIRM_VEHICLE_S and time.monotonic() - held_wall >= wall_needed:
                return
        elif held_since is not None and math.isfinite(error):
            raise _Overtaken(check.describe(telemetry))  # a snapshot without the read-back says nothing
        if telemetry.time_s - start_vehicle > CONFIRM_TIMEOUT_S and time.monotonic() - start_wall > 2.0 * wall_needed:
            raise NotConfirmed(f"{check.describe(telemetry)} {CONFIRM_TIMEOUT_S:g} s after it was acknowledged")
        telemetry = link.next_telemetry()


def in_flight_possible(link: VehiclePort) -> bool:
    """Something the procedure sent may still be on its way: a link that is not in lockstep. In
    lockstep (and in process, where every command is applied at once) nothing can land later."""
    return not link.clock.lockstep


def wait_in_flight(link: VehiclePort) -> None:
    """Let what the procedure sent before the restore land: :data:`CONFIRM_VEHICLE_S` of vehicle time
    and the link's in-flight window of wall clock (:func:`_in_flight_wall_s`), reading telemetry
    meanwhile; nothing to wait for in lockstep or without telemetry."""
    if not in_flight_possible(link):
        return
    wall_needed = _in_flight_wall_s(link)
    start_wall = time.monotonic()
    first = link.next_telemetry()
    telemetry = first
    while telemetry.time_s - first.time_s < CONFIRM_VEHICLE_S or time.monotonic() - start_wall < wall_needed:
        telemetry = link.next_telemetry()


def pump_vehicle_time(link: VehiclePort, seconds: float) -> None:
    """Keep reading telemetry for ``seconds`` of vehicle time (what is held is refreshed, what is
    released is sent, with every snapshot)."""
    first = link.next_telemetry()
    while link.next_telemetry().time_s - first.time_s < seconds:
        pass


def write_if_changed(link: VehiclePort, name: str, value: float) -> None:
    """Write ``name`` back unless it already holds ``value`` (every write costs a flash write)."""
    current = link.get_param(name)
    if not (math.isfinite(current) and abs(current - value) <= 1e-6 * max(1.0, abs(value))):
        link.set_param(name, value)


class Reconnector:
    """A restore's bounded attempts to get a closed link back (``link.reconnect``, at most
    :data:`RESTORE_RECONNECTS` per restore, each bounded by the link's own wall-clock limit);
    once one fails, the link is taken as gone for the rest of the restore."""

    def __init__(self, link: VehiclePort) -> None:
        self._reconnect = link.reconnect
        self.left = RESTORE_RECONNECTS
        self.gone: str | None = None  # why the rest of the restore is not tried (the link did not come back)

    def __call__(self) -> bool:
        if self.left <= 0:
            return False
        self.left -= 1
        try:
            back = bool(self._reconnect())
        except Exception as exc:  # noqa: BLE001 - a failed reconnect is a lost link, reported below
            log.error("reconnect failed: %s", exc)
            back = False
        if not back:
            self.left = 0
            self.gone = "the link was lost and did not come back"
        return back


def try_restore_item(what: str, action: Callable[[], None], reconnect: Reconnector | None = None) -> str | None:
    """``action`` tried up to :data:`RESTORE_TRIES` times; None on success, else the last failure.
    A lost link is reconnected if it can be and the item tried again; otherwise it ends the tries at
    once (bounded: each attempt already waited out its timeout)."""
    from companion.link.errors import LinkLost, VehicleRebooted

    if reconnect is not None and reconnect.gone:  # each try would fail on the closed connection
        return f"{what}: not tried: {reconnect.gone}"
    failure = "not tried"
    for attempt in range(1, RESTORE_TRIES + 1):
        try:
            action()
            return None
        except VehicleRebooted as exc:  # reported once; the item is tried again on the new boot
            log.warning("%s: %s", what, exc)
            failure = str(exc)
        except Exception as exc:  # noqa: BLE001 - every item is tried whatever went wrong
            failure = f"{type(exc).__name__}: {exc}" if not str(exc) else str(exc)
            log.error("%s failed (try %d of %d): %s", what, attempt, RESTORE_TRIES, failure)
            if isinstance(exc, LinkLost) and (reconnect is None or not reconnect()):
                break
    return f"{what}: {failure}"
