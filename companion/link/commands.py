"""COMMAND_LONG to the autopilot: acknowledged commands and set-points (SPEC C1, docs/PROTOCOL.md).

Two kinds of command:

* :meth:`CommandChannel.command` sends and waits (vehicle time, retried) for the COMMAND_ACK and
  returns its result (mode changes, arming, servo moves that must be confirmed);
* :meth:`CommandChannel.send_setpoint` sends a set-point without waiting; its acknowledgement is
  awaited in the background. A set-point the vehicle refused, or left unanswered for three command
  periods of vehicle time, fails the procedure that sent it (:meth:`check_answers` raises
  CommandFailed at the next snapshot); one unanswered for a command period is sent again first
  (a frame lost on the link). Set-points are absolute, so a vehicle that did get the first one is
  not moved by the second.
"""
from __future__ import annotations

import collections
import logging
import math
import time
from typing import Any, Sequence

from companion.link.clock import VehicleClock
from companion.link.errors import CommandFailed
from companion.link.transport import Transport

log = logging.getLogger(__name__)

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_IN_PROGRESS = 5
MAV_CMD_DO_SET_SERVO = 183


class CommandChannel:
    """Commands to the autopilot and what it answered (see the module docstring)."""

    #: a set-point's acknowledgement may arrive after the procedure gave up on it (``companion.link.port``)
    answers_late = True

    def __init__(self, transport: Transport, clock: VehicleClock) -> None:
        self.transport = transport
        self.clock = clock
        self.acks: dict[int, tuple[int, int, int]] = {}  # command -> (result, progress, arrival counter)
        self.ack_count = 0
        self.rejected: collections.deque[tuple[float, int, int]] = collections.deque(maxlen=64)
        # set-point command -> (vehicle time, wall time) it was first sent
        self._awaiting: dict[int, tuple[float, float]] = {}
        # set-point command -> (its latest parameters, vehicle time last sent, times sent, wall time last sent)
        self._sends: dict[int, tuple[tuple[float, ...], float, int, float]] = {}
        self._refusals: collections.deque[str] = collections.deque(maxlen=16)
        # the link's round trip (wall seconds from a command to its acknowledgement), recent ones: how
        # long a command already sent may still be on its way (a restore waits that out)
        self._sent_wall: dict[int, float] = {}
        self.round_trips: collections.deque[float] = collections.deque(maxlen=32)
        # every COMMAND_LONG sent and every acknowledgement aimed at us, per command: after an
        # abandon, answers beyond the sends since then are the abandoned sends landing (late_answers)
        self.sends_of: collections.Counter[int] = collections.Counter()
        self.answers_of: collections.Counter[int] = collections.Counter()
        self._abandoned_at: dict[int, tuple[int, int]] = {}  # command -> (sends, answers) when abandoned
        self.abandon_generation = 0  # counts abandons (and forget_abandoned): a watch knows it is stale
        transport.on("COMMAND_ACK", self._on_command_ack)

    @property
    def period_s(self) -> float:
        return self.clock.timeouts.command_s

    # ------------------------------------------------------------------ acknowledged commands
    def send(self, command: int, params: Sequence[float], *, confirmation: int = 0) -> int:
        """Send a COMMAND_LONG; returns the acknowledgement counter to wait from."""
        self.transport.command_long(command, tuple(params), confirmation=confirmation)
        self.sends_of[command] += 1
        self._sent_wall[command] = time.monotonic()  # the latest send: a resend's answer is timed from it
        return self.ack_count

    @property
    def max_round_trip_s(self) -> float:
        """The longest recent command round trip (wall seconds; 0 before any was measured)."""
        return max(self.round_trips, default=0.0)

    @property
    def try_wall_s(self) -> float:
        """The wall clock one command period lasts at least: the configured minimum, or three times
        the link's median round trip when that is longer (a loaded companion or a slow radio)."""
        trips = sorted(self.round_trips)
        median = trips[len(trips) // 2] if trips else 0.0
        return max(self.clock.timeouts.min_try_wall_s, 3.0 * median)

    def abandon(self) -> list[int]:
        """Stop awaiting (and re-sending) every set-point still unanswered: a restore begins, and
        nothing of the procedure may be sent after it. Returns the commands abandoned."""
        abandoned = sorted(self._awaiting)
        self._abandoned_at = {command: (self.sends_of[command], self.answers_of[command]) for command in abandoned}
        self.abandon_generation += 1
        self._awaiting.clear()
        self._sends.clear()
        for command in abandoned:  # an answer to these no longer measures the link
            self._sent_wall.pop(command, None)
        self._refusals.clear()
        return abandoned

    def forget_abandoned(self) -> None:
        """A new procedure owns the set-points now: answers to the last abandoned ones are its business."""
        self._abandoned_at = {}
        self.abandon_generation += 1

    @property
    def abandoned(self) -> tuple[int, ...]:
        """The set-point commands the last :meth:`abandon` left unanswered."""
        return tuple(self._abandoned_at)

    def late_answers(self, command: int) -> int:
        """Acknowledgements of ``command`` since it was abandoned beyond one per send since then: the
        abandoned sends that reached the vehicle after all (0 for a command not abandoned). An
        acknowledgement carries no sequence, so this counts: a lost answer to a later send hides
        a landing, a duplicated one shows one that did not happen — the vehicle's state decides."""
        if command not in self._abandoned_at:
            return 0
        sends, answers = self._abandoned_at[command]
        return max(0, (self.answers_of[command] - answers) - (self.sends_of[command] - sends))

    def last_setpoint(self, command: int) -> tuple[float, ...] | None:
        """The parameters of the latest set-point of ``command`` sent since the last abandon."""
        sent = self._sends.get(command)
        return sent[0] if sent is not None else None

    def answered_since(self, command: int, since: int) -> tuple[int, int] | None:
        """(result, progress) of an acknowledgement of ``command`` that arrived after counter ``since``."""
        ack = self.acks.get(command)
        return (ack[0], ack[1]) if ack is not None and ack[2] > since else None

    def command(self, command: int, params: Sequence[float], *, retries: int = 2) -> int:
        """Send a COMMAND_LONG and wait (vehicle time) for its ACK; returns the MAV_RESULT.
        Raises CommandFailed when no ACK arrives after all tries."""
        for attempt in range(retries + 1):
            since = self.send(command, params, confirmation=attempt)
            if self.clock.wait_until(lambda: self.answered_since(command, since) is not None, self.period_s):
                return self.acks[command][0]
        raise CommandFailed(f"no COMMAND_ACK for command {command}", command=command)

    def set_servo(self, output: int, pwm: int, *, wait: bool = False) -> None:
        """DO_SET_SERVO on a spare output. With ``wait``, raise CommandFailed unless ACCEPTED."""
        if not wait:
            self.send(MAV_CMD_DO_SET_SERVO, (float(output), float(pwm)))
            return
        result = self.command(MAV_CMD_DO_SET_SERVO, (float(output), float(pwm)))
        if result != MAV_RESULT_ACCEPTED:
            raise CommandFailed(f"DO_SET_SERVO output {output} refused: result {result}",
                                command=MAV_CMD_DO_SET_SERVO, result=result)

    # ------------------------------------------------------------------ set-points
    def send_setpoint(self, command: int, params: Sequence[float]) -> None:
        """A set-point COMMAND_LONG whose ACK is awaited in the background (module docstring)."""
        self.send(command, params)
        now = self.clock.vehicle_time_s if math.isfinite(self.clock.vehicle_time_s) else 0.0
        wall = time.monotonic()
        self._awaiting.setdefault(command, (now, wall))
        self._sends[command] = (tuple(params), now, 1, wall)

    def _waited(self, vehicle_s: float, wall_s: float, periods: float) -> bool:
        """``periods`` command periods of vehicle time have passed since (vehicle_s, wall_s) — and,
        unless in lockstep, as many minimum tries of wall clock: the answer to a command can only come
        after the vehicle's clock as it is *now*, and a companion reading its telemetry some vehicle
        seconds behind (a loaded computer at a high speed-up) would otherwise count the backlog it
        is still reading as time the vehicle had to answer."""
        if self.clock.vehicle_time_s - vehicle_s <= periods * self.period_s:
            return False
        return self.clock.lockstep or time.monotonic() - wall_s >= periods * self.try_wall_s

    @property
    def awaiting(self) -> tuple[int, ...]:
        """Set-point commands sent and not yet acknowledged."""
        return tuple(self._awaiting)

    def check_answers(self) -> None:
        """Raise CommandFailed for a refused set-point or one unanswered for 3 command periods of
        vehicle time; send again those unanswered for one period."""
        if self._refusals:
            reason = self._refusals.popleft()
            self._refusals.clear()
            raise CommandFailed(reason)
        overdue = [c for c, (vehicle_s, wall_s) in self._awaiting.items() if self._waited(vehicle_s, wall_s, 3.0)]
        if overdue:
            self._awaiting.clear()
            raise CommandFailed(f"the vehicle did not acknowledge command {overdue[0]}", command=overdue[0])
        self._resend()

    def _resend(self) -> None:
        """Send again every awaited set-point last sent a command period of vehicle time ago."""
        now = self.clock.vehicle_time_s
        for command in list(self._awaiting):
            params, last, sends, last_wall = self._sends.get(command, ((), -math.inf, 1, -math.inf))
            if params and self._waited(last, last_wall, 1.0):
                log.info("command %d unanswered for %.1f s: sent again", command, now - last)
                self.send(command, params, confirmation=min(sends, 255))
                self._sends[command] = (params, now, sends + 1, time.monotonic())

    def await_setpoints(self) -> None:
        """Wait (vehicle time, three command periods, sending unanswered ones again each period)
        until every set-point sent has been acknowledged; CommandFailed on a refusal or when one
        is still unanswered."""
        for _period in range(3):
            if self.clock.wait_until(lambda: not self._awaiting or bool(self._refusals), self.period_s):
                break
            self._resend()
        if self._refusals:
            reason = self._refusals.popleft()
            self._refusals.clear()
            self._awaiting.clear()
            raise CommandFailed(reason)
        if self._awaiting:
            unanswered = sorted(self._awaiting)
            self._awaiting.clear()
            raise CommandFailed(f"the vehicle did not acknowledge command {unanswered[0]}", command=unanswered[0])

    # ------------------------------------------------------------------ receiving
    def _on_command_ack(self, msg: Any) -> None:
        if not self.transport.from_vehicle(msg):
            return
        if not self.transport.aimed_at_us(getattr(msg, "target_system", 0), getattr(msg, "target_component", 0)):
            return
        self.ack_count += 1
        self.answers_of[msg.command] += 1
        self.acks[msg.command] = (msg.result, getattr(msg, "progress", 0) or 0, self.ack_count)
        sent = self._sent_wall.pop(msg.command, None)
        if sent is not None:
            self.round_trips.append(time.monotonic() - sent)
        awaited = self._awaiting.pop(msg.command, None) is not None
        if msg.result not in (MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS):
            self.rejected.append((self.clock.vehicle_time_s, msg.command, msg.result))
            log.warning("vehicle answered command %d with result %d", msg.command, msg.result)
            if awaited:
                self._refusals.append(f"the vehicle refused command {msg.command} (MAV_RESULT {msg.result})")
