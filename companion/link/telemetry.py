"""Telemetry snapshots, in order, on the vehicle clock (SPEC C1; docs/PROTOCOL.md "Telemetry").

:class:`TelemetryFeed` folds the telemetry messages into snapshots (``companion.link.snapshot``),
lets the autopilot's strategy complete each one (``refine``: a read-back it must un-mix, a servo it
must model), and queues every snapshot: an estimator must see no holes, so snapshots completed
while another call was blocking are returned first by the next :meth:`TelemetryFeed.wait` /
:meth:`TelemetryFeed.pop`. ATTITUDE drives the vehicle clock; a ``time_boot_ms`` that jumps back by
more than a second, confirmed by the next sample continuing the new clock, is a reboot
(VehicleRebooted; a single stray stamp is dropped, counted); one that arrives after a newer sample is placed
in order while it still can be (the assembler holds snapshots briefly once the link has reordered)
and dropped, counted, when it cannot; a repeated one is dropped.
"""
from __future__ import annotations

import collections
import logging
import math
import time
from typing import Any, Callable

from companion.interface import Telemetry
from companion.link.clock import VehicleClock
from companion.link.errors import LinkLost, VehicleRebooted
from companion.link.snapshot import TelemetryAssembler
from companion.link.transport import Transport

log = logging.getLogger(__name__)

SNAPSHOT_QUEUE_MAX = 2000
#: once the link has delivered an attitude sample late, complete snapshots are held this many sample
#: periods before they are returned, so a late sample can still be placed in order
REORDER_HOLD_SAMPLES = 2
#: ... at most this long (ms of vehicle time), whatever the sample period
REORDER_HOLD_MAX_MS = 250.0
#: ... and no longer after this many samples in a row arrived in order (the link recovered)
REORDER_CALM_SAMPLES = 400
TELEMETRY_TYPES = ("SERVO_OUTPUT_RAW", "LOCAL_POSITION_NED", "VFR_HUD", "SCALED_PRESSURE", "GLOBAL_POSITION_INT",
                   "NAV_CONTROLLER_OUTPUT", "PID_TUNING")


