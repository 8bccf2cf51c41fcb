"""Telemetry snapshots, in order, on the vehicle clock (SPEC C1; docs/PROTOCOL.md "Telemetry").

:class:`TelemetryFeed` folds the telemetry messages into snapshots (``companion.link.snapshot``),
lets the autopilot's strategy complete each one (``refine``: a read-back it must un-mix, a servo it
must model), and queues every snapshot: an estimator must see no holes, so snapshots completed
while another call was blocking are returned first by the next :meth:`TelemetryFeed.wait` /
:meth:`TelemetryFeed.pop`. ATTITUDE drives the vehicle clock; a ``time_boot_ms`` that jumps back by
more than a second is a reboot (VehicleRebooted), a repeated or older one is dropped.
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
TELEMETRY_TYPES = ("SERVO_OUTPUT_RAW", "LOCAL_POSITION_NED", "VFR_HUD", "SCALED_PRESSURE", "GLOBAL_POSITION_INT")


class TelemetryFeed:
    """Snapshots from the vehicle's telemetry, queued in order (module docstring)."""

    def __init__(self, transport: Transport, clock: VehicleClock) -> None:
        self.transport = transport
        self.clock = clock
        self.assembler: TelemetryAssembler | None = None  # set once the profile is known
        self.refine: Callable[[Telemetry], Telemetry] | None = None  # the strategy's per-snapshot completion
        self._after_snapshot: list[Callable[[], None]] = []
        # bounded (SNAPSHOT_QUEUE_MAX, ~100 s at 20 Hz) so a caller that never reads cannot grow it forever
        self._unread: collections.deque[Telemetry] = collections.deque(maxlen=SNAPSHOT_QUEUE_MAX)
        self.snapshots_dropped = 0
        self._returned_ms: int | None = None
        transport.on("ATTITUDE", self._on_attitude)
        for message_type in TELEMETRY_TYPES:
            transport.on(message_type, self._on_telemetry)

    def after_snapshot(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` after each snapshot is queued (override refresh...)."""
        self._after_snapshot.append(listener)

    def use(self, assembler: TelemetryAssembler, first_heartbeat: Any = None) -> None:
        """Start assembling snapshots (the profile is known)."""
        self.assembler = assembler
        if first_heartbeat is not None:
            assembler.on_message(first_heartbeat)

    # ------------------------------------------------------------------ receiving
    def _on_attitude(self, msg: Any) -> None:
        if not self.transport.from_autopilot(msg):
            return
        time_ms = getattr(msg, "time_boot_ms", None)
        numeric = isinstance(time_ms, (int, float))
        last = self.clock.last_sample_ms
        if numeric and last is not None:
            if time_ms < last - 1000:
                self.clock.restart(time_ms)
                raise VehicleRebooted(f"time_boot_ms went back from {last} to {time_ms}: the vehicle rebooted")
            if time_ms <= last:
                return  # duplicate or reordered sample
        if self.assembler is None:
            if numeric:
                self.clock.advance(time_ms)
            return
        snapshot = self.assembler.on_message(msg)
        if numeric and math.isfinite(time_ms):
            self.clock.sample(time_ms)
        if snapshot is not None:
            self._queue(snapshot)

    def _on_telemetry(self, msg: Any) -> None:
        if self.assembler is not None and self.transport.from_vehicle(msg):
            snapshot = self.assembler.on_message(msg)  # ArduPilot: SERVO_OUTPUT_RAW completes a snapshot
            if snapshot is not None:
                self._queue(snapshot)

    def on_heartbeat(self, msg: Any) -> None:
        """The autopilot's HEARTBEAT carries the mode and armed state of the next snapshots."""
        if self.assembler is not None:
            self.assembler.on_message(msg)

    def _queue(self, snapshot: Telemetry) -> None:
        if self.refine is not None:
            snapshot = self.refine(snapshot)
            self.assembler.latest = snapshot
        if len(self._unread) == SNAPSHOT_QUEUE_MAX:
            self.snapshots_dropped += 1
            if self.snapshots_dropped == 1 or self.snapshots_dropped % 1000 == 0:
                log.warning("telemetry not read: %d old snapshots dropped", self.snapshots_dropped)
        self._unread.append(snapshot)
        for listener in self._after_snapshot:
            listener()

    # ------------------------------------------------------------------ reading
    def wait(self, timeout_s: float) -> None:
        """Block until a snapshot is queued; LinkLost after ``timeout_s`` of wall clock without one.
        In lockstep, everything the last snapshot asked for has been sent: acknowledge it first."""
        if self.clock.lockstep:  # 0: start the waiting simulator
            self.clock.acknowledge(self._returned_ms if self._returned_ms is not None else 0)
        deadline = time.monotonic() + timeout_s
        while not self._unread:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                silent = time.monotonic() - self.transport.last_rx_wall
                raise LinkLost(f"no telemetry snapshot for {timeout_s:g} s of wall clock "
                               f"(last message of any kind {silent:.1f} s ago)")
            if self.clock.lockstep:  # wake in time to notice a stall
                self.transport.pump(min(remaining, 0.5, self.clock.timeouts.lockstep_stall_s / 2.0))
                self.clock.unstall()
            else:
                self.transport.pump(min(remaining, 0.5))

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

    def servo_pwm(self) -> list[float]:
        """The latest SERVO_OUTPUT_RAW, outputs 1..16 in µs (empty before the first one)."""
        return list(self.assembler.servo_pwm) if self.assembler is not None else []
