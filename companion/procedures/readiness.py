"""Is the vehicle ready for a procedure, and is the link good enough for one? (expected conditions,
said in a sentence before anything is changed).

* **Ready**: the autopilot's strategy says why a procedure cannot start yet (ArduRover without a
  position estimate refuses GUIDED); the companion waits for it, telling the operator, for a bounded
  vehicle time, then refuses with the reason.
* **Link rate**: the attitude samples per second and bytes per second the link delivers, measured
  over a few vehicle seconds. Identification needs at least :data:`MIN_SAMPLE_HZ` samples a second
  (below, the doublet's switches fall between samples and the record sampling rule rejects records
  anyway); below the rate the autopilot profile asks for, the operator is told what to change.
* **Link losses**: the fraction of those samples the link lost (against the median interval, as
  the record sampling rule counts them, ``companion.numerics.sampling``). Above
  :data:`MAX_PROBE_MISSING` identification is refused before anything is changed: records losing
  that much move the identified a22 by up to 5.5 % and b2 by 4.7 % (``python
  bench/bench_sampling_gaps.py --seeds 6``: random 20 % loss), beyond the clean-link spread of a22
  over seeds (2–4 %) — the models would be biased by the link, not the water. Between the record
  rule's 10 % and this bound the campaign flies, and records that lose too much are flown again.
  The bound is above the record rule's because the probe is short: 40 samples at a true 10 % loss
  read above 20 % less than once in a hundred probes (binomial).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

from companion.link.port import VehiclePort
from companion.numerics.sampling import sampling_quality

log = logging.getLogger(__name__)

MIN_SAMPLE_HZ = 10.0
MAX_PROBE_MISSING = 0.20  # fraction of the probe's samples lost beyond which identification is refused
READY_PATIENCE_S = 60.0  # vehicle seconds waited for a vehicle that is not ready yet


@dataclass(frozen=True)
class LinkRate:
    """What the link delivered over ``seconds`` of vehicle time."""

    samples_per_s: float
    bytes_per_s: float
    seconds: float
    wanted_hz: float
    missing: float = 0.0  # fraction of the samples the median interval implies that never came
    max_gap_s: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.missing <= 1.0:
            raise ValueError(f"a link's missing fraction is within [0, 1], not {self.missing}")

    def verdict(self) -> str | None:
        """None when identification can run, else why not (one sentence saying what to do)."""
        if self.samples_per_s >= MIN_SAMPLE_HZ:
            if self.missing <= MAX_PROBE_MISSING:
                return None
            return (f"the link lost {100 * self.missing:.0f} % of the attitude samples over {self.seconds:.1f} s "
                    f"(longest gap {self.max_gap_s:.2f} s); above {100 * MAX_PROBE_MISSING:.0f} % the identified "
                    "model moves by up to 5 % with the losses alone: fix the link first (a radio's range or "
                    "interference, its air rate, a serial port's baud rate, or connect through a MAVLink router)")
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
                "wanted_hz": self.wanted_hz, "missing": self.missing, "max_gap_s": self.max_gap_s}


def measure_link_rate(link: VehiclePort, seconds: float = 2.0) -> LinkRate:
    """Read telemetry for ``seconds`` of vehicle time and count what arrived (bounded by the link's
    own silence watchdog)."""
    bytes_before = link.transport.bytes_received
    wall_before = time.monotonic()
    link.skip_to_now()
    first = link.next_telemetry()
    count, last, times = 0, first, [first.time_s]
    while last.time_s - first.time_s < seconds:
        last = link.next_telemetry()
        count += 1
        times.append(last.time_s)
    elapsed = max(last.time_s - first.time_s, 1e-6)
    wall = max(time.monotonic() - wall_before, 1e-6)
    speedup = elapsed / wall  # bytes per vehicle second: a simulator at N x sends N times the wall rate
    received = link.transport.bytes_received - bytes_before
    streams = link.autopilot.streams
    sampling = sampling_quality(times)
    missing = sampling.missing if math.isfinite(sampling.missing) else 0.0
    return LinkRate(samples_per_s=count / elapsed, bytes_per_s=received / wall / max(speedup, 1e-6),
                    seconds=elapsed, wanted_hz=float(streams.get(30, 20.0)), missing=min(1.0, missing),
                    max_gap_s=sampling.max_gap_s if math.isfinite(sampling.max_gap_s) else 0.0)


def await_ready(link: VehiclePort, patience_s: float = READY_PATIENCE_S, tell=None) -> str | None:
    """Wait (vehicle time) until the strategy has no objection; None when ready, else the last
    objection after ``patience_s``. ``tell(text)`` hears each new objection once."""
    not_ready = link.autopilot.not_ready
    latest = link.latest_telemetry
    if latest is not None and not_ready(latest) is None:
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