class TelemetryFeed:
    """Snapshots from the vehicle's telemetry, queued in order (module docstring)."""

    def __init__(self, transport: Transport, clock: VehicleClock) -> None:
        self.transport = transport
        self.clock = clock
        self.assembler: TelemetryAssembler | None = None  # set once the profile is known
        self.refine: Callable[[Telemetry], Telemetry] | None = None  # the strategy's per-snapshot completion
        self._after_snapshot: list[Callable[[], None]] = []
        self._reboot_listeners: list[Callable[[], None]] = []
        # bounded (SNAPSHOT_QUEUE_MAX, ~100 s at 20 Hz) so a caller that never reads cannot grow it forever
        self._unread: collections.deque[Telemetry] = collections.deque(maxlen=SNAPSHOT_QUEUE_MAX)
        self.snapshots_dropped = 0
        # link quality, counted as the samples arrive: attitude samples that came after a newer one
        # (reordered; dropped, the estimator needs time order) or twice (duplicated; dropped)
        self.samples_late = 0
        self.samples_dropped_late = 0
        self.samples_duplicate = 0
        self.samples_accepted = 0
        self._returned_ms: int | None = None
        self._spacings: collections.deque[float] = collections.deque(maxlen=21)  # ms between in-order samples
        self._in_order_run = 0  # samples in a row that arrived in order
        self.reboot: str | None = None  # a reboot seen and not yet reported by wait()
        # an attitude sample stamped more than a second before the newest: a reboot if the next
        # one continues its clock, else a stray (a corrupted or very late frame), dropped
        self._reboot_candidate_ms: float | None = None
        self.samples_stray = 0
        transport.on("ATTITUDE", self._on_attitude)
        for message_type in TELEMETRY_TYPES:
            transport.on(message_type, self._on_telemetry)

    def after_snapshot(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` after each snapshot is queued (override refresh...)."""
        self._after_snapshot.append(listener)

    def stop_calling(self, listener: Callable[[], None]) -> None:
        """No longer call ``listener`` (a no-op when it is not listening)."""
        if listener in self._after_snapshot:
            self._after_snapshot.remove(listener)

    def on_reboot(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` when a reboot of the vehicle is recognised (before it is reported)."""
        self._reboot_listeners.append(listener)

    def use(self, assembler: TelemetryAssembler, first_heartbeat: Any = None) -> None:
        """Start assembling snapshots (the profile is known)."""
        self.assembler = assembler
        assembler.wait_for_outputs = not self.clock.lockstep
        if first_heartbeat is not None:
            assembler.on_message(first_heartbeat)

    # ------------------------------------------------------------------ receiving
    def _on_attitude(self, msg: Any) -> None:
        if not self.transport.from_autopilot(msg):
            return
        time_ms: float = math.nan
        stamp = getattr(msg, "time_boot_ms", None)
        if isinstance(stamp, (int, float)) and math.isfinite(stamp):
            time_ms = stamp
        numeric = math.isfinite(time_ms)
        last = self.clock.last_sample_ms
        if numeric and last is not None and time_ms < last - 1000:
            if not self._confirms_reboot(time_ms):
                return
            self._rebooted(last, time_ms)
            last = self.clock.last_sample_ms
        elif numeric and self._reboot_candidate_ms is not None:
            self._reboot_candidate_ms = None  # the clock went on: the candidate was a stray
            self.samples_stray += 1
        if self.assembler is None:
            if numeric:
                self.clock.advance(time_ms)
            return
        if numeric and last is not None and time_ms <= last:
            if time_ms == last or not self.assembler.accepts(time_ms):
                self._count_unplaced(time_ms == last)
                return
            self.samples_late += 1  # late, but still placed in order
            self._hold_for_late_samples()
        done = self.assembler.take(msg)
        if numeric:
            self.samples_accepted += 1
            if last is None or time_ms > last:
                if last is not None:
                    self._spacings.append(time_ms - last)
                self.clock.sample(time_ms)
                self._calm_down()
        for snapshot in done:
            self._queue(snapshot)

    def _confirms_reboot(self, time_ms: float) -> bool:
        """A stamp far behind the clock: the second of two consecutive ones, the later continuing the
        earlier's clock (within 2 s), confirms a reboot; the first is held as a candidate and a
        candidate not confirmed was a stray sample."""
        candidate = self._reboot_candidate_ms
        if candidate is not None and candidate < time_ms <= candidate + 2000.0:
            self._reboot_candidate_ms = None
            return True
        if candidate is not None:
            self.samples_stray += 1
        self._reboot_candidate_ms = time_ms
        return False

    def _rebooted(self, last_ms: float, time_ms: float) -> None:
        """The vehicle's clock went back: it rebooted. The clock and the assembler start again,
        snapshots of the old boot are dropped, and the next :meth:`wait` raises VehicleRebooted
        (once): a procedure stops there, while a restore under way carries on with the new boot."""
        self.clock.restart(time_ms)
        if self.assembler is not None:
            self.assembler.restart()
        self._unread.clear()
        self._returned_ms = None
        self.reboot = f"time_boot_ms went back from {last_ms:.0f} to {time_ms:.0f}: the vehicle rebooted"
        log.warning("%s", self.reboot)
        for listener in self._reboot_listeners:
            listener()

    def _count_unplaced(self, duplicate: bool) -> None:
        """A sample repeated, or arriving after newer snapshots were returned: dropped, counted."""
        if duplicate:
            self.samples_duplicate += 1
        else:
            self.samples_late += 1
            self.samples_dropped_late += 1
            self._hold_for_late_samples()

    @property
    def nominal_period_ms(self) -> float:
        """The stream's sample period: the median spacing of recent in-order samples (a lost sample
        makes one spacing long, not the median)."""
        spacings = sorted(self._spacings)
        return spacings[len(spacings) // 2] if spacings else float(self.clock.sample_period_ms)

    def _hold_for_late_samples(self) -> None:
        """From now on, hold complete snapshots a little (REORDER_HOLD_SAMPLES nominal periods, at
        most REORDER_HOLD_MAX_MS) so later late samples find their place. Not in lockstep: the
        simulator sends the next sample only once the last one returned is acknowledged, so a held
        snapshot would wait for a sample that never comes."""
        self._in_order_run = 0
        if self.assembler is not None and not self.clock.lockstep:
            hold = min(REORDER_HOLD_SAMPLES * self.nominal_period_ms, REORDER_HOLD_MAX_MS)
            self.assembler.hold_ms = max(self.assembler.hold_ms, hold)

    def _calm_down(self) -> None:
        """A link that has delivered REORDER_CALM_SAMPLES samples in order since its last late one is
        no longer held (20 s at 20 Hz): a single burst of reordering does not cost latency for good."""
        self._in_order_run += 1
        if self.assembler is not None and self.assembler.hold_ms > 0.0 and self._in_order_run >= REORDER_CALM_SAMPLES:
            log.info("telemetry in order for %d samples: snapshots no longer held", self._in_order_run)
            self.assembler.hold_ms = 0.0

    def _on_telemetry(self, msg: Any) -> None:
        if self.assembler is not None and self.transport.from_vehicle(msg):
            for snapshot in self.assembler.take(msg):  # an output message can complete waiting snapshots
                self._queue(snapshot)

    def on_heartbeat(self, msg: Any) -> None:
        """The autopilot's HEARTBEAT carries the mode and armed state of the next snapshots."""
        if self.assembler is not None:
            self.assembler.on_message(msg)

    def _queue(self, snapshot: Telemetry) -> None:
        if self.refine is not None:
            snapshot = self.refine(snapshot)
            if self.assembler is not None:  # set: snapshots come only from the assembler
                self.assembler.latest = snapshot
        if len(self._unread) == SNAPSHOT_QUEUE_MAX:
            self.snapshots_dropped += 1
            if self.snapshots_dropped == 1 or self.snapshots_dropped % 1000 == 0:
                log.warning("telemetry not read: %d old snapshots dropped", self.snapshots_dropped)
        self._unread.append(snapshot)
        for listener in list(self._after_snapshot):  # a listener may stop listening while called
            listener()

    # ------------------------------------------------------------------ reading
    def wait(self, timeout_s: float) -> None:
        """Block until a snapshot is queued; LinkLost after ``timeout_s`` of wall clock without one.
        In lockstep, everything the last snapshot asked for has been sent: acknowledge it first."""
        if self.clock.lockstep:  # 0: start the waiting simulator
            self.clock.acknowledge(self._returned_ms if self._returned_ms is not None else 0)
        deadline = time.monotonic() + timeout_s
        while not self._unread:
            self._report_reboot()
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                silent = time.monotonic() - self.transport.last_rx_wall
                raise LinkLost(f"no telemetry snapshot for {timeout_s:g} s of wall clock "
                               f"(last message of any kind {silent:.1f} s ago)")
            if self.clock.lockstep:  # wake in time to notice a stall
                timeouts = self.clock.timeouts
                self.transport.pump(min(remaining, 0.5, timeouts.lockstep_stall_s / 2.0,
                                        timeouts.lockstep_lossy_stall_s / 2.0))
                self.clock.unstall()
            else:
                self.transport.pump(min(remaining, 0.5))
        self._report_reboot()

    def _report_reboot(self) -> None:
        if self.reboot is not None:
            reason, self.reboot = self.reboot, None
            raise VehicleRebooted(reason)

    def pop(self) -> Telemetry:
        """The oldest queued snapshot (call :meth:`wait` first)."""
        snapshot = self._unread.popleft()
        self._returned_ms = int(round(snapshot.time_s * 1000.0))
        return snapshot

    @property
    def pending(self) -> int:
        """Snapshots received but not yet returned."""
        return len(self._unread)

    def skip_to_now(self) -> int:
        """Drop the queued snapshots (the next one returned is newer than anything seen so far);
        returns how many were dropped."""
        dropped = len(self._unread)
        self._unread.clear()
        return dropped

    @property
    def latest(self) -> Telemetry | None:
        """The most recent snapshot (whether or not it was returned yet)."""
        return self.assembler.latest if self.assembler else None

    def quality(self) -> dict:
        """Link quality as the attitude samples arrived: accepted, late (reordered), duplicated, and
        snapshots released without their own output sample (it was lost); and as the vehicle's frames
        arrived (``companion.link.frame_loss``): received, lost on the link (sequence gaps), late,
        repeated, discarded as corrupt (and their bytes), and the fraction lost."""
        lost_outputs = self.assembler.released_without_outputs if self.assembler is not None else 0
        frame_loss = self.transport.frame_loss
        return {"samples": self.samples_accepted, "late": self.samples_late,
                "late_dropped": self.samples_dropped_late, "duplicate": self.samples_duplicate,
                "outputs_lost": lost_outputs, "dropped_unread": self.snapshots_dropped, "stray": self.samples_stray,
                "hold_ms": self.assembler.hold_ms if self.assembler is not None else 0.0,
                **frame_loss.counts()}

    def servo_pwm(self) -> list[float]:
        """The latest SERVO_OUTPUT_RAW, outputs 1..16 in µs (empty before the first one)."""
        return list(self.assembler.servo_pwm) if self.assembler is not None else []
