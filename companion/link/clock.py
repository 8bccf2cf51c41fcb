"""The vehicle clock: vehicle time from telemetry, blocking waits on it, lockstep (SPEC C1).

Every timer of the companion runs on the autopilot's ``time_boot_ms`` (SPEC C1, "Vehicle time, not
wall-clock"), so the same code runs at 1× on a vehicle and at 50× against the simulator. The wall
clock appears only as guards: a wait whose vehicle clock stops (a silent link) gives up after
``LinkTimeouts.wall_guard_s``, and such wall-clock decisions are counted (``wall_timeouts``) so a
run can say it was not exact.

Lockstep (docs/PROTOCOL.md "Lockstep"): with a simulator started with ``--lockstep`` the companion
acknowledges every processed sample with SYSTEM_TIME(time_boot_ms) and the simulator never runs
ahead of it, which makes a rehearsal a function of its seed alone.
"""
from __future__ import annotations

import collections
import logging
import math
import time
from dataclasses import dataclass
from typing import Any, Callable

from companion.checks import require_positive
from companion.link.transport import Transport

log = logging.getLogger(__name__)

#: a link that discarded a corrupt frame this recently (wall seconds) is taken as damaging frames
DAMAGE_MEMORY_S = 5.0
MAV_CMD_REQUEST_MESSAGE = 512
MSG_ID_SYSTEM_TIME = 2


@dataclass(frozen=True)
class LinkTimeouts:
    """Timeouts of the blocking calls: vehicle seconds per try, with wall-clock guards."""

    param_try_s: float = 1.0  # vehicle time per PARAM_SET / PARAM_REQUEST_READ try
    mode_s: float = 3.0  # vehicle time for the heartbeat to show a mode / armed state
    command_s: float = 1.0  # vehicle time per COMMAND_LONG try awaiting its ACK
    wall_guard_s: float = 3.0  # wall-clock guard of one try when the vehicle clock stops
    # A try also lasts at least this much wall clock: the round trip of a request is a property of
    # the link and of how far the companion lags behind the stream, not of the vehicle clock. At 1x
    # the vehicle-time budget dominates; at 50x a companion a few tens of ms behind would otherwise
    # time out (and then read the late echo as a refusal of its next write).
    min_try_wall_s: float = 0.5
    heartbeat_period_s: float = 1.0  # our HEARTBEAT, vehicle time
    # lockstep: wall seconds with nothing received while waiting before acknowledging again (a lost
    # acknowledgement or sample would otherwise stall vehicle time for good; a lossless link never
    # goes that long without a frame)
    lockstep_stall_s: float = 1.0
    # ... on a link that damages frames (a serial radio losing bytes: VehicleClock.unstall), where a
    # stall is a loss, not a slow vehicle
    lockstep_lossy_stall_s: float = 0.1
    reconnect_s: float = 10.0  # wall seconds a restore waits for a closed TCP link to come back

    def __post_init__(self) -> None:
        for name in ("param_try_s", "mode_s", "command_s", "wall_guard_s", "heartbeat_period_s",
                     "lockstep_stall_s", "lockstep_lossy_stall_s", "reconnect_s"):
            require_positive(self, name)
        if not (math.isfinite(self.min_try_wall_s) and self.min_try_wall_s >= 0.0):
            raise ValueError(f"LinkTimeouts.min_try_wall_s must be a finite number ≥ 0, not {self.min_try_wall_s!r}")


