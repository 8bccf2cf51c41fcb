"""The simulator's loop: vehicle time paced against the wall clock (docs/PROTOCOL.md, "Transport").

Physics run at ``dt`` of vehicle time in batches of at most ``MAX_TICKS_PER_POLL`` steps, incoming
MAVLink is applied between batches. ``speedup`` paces vehicle time against ``time.monotonic()`` —
the only place in the simulator that reads a wall clock. If the machine cannot keep up it runs as
fast as it can, drops the backlog instead of bursting, and logs the achieved ratio.

Vehicle time also waits: for a TCP client that has fallen behind (lossless transport), and under
lockstep (sim/lockstep.py) for the companion's acknowledgement. With lockstep input is read only
when the physics has reached the last tick the companion allows, so every message acts at a
vehicle time fixed by the companion's own stream, never by scheduling.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Protocol

from sim.lockstep import Lockstep

# the achieved-ratio lines are the endpoint's (bench/bench_sim_speed.py finds them by this name)
log = logging.getLogger("sim.server")

MAX_TICKS_PER_POLL = 10  # physics steps between two polls of the socket
MAX_BACKLOG_S = 0.25  # wall seconds behind schedule before the pacing drops the backlog
REPORT_EVERY_S = 10.0  # wall seconds between achieved-ratio log lines


class Simulation(Protocol):
    """What the loop steps and asks (``SimServer``)."""

    tick: int
    lockstep: Lockstep

    @property
    def stopping(self) -> bool:
        """The loop should end."""

    def step(self) -> None:
        """One physics step of ``dt`` (and the streams due at the new tick)."""

    def lead_ticks(self) -> int:
        """How far past the acknowledged sample the physics may run under lockstep."""

    def poll(self) -> None:
        """Free-running: apply what has arrived."""

    def poll_at_limit(self) -> bool:
        """Lockstep, at the limit: apply input until the limit moves; True when the physics may move on."""


class Transport(Protocol):
    """The waits the loop needs from the clients (:class:`sim.routing.Clients`)."""

    def backlogged(self) -> bool: ...

    def wait_readable(self, timeout: float) -> None: ...

    def wait_writable(self, timeout: float) -> None: ...


@dataclass(frozen=True)
class Pace:
    """How vehicle time runs: ``speedup`` times the wall clock (0: as fast as possible), for
    ``duration`` seconds of vehicle time (None: until stopped)."""

    dt: float
    speedup: float = 1.0
    duration: float | None = None

    @property
    def end_tick(self) -> int | None:
        return None if self.duration is None else int(round(self.duration / self.dt))


def run_paced(sim: Simulation, transport: Transport, pace: Pace) -> float:
    """Step ``sim`` until it is stopping or ``pace.duration`` has passed; returns the wall seconds."""
    dt = pace.dt
    speedup = pace.speedup
    paced = speedup > 0
    end_tick = pace.end_tick
    wall_start = time.monotonic()
    base_wall, base_tick = wall_start, 0
    report_wall, report_tick = wall_start, 0
    step = sim.step
    lockstep = sim.lockstep
    while not sim.stopping:
        now = time.monotonic()
        if paced:
            due = base_tick + int((now - base_wall) * speedup / dt)
            if due - sim.tick > MAX_BACKLOG_S * speedup / dt:
                # Cannot keep up: drop the backlog rather than burst to catch up later.
                base_wall, base_tick = now, sim.tick
                due = sim.tick + 1
        else:
            due = sim.tick + MAX_TICKS_PER_POLL
        batch_end = min(due, sim.tick + MAX_TICKS_PER_POLL)
        if end_tick is not None:
            batch_end = min(batch_end, end_tick)
        limit = lockstep.limit(sim.tick, sim.lead_ticks(), now)
        if limit is not None:
            batch_end = min(batch_end, max(sim.tick, limit))
        if transport.backlogged():
            # A TCP client is behind: vehicle time waits for it (lossless, flow-controlled).
            transport.wait_writable(0.005)
            batch_end = sim.tick
        first = sim.tick
        while sim.tick < batch_end:
            step()
        if limit is None:
            lockstep.count_free(sim.tick - first)
            sim.poll()
        elif sim.tick >= limit:
            # Lockstep: input is applied only here, at the last tick the companion allows.
            if not sim.poll_at_limit():
                if end_tick is not None and sim.tick >= end_tick:
                    break
                transport.wait_readable(0.05)  # the companion has not acknowledged yet: wait for it
                continue
        if end_tick is not None and sim.tick >= end_tick:
            break
        if now - report_wall >= REPORT_EVERY_S:
            log_ratio("running", now - report_wall, (sim.tick - report_tick) * dt, speedup)
            report_wall, report_tick = now, sim.tick
        if paced and sim.tick >= due:
            wait = base_wall + (sim.tick + 1 - base_tick) * dt / speedup - time.monotonic()
            if wait > 0:
                if limit is None:
                    transport.wait_readable(min(wait, 0.05))
                else:
                    time.sleep(min(wait, 0.05))  # input waits for the limit anyway
    return time.monotonic() - wall_start


def log_ratio(label: str, wall_s: float, sim_s: float, target: float) -> None:
    """Log the achieved vehicle/wall ratio against the ``target`` speed-up (a warning below 90 %)."""
    if wall_s <= 0:
        return
    ratio = sim_s / wall_s
    level = logging.WARNING if target > 0 and ratio < 0.9 * target else logging.INFO
    log.log(level, "%s: %.1f s vehicle in %.1f s wall = %.1fx (target %s)", label, sim_s,
            wall_s, ratio, f"{target:g}x" if target > 0 else "as fast as possible")
