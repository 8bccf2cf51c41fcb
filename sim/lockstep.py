"""Lockstep with the companion: vehicle time advances only as the companion acknowledges it
(docs/PROTOCOL.md, "Lockstep"; docs/reproducibility.md, "same seed, same numbers").

The companion (component 191) acknowledges the sample it has finished acting on with SYSTEM_TIME
(``time_boot_ms``). The simulator may then run one attitude period past it — to the next sample —
and no further. Two rules make a rehearsal a function of its seed alone, whatever the speed-up,
the machine's load or the scheduling of the two processes:

* **Vehicle time waits at its start** until the first acknowledgement: the companion's connection
  (heartbeat, parameter reads, stream requests) is answered at t = 0, however long it takes.
* **Input is applied only at the limit** (``SimServer`` reads the socket only when the physics has
  reached the last tick it may reach): a message the companion sent after acknowledging sample A
  and before acknowledging sample B acts at the tick after A plus one period, never "whenever the
  simulator happened to read it". The server stops applying input at the acknowledgement that
  raises the limit; what follows waits for the next limit.

When a TCP companion disconnects, vehicle time waits again, as at the start, for the next one
(whose first acknowledgement engages from where the vehicle is). A reboot is simulated in lockstep
too: the autopilot's silence and its new boot's first sample run without acknowledgements
(``hold_until``: there is nothing to acknowledge meanwhile), then the companion's acknowledgements of
the new boot's clock step it on; an acknowledgement of the old boot's clock that arrives after the
new boot began lies far ahead of the vehicle and is ignored. The one wall-clock rule left: a
companion silent for ``SILENCE_S`` (it hung, or a UDP client left) releases the vehicle, which then
free-runs so that other clients keep a live vehicle, until a companion acknowledges again.
``stats`` counts such *interruptions* that a companion came back from, and the ticks they ran
free, so a run can say whether it was exact.
"""
from __future__ import annotations

import logging
import math

log = logging.getLogger(__name__)

COMPONENT = 191  # MAV_COMP_ID_ONBOARD_COMPUTER: the companion
SILENCE_S = 30.0  # wall seconds without an acknowledgement before the companion is taken as gone


class Lockstep:
    """The acknowledgement state of one simulator (``enabled`` False: always free-running)."""

    def __init__(self, enabled: bool, dt: float) -> None:
        self.enabled = enabled
        self.dt = dt
        self.acked_tick: int | None = None  # last tick the companion acknowledged (None: none yet)
        self.engaged = False  # a companion is acknowledging
        self.released = False  # a companion was engaged and left: free-run until the next one
        self.last_ack_wall = 0.0
        self.client: object | None = None  # the TCP client the acknowledgements come from
        #: a tick the physics may reach without acknowledgements (a rebooting autopilot's silence and
        #: its new boot's first sample: nothing to acknowledge meanwhile); None: none
        self.hold_until: int | None = None
        self.stats: dict[str, float | int | None] = {"engaged_at_s": None, "acks": 0, "interruptions": 0,
                                                     "free_ticks": 0}
        self._free_since_release = 0  # ticks run free since the last release (counted if a companion returns)

    def limit(self, tick: int, lead_ticks: int, now: float) -> int | None:
        """The last tick the physics may reach now; None to free-run."""
        if not self.enabled:
            return None
        if self.engaged:
            if now - self.last_ack_wall > SILENCE_S:
                self.release(f"no acknowledgement for {SILENCE_S:g} s of wall clock")
                return None
            return max(self.acked_tick + lead_ticks, self.hold_until if self.hold_until is not None else -1)
        if self.released:
            return None
        return tick  # before the first acknowledgement vehicle time waits at its start

    def acknowledge(self, time_boot_ms: float, tick: int, now: float, client: object | None = None,
                    boot_tick: int = 0, max_ahead: int | None = None) -> bool:
        """Take a SYSTEM_TIME acknowledgement of this boot's ``time_boot_ms`` (the boot began at
        ``boot_tick``); True when it is valid. A companion acknowledges at most a sample or so ahead
        of what it received (its stall rule steps one sample on): an acknowledgement more than
        ``max_ahead`` ticks ahead of the vehicle is of the previous boot's clock (the companion had not
        yet heard the new boot) and is ignored."""
        if not self.enabled or not math.isfinite(time_boot_ms):
            return False
        acked = boot_tick + int(math.floor(time_boot_ms / (self.dt * 1000.0) + 1e-6))
        if max_ahead is not None and acked > tick + max_ahead:
            return False
        if not self.engaged:
            # first acknowledgement (or a new companion after a release): from here, or from where the
            # vehicle already is when it was released
            self.acked_tick = max(acked, tick)
            self.engaged = True
            if self.released:  # a companion acknowledges again after the vehicle ran free
                self.stats["interruptions"] += 1
                self.stats["free_ticks"] += self._free_since_release
                self._free_since_release = 0
            self.released = False
            if self.stats["engaged_at_s"] is None:
                self.stats["engaged_at_s"] = round(self.acked_tick * self.dt, 6)
            log.info("lockstep engaged at t=%.2f", self.acked_tick * self.dt)
        else:
            self.acked_tick = max(self.acked_tick, acked)
        self.stats["acks"] += 1
        self.last_ack_wall = now
        self.client = client
        return True

    def release(self, why: str) -> None:
        """The companion left: free-run until a companion acknowledges again."""
        if not self.engaged:
            return
        self.engaged = False
        self.released = True
        self.client = None
        log.warning("lockstep released (%s): vehicle time runs free until a companion acknowledges again", why)

    def client_left(self, client: object) -> None:
        """A TCP client disconnected: if it was the acknowledging companion, vehicle time waits for
        the next companion where it is (nothing runs free, nothing burns the CPU meanwhile)."""
        if self.engaged and client is not None and client is self.client:
            self.engaged = False
            self.client = None
            log.info("the lockstep companion disconnected: vehicle time waits for the next one at t=%.2f",
                     self.acked_tick * self.dt)

    def count_free(self, ticks: int) -> None:
        """Ticks stepped without lockstep after a release (counted when a companion comes back)."""
        if self.enabled and self.released:
            self._free_since_release += ticks