class VehicleClock:
    """Vehicle time (seconds of ``time_boot_ms``), waits on it, and the lockstep acknowledgements."""

    def __init__(self, transport: Transport, timeouts: LinkTimeouts, *, lockstep: bool = False) -> None:
        self.transport = transport
        self.timeouts = timeouts
        self.lockstep = lockstep
        self.vehicle_time_s: float = math.nan
        self.last_sample_ms: float | None = None  # time_boot_ms of the newest accepted attitude sample
        self.sample_period_ms = 50  # the median spacing of recent samples
        self._spacings: collections.deque[float] = collections.deque(maxlen=21)  # ms between recent samples
        # the attitude period the companion asked the vehicle for (the handshake's stream request):
        # what a lockstep simulator runs past an acknowledgement, and what a stalled lockstep steps on
        self.requested_period_ms: float | None = None
        self.acked_ms = -1
        self._nudged_ms: int | None = None  # the last acknowledgement re-sent after a stall
        self._last_nudge_wall = -math.inf
        self._bytes_acked = 0  # bytes received when the last acknowledgement was sent (or sent again)
        self._losses_acked = 0  # frames lost or discarded on the link by then
        self._corrupt_seen, self._corrupt_wall = 0, -math.inf  # frames discarded as corrupt, and when last
        # wall-clock decisions, counted so a run can say it was not exact: blocking waits ended by
        # their wall-clock guard (the vehicle clock stalled) and lockstep re-acknowledgements
        self.wall_timeouts = 0
        self.reboots = 0  # times the vehicle's clock went back (it rebooted) since we connected
        self._tick_listeners: list[Callable[[float], None]] = []
        transport.on("SYSTEM_TIME", self._on_system_time)
        transport.on_reconnect(self._resume_lockstep)

    def on_tick(self, listener: Callable[[float], None]) -> None:
        """Call ``listener(vehicle_time_s)`` whenever vehicle time is advanced (heartbeats...)."""
        self._tick_listeners.append(listener)

    # ------------------------------------------------------------------ time
    def advance(self, time_ms: float) -> None:
        """Vehicle time moves forward to ``time_ms`` (never back: a reboot is :meth:`restart`)."""
        time_s = time_ms / 1000.0
        if not math.isfinite(self.vehicle_time_s) or time_s > self.vehicle_time_s:
            self.vehicle_time_s = time_s
        for listener in self._tick_listeners:
            listener(self.vehicle_time_s)

    def sample(self, time_ms: float) -> None:
        """An attitude sample stamped ``time_ms`` was accepted: the newest sample, then advance."""
        if self.last_sample_ms is not None:
            # the median: a lost sample (or a stream re-requested out of phase) makes one spacing
            # longer (or shorter), not the period
            self._spacings.append(min(max(time_ms - self.last_sample_ms, 1), 1000))
            self.sample_period_ms = int(sorted(self._spacings)[len(self._spacings) // 2])
        self.last_sample_ms = time_ms
        self.advance(time_ms)

    def restart(self, time_ms: float) -> None:
        """The vehicle's clock went back (a reboot): start again from ``time_ms``."""
        self.last_sample_ms = time_ms
        self.vehicle_time_s = time_ms / 1000.0
        self.acked_ms = -1
        self.reboots += 1

    def _on_system_time(self, msg: Any) -> None:
        if self.transport.from_autopilot(msg) and isinstance(msg.time_boot_ms, int):
            if self.last_sample_ms is None or msg.time_boot_ms >= self.last_sample_ms - 1000:
                self.advance(msg.time_boot_ms)

    # ------------------------------------------------------------------ waiting
    def wait_until(self, done: Callable[[], bool], vehicle_timeout_s: float, wall_guard_s: float | None = None) -> bool:
        """Pump until ``done()``; False after ``vehicle_timeout_s`` of vehicle time or the wall guard."""
        start_vehicle = self.vehicle_time_s
        wall_start = time.monotonic()
        wall_deadline = wall_start + (self.timeouts.wall_guard_s if wall_guard_s is None else wall_guard_s)
        while not done():
            # in lockstep the companion never lags the stream (the simulator waits for it), so the
            # wall-clock minimum would only let the vehicle run on for a machine-dependent time
            if (math.isfinite(start_vehicle) and self.vehicle_time_s - start_vehicle >= vehicle_timeout_s
                    and (self.lockstep or time.monotonic() - wall_start >= self.timeouts.min_try_wall_s)):
                return False
            if not math.isfinite(start_vehicle) and math.isfinite(self.vehicle_time_s):
                start_vehicle = self.vehicle_time_s  # vehicle clock appeared while waiting
            remaining = wall_deadline - time.monotonic()
            if remaining <= 0.0:
                self.wall_timeouts += 1  # a wall-clock decision: counted, so a run can say it was not exact
                return False
            self.transport.pump(min(remaining, 0.1))
            if self.lockstep:
                # blocked on an answer: let the simulator run on (a real vehicle would); 0 before any
                # sample starts a simulator that waits at t = 0 for its companion
                self.acknowledge(int(self.last_sample_ms) if self.last_sample_ms is not None else 0)
                self.unstall()
        return True

    # ------------------------------------------------------------------ lockstep
    def acknowledge(self, time_ms: int) -> None:
        """SYSTEM_TIME(time_boot_ms) to a --lockstep simulator: samples up to here are processed."""
        if time_ms > self.acked_ms:
            self.acked_ms = time_ms
            self._sent_acknowledgement()
            self.transport.mav.system_time_send(0, time_ms & 0xFFFFFFFF)

    def unstall(self) -> None:
        """Lockstep over a link that loses frames: a lost acknowledgement leaves the simulator
        waiting at its limit, and a lost sample leaves the companion waiting for one the simulator
        will not send before the next acknowledgement, so vehicle time would stop for good. After
        ``timeouts.lockstep_stall_s`` of wall clock with nothing received the last acknowledgement
        is sent again (a lost one is replaced), and if that was already done, one sample period
        further (a lost sample is skipped).

        On a link that damages frames (:meth:`_damaging`: a serial radio losing bytes) a stall is a
        loss, not a slow vehicle, and is broken after the shorter ``timeouts.lockstep_lossy_stall_s``:

        * whole frames hidden in the parser behind a damaged one are read first
          (``Transport.resynchronise``);
        * when the vehicle answered the last acknowledgement (bytes came after it, whole frames or
          not) but its sample did not, one sample period further at once (the sample was lost).

        A step goes at least to the vehicle time last heard in any of the autopilot's frames (its
        samples may all have been lost; with none heard yet, SYSTEM_TIME is asked for with
        MAV_CMD_REQUEST_MESSAGE), and one sent again unanswered no further than one sample period
        past it: the simulator ignores an acknowledgement more than two periods ahead of its clock (it
        would be of a previous boot), so acknowledgements lost one after another would otherwise stop
        vehicle time for good. A period is the one the handshake asked for (``requested_period_ms``),
        else the samples' median spacing. A wall-clock decision, so it is counted in
        ``wall_timeouts``; a lossless link never stalls that long."""
        now = time.monotonic()
        damaging = self._damaging(now)
        stall = self.timeouts.lockstep_stall_s
        if damaging:
            stall = min(stall, self.timeouts.lockstep_lossy_stall_s)
        if now - max(self.transport.last_rx_wall, self._last_nudge_wall) < stall:
            return
        if self.transport.unparsed_bytes > 0 and self.transport.resynchronise():
            self._last_nudge_wall = now  # whole frames were hidden behind a damaged one: read them first
            return
        base = max(self.acked_ms, 0)
        answered = self.transport.bytes_received != self._bytes_acked
        heard = [t for t in (self.last_sample_ms, self.transport.heard_time_ms) if t is not None]
        period = int(self.requested_period_ms) if self.requested_period_ms else self.sample_period_ms
        if (damaging and answered) or self._nudged_ms == base:
            # one period on, or to the vehicle time last heard (its samples lost since), whichever is later
            target = max(base + period, int(max(heard)) if heard else 0)
            if not answered and heard:
                target = min(target, max(base, int(max(heard)) + period))
        else:
            target = base
        if not heard:  # nothing of the vehicle's clock heard (its first samples lost): ask for it
            self.transport.command_long(MAV_CMD_REQUEST_MESSAGE, (float(MSG_ID_SYSTEM_TIME),))
        self.acked_ms = self._nudged_ms = target
        self._sent_acknowledgement()
        self._last_nudge_wall = now
        self.wall_timeouts += 1
        log.info("lockstep stalled %.1f s: acknowledging t=%d ms again", now - self.transport.last_rx_wall, target)
        self.transport.mav.system_time_send(0, target & 0xFFFFFFFF)

    def _sent_acknowledgement(self) -> None:
        self._bytes_acked = self.transport.bytes_received
        self._losses_acked = self._link_losses()

    def _link_losses(self) -> int:
        """Frames the link lost or discarded so far (``companion.link.frame_loss``)."""
        return self.transport.frame_loss.lost + self.transport.frame_loss.corrupt

    def _damaging(self, now: float) -> bool:
        """The link damages frames: some were lost or discarded since the last acknowledgement, part
        of a frame waits in the parser (on a stalled lockstep link nothing more is on its way), or
        frames were discarded as corrupt within :data:`DAMAGE_MEMORY_S` (a radio damaging what it
        carries to us damages what it carries from us too, where we cannot see it)."""
        corrupt = self.transport.frame_loss.corrupt
        if corrupt != self._corrupt_seen:
            self._corrupt_seen, self._corrupt_wall = corrupt, now
        return (self._link_losses() > self._losses_acked or self.transport.unparsed_bytes > 0
                or now - self._corrupt_wall < DAMAGE_MEMORY_S)

    def _resume_lockstep(self) -> None:
        """After a reconnection a lockstep simulator waits for its new companion: acknowledge again."""
        if self.lockstep and self.acked_ms >= 0:
            self.transport.mav.system_time_send(0, self.acked_ms & 0xFFFFFFFF)
