"""Is the vehicle ready for a procedure, and is the link good enough for one? (expected conditions,
said in a sentence before anything is changed).

* **Ready**: the autopilot's strategy says why a procedure cannot start yet (ArduRover without a
  position estimate refuses GUIDED); the companion waits for it, telling the operator, for a bounded
  vehicle time, then refuses with the reason.
* **Link rate**: the attitude samples per second and bytes per second the link delivers, measured
  over a few vehicle seconds. Identification needs at least :data:`MIN_SAMPLE_HZ` samples a second
  (below, the doublet's switches fall between samples and the record sampling rule rejects records
  anyway); below the rate the autopilot profile asks for, the operator is told what to change.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

log = logging.getLogger(__name__)

MIN_SAMPLE_HZ = 10.0
READY_PATIENCE_S = 60.0  # vehicle seconds waited for a vehicle that is not ready yet


@dataclass(frozen=True)
class LinkRate:
    """What the link delivered over ``seconds`` of vehicle time."""

    samples_per_s: float
    bytes_per_s: float
    seconds: float
    wanted_hz: float

    def verdict(self) -> str | None:
        """None when identification can run, else why not (one sentence saying what to do)."""
        if self.samples_per_s >= MIN_SAMPLE_HZ:
            return None
        return (f"the link delivers {self.samples_per_s:.1f} attitude samples per second "
                f"({self.bytes_per_s / 1000:.1f} kB/s); identification needs at least {MIN_SAMPLE_HZ:g} "
                f"({self.wanted_hz:g} asked for): raise the telemetry link's rate (on ArduPilot its "
                "SERIALn_BAUD) or connect through a MAVLink router on the companion computer")

    def warning(self) -> str | None:
        """A slower link than asked for, that still works: worth saying."""
        if self.verdict() is None and self.samples_per_s < 0.8 * self.wanted_hz:
            return (f"the link delivers {self.samples_per_s:.1f} attitude samples per second, "
                    f"{self.wanted_hz:g} were asked for")
        return None

    def as_json(self) -> dict:
        return {"samples_per_s": self.samples_per_s, "bytes_per_s": self.bytes_per_s, "seconds": self.seconds,
                "wanted_hz": self.wanted_hz}


def measure_link_rate(link, seconds: float = 2.0) -> LinkRate:
    """Read telemetry for ``seconds`` of vehicle time and count what arrived (bounded by the link's
    own silence watchdog)."""
    transport = getattr(link, "transport", None)
    bytes_before = getattr(transport, "bytes_received", 0)
    wall_before = time.monotonic()
    link.skip_to_now()
    first = link.next_telemetry()
    count, last = 0, first
    while last.time_s - first.time_s < seconds:
        last = link.next_telemetry()
        count += 1
    elapsed = max(last.time_s - first.time_s, 1e-6)
    wall = max(time.monotonic() - wall_before, 1e-6)
    speedup = elapsed / wall  # bytes per vehicle second: a simulator at N x sends N times the wall rate
    received = getattr(transport, "bytes_received", 0) - bytes_before
    streams = getattr(getattr(link, "autopilot", None), "streams", {}) or {}
    return LinkRate(samples_per_s=count / elapsed, bytes_per_s=received / wall / max(speedup, 1e-6),
                    seconds=elapsed, wanted_hz=float(streams.get(30, 20.0)))


def await_ready(link, patience_s: float = READY_PATIENCE_S, tell=None) -> str | None:
    """Wait (vehicle time) until the strategy has no objection; None when ready, else the last
    objection after ``patience_s``. ``tell(text)`` hears each new objection once."""
    strategy = getattr(link, "autopilot", None)
    not_ready = getattr(strategy, "not_ready", None)
    if not callable(not_ready):
        return None
    latest = getattr(link, "latest_telemetry", None)
    if latest is not None and not callable(latest) and not_ready(latest) is None:
        return None  # ready now: nothing is read, nothing waited for
    start = math.nan
    said = None
    while True:
        telemetry = link.next_telemetry()
        start = telemetry.time_s if math.isnan(start) else start
        objection = not_ready(telemetry)
        if objection is None:
            return None
        if objection != said:
            said = objection
            log.warning("waiting: %s", objection)
            if tell is not None:
                tell(f"waiting: {objection}")
        if telemetry.time_s - start >= patience_s:
            return objection
