"""The procedure's set-points that land after its restore (SPEC C1, §4: "leaves the autopilot as it
found it"; docs/reliability.md).

A restore stops sending the procedure's set-points (``CommandChannel.abandon``), but one already
sent and still unanswered may be held on the link — a radio's buffer, a relay, a queue — and reach
the vehicle after the restore put the found value back. The restore's own state confirmation
(``restore_items``) covers what lands within its window; this covers what lands later:

* **at the restore's end** the abandoned set-points are waited for, bounded
  (:data:`LATE_WAIT_WALL_S` of wall clock and :data:`LATE_WAIT_PERIODS` command periods of vehicle
  time): an acknowledgement beyond the restore's own sends is one landing
  (``CommandChannel.late_answers``). Each landed set-point whose state then differs from the
  restored value is put back and confirmed again (``set_and_confirm``), and said. One never
  answered within the bound is said too.
* **for as long as the companion stays connected** (``companion run``), a landing seen later is
  put back at once, from the snapshot that shows the vehicle's state left the restored value,
  and logged. A new procedure's restore point ends the watch (its set-points are then its own).

An acknowledgement says nothing about which send it answers, so the trigger is the count and the
judge is the vehicle's state: a value someone else sets (a ground station's DO_CHANGE_SPEED is
acknowledged to the ground station, not to us) is never put back.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

from companion.interface import Command
from companion.link.port import VehiclePort
from companion.procedures.restore_items import CONFIRM_TIMEOUT_S, StateCheck, set_and_confirm

log = logging.getLogger(__name__)

LATE_WAIT_WALL_S = 2.0  # wall seconds a restore's end waits for an abandoned set-point (a held radio frame)
LATE_WAIT_PERIODS = 3.0  # ... and command periods of vehicle time
RESEND_GAP_S = 1.0  # vehicle seconds between two put-backs (the state shows the first one meanwhile)
LATE_RESENDS = 3  # put-backs of one landing while connected (a link that keeps delivering old frames)


@dataclass(frozen=True)
class WatchedSetpoint:
    """A set-point the restore put back: ``label`` (thrust, heading...), the MAVLink ``command``
    that carries it on this autopilot, the ``setpoint`` that was sent and how its state reads."""

    label: str
    command: int
    setpoint: Command
    check: StateCheck

    def __post_init__(self) -> None:
        if self.command <= 0:
            raise ValueError(f"a watched set-point needs its MAVLink command id, not {self.command}")


class LateSetpointWatch:
    """See the module docstring. Built by the restore from what it put back; :meth:`settle` is its
    last item, after which the watch listens to each snapshot while the link lasts."""

    def __init__(self, link: VehiclePort, watched: list[WatchedSetpoint], notes: list[str]) -> None:
        self.link = link
        self.commands = link.commands
        self.watched = [w for w in watched if w.command in self.commands.abandoned]
        self.notes = notes
        self.generation = self.commands.abandon_generation
        self._seen = {w.command: 0 for w in self.watched}  # late answers already handled
        self._until: dict[int, float] = {}  # command -> vehicle time its state is watched until
        self._resends: dict[int, int] = {}
        self._next: dict[int, float] = {}  # command -> vehicle time from which a put-back may be sent again

    @property
    def active(self) -> bool:
        return bool(self.watched) and self.commands.abandon_generation == self.generation

    def settle(self) -> None:
        """Wait (bounded) for the abandoned set-points to land, put back what they changed, say
        what never landed, then keep watching after each snapshot (module docstring)."""
        if not self.watched:
            return
        landed = self._wait_for_landings()
        for w in self.watched:
            if w.command not in landed:
                self.notes.append(f"the procedure's {w.label} set-point (command {w.command}) was still unanswered "
                                  f"{LATE_WAIT_WALL_S:g} s after its restore: if it lands while the companion is "
                                  f"connected it is put back, after that the vehicle keeps it")
                continue
            self._seen[w.command] = self.commands.late_answers(w.command)
            telemetry = self.link.latest_telemetry
            error = w.check.error(telemetry) if telemetry is not None else math.nan
            if math.isfinite(error) and error <= w.check.tolerance:
                continue
            set_and_confirm(self.link, w.setpoint, w.check)
            self.notes.append(f"the procedure's {w.label} set-point (command {w.command}) landed after its restore: "
                              f"{w.check.what} put back to {w.check.target:.3f} (read back)")
        self.link.telemetry.after_snapshot(self._after_snapshot)

    def _wait_for_landings(self) -> set[int]:
        clock = self.link.clock
        start_wall, start_vehicle = time.monotonic(), clock.vehicle_time_s
        vehicle_bound = LATE_WAIT_PERIODS * self.commands.period_s

        def landed() -> set[int]:
            return {w.command for w in self.watched if self.commands.late_answers(w.command) > 0}

        while len(landed()) < len(self.watched):
            if (time.monotonic() - start_wall >= LATE_WAIT_WALL_S
                    and clock.vehicle_time_s - start_vehicle >= vehicle_bound):
                break
            self.link.next_telemetry()
        if landed():  # what a landing changed shows in the state a moment later
            first = self.link.next_telemetry()
            while self.link.next_telemetry().time_s - first.time_s < 0.2:
                pass
        return landed()

    def _after_snapshot(self) -> None:
        """A landing after the restore's end: put the set-point back while the state shows it left.
        A watch made stale by a later restore or procedure stops listening (a long ``companion run``
        would otherwise keep one listener per restore)."""
        if not self.active:
            self.link.telemetry.stop_calling(self._after_snapshot)
            return
        telemetry = self.link.latest_telemetry
        if telemetry is None:
            return
        for w in self.watched:
            answers = self.commands.late_answers(w.command)
            if answers > self._seen[w.command]:
                self._seen[w.command] = answers
                self._until[w.command] = telemetry.time_s + CONFIRM_TIMEOUT_S
                self._resends[w.command] = 0
            if not self._next.get(w.command, -math.inf) <= telemetry.time_s <= self._until.get(w.command, -math.inf):
                continue
            error = w.check.error(telemetry)
            if not math.isfinite(error) or error <= w.check.tolerance or self._resends[w.command] >= LATE_RESENDS:
                continue
            params = self.commands.last_setpoint(w.command)
            if params is None:
                continue
            self._resends[w.command] += 1
            self._until[w.command] = telemetry.time_s + CONFIRM_TIMEOUT_S
            self._next[w.command] = telemetry.time_s + RESEND_GAP_S
            self.commands.send(w.command, params)  # its own answer balances its send (late_answers)
            log.warning("the procedure's %s set-point (command %d) landed after its restore: %s; put back to %.3f",
                        w.label, w.command, w.check.describe(telemetry), w.check.target)
