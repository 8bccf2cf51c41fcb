"""Seeded random link conditions of one direction of a link: loss, delay, jitter, reordering,
duplication and a byte-rate cap (a radio link, or a router on the way), for the UDP relay
(``harness.udp_relay``; the TCP fault proxy uses the rate cap and the fixed delay).

:class:`LinkConditions` says what the link does; :class:`FateDraws` draws the fate of each datagram
from its own :class:`random.Random` (seeded per direction), always the same number of draws per
datagram, so the fate of the k-th datagram of a direction depends only on the seed, the direction and
k — not on the other direction, on timing, or on what earlier datagrams met. :class:`TokenBucket` is
the rate cap: a token bucket (``rate_bytes_s``, ``burst_bytes``) in front of a bounded queue
(``queue_bytes``); a datagram that does not fit in the queue is dropped, as a radio modem drops what
its buffer cannot hold. Its departure times are computed from arrival times, not from when a loop
happens to wake up.
"""
from __future__ import annotations

import collections
import random
from dataclasses import dataclass

__all__ = ["Fate", "FateDraws", "LinkConditions", "TokenBucket"]

JITTER_SHAPES = ("uniform", "normal")


@dataclass(frozen=True)
class LinkConditions:
    """What one direction of the link does to each datagram.

    ``loss``: probability a datagram is lost. ``delay_s``: fixed delay. ``jitter_s``: added to the
    delay, uniform in ±``jitter_s`` (``jitter_shape`` "uniform") or normal with σ = ``jitter_s``
    ("normal", cut at ±3σ); a total below zero is zero. Datagrams are delivered in the order of their
    delivery times, so jitter larger than the interval between datagrams reorders them.
    ``reorder``: probability a datagram is held back until the next one of its direction has been
    delivered (at most ``reorder_max_s``). ``duplicate``: probability it is delivered twice.
    ``rate_bytes_s``: the byte-rate cap (None: none), with ``burst_bytes`` of credit and a queue of
    ``queue_bytes`` (MAVLink bytes, without IP/UDP headers) beyond which datagrams are dropped."""

    loss: float = 0.0
    delay_s: float = 0.0
    jitter_s: float = 0.0
    jitter_shape: str = "uniform"
    reorder: float = 0.0
    reorder_max_s: float = 0.5
    duplicate: float = 0.0
    rate_bytes_s: float | None = None
    burst_bytes: int = 512
    queue_bytes: int = 4096

    def __post_init__(self) -> None:
        for name in ("loss", "reorder", "duplicate"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"LinkConditions.{name} is a probability (0..1), not {value!r}")
        if self.delay_s < 0 or self.jitter_s < 0 or self.reorder_max_s < 0:
            raise ValueError("LinkConditions: delay_s, jitter_s and reorder_max_s are >= 0")
        if self.jitter_shape not in JITTER_SHAPES:
            raise ValueError(f"LinkConditions.jitter_shape must be one of {JITTER_SHAPES}, not {self.jitter_shape!r}")
        if self.rate_bytes_s is not None and self.rate_bytes_s <= 0:
            raise ValueError("LinkConditions.rate_bytes_s must be > 0 (None: no cap)")
        if self.burst_bytes < 1 or self.queue_bytes < 1:
            raise ValueError("LinkConditions: burst_bytes and queue_bytes are >= 1")

    @property
    def random(self) -> bool:
        """Whether any datagram's fate is drawn (loss, jitter, reordering or duplication)."""
        return bool(self.loss or self.jitter_s or self.reorder or self.duplicate)

    @property
    def clean(self) -> bool:
        return not self.random and not self.delay_s and self.rate_bytes_s is None

    def describe(self) -> str:
        if self.clean:
            return "clean"
        parts = []
        if self.loss:
            parts.append(f"{self.loss * 100:g} % loss")
        if self.delay_s or self.jitter_s:
            spread = (f" ± {self.jitter_s * 1000:g}" if self.jitter_shape == "uniform"
                      else f" (σ {self.jitter_s * 1000:g})") if self.jitter_s else ""
            parts.append(f"{self.delay_s * 1000:g}{spread} ms")
        if self.reorder:
            parts.append(f"{self.reorder * 100:g} % reordered")
        if self.duplicate:
            parts.append(f"{self.duplicate * 100:g} % duplicated")
        if self.rate_bytes_s is not None:
            parts.append(f"≤ {self.rate_bytes_s:g} B/s (queue {self.queue_bytes} B)")
        return ", ".join(parts)


@dataclass(frozen=True)
class Fate:
    """What the link does to one datagram."""

    lost: bool
    duplicate: bool
    reorder: bool
    delay_s: float  # delay + jitter, >= 0


class FateDraws:
    """The fates of one direction's datagrams, in order (module docstring: four draws per datagram)."""

    def __init__(self, conditions: LinkConditions, seed: int) -> None:
        self.conditions = conditions
        self.rng = random.Random(seed)
        self.drawn = 0

    def next(self) -> Fate:
        c, rng = self.conditions, self.rng
        lost, duplicate, reorder, spread = rng.random(), rng.random(), rng.random(), rng.random()
        self.drawn += 1
        if c.jitter_shape == "normal":
            jitter = c.jitter_s * max(-3.0, min(3.0, _normal_quantile(spread)))
        else:
            jitter = c.jitter_s * (2.0 * spread - 1.0)
        return Fate(lost < c.loss, duplicate < c.duplicate, reorder < c.reorder, max(0.0, c.delay_s + jitter))


def _normal_quantile(u: float) -> float:
    """The standard normal quantile of ``u`` (one uniform draw per datagram, whatever the shape)."""
    from statistics import NormalDist

    return NormalDist().inv_cdf(min(max(u, 1e-12), 1.0 - 1e-12))


class TokenBucket:
    """A byte-rate cap in front of a bounded FIFO queue (module docstring). :meth:`admit` gives the
    departure time of a datagram arriving at ``now`` (None: the queue is full, it is dropped).

    A datagram leaves once the bucket holds min(its size, ``burst_bytes``) tokens; it then takes its
    whole size (the balance may go below zero), so the long-run rate is ``rate_bytes_s`` whatever the
    sizes. The queue holds the bytes admitted but not yet departed; a datagram is always admitted to
    an empty queue."""

    def __init__(self, rate_bytes_s: float, burst_bytes: int = 512, queue_bytes: int = 4096) -> None:
        self.rate = float(rate_bytes_s)
        self.burst = float(burst_bytes)
        self.queue_bytes = queue_bytes
        self._tokens = self.burst
        self._time: float | None = None  # when the balance was last settled
        self._queue: collections.deque[tuple[float, int]] = collections.deque()  # (departure, size)
        self._queued = 0
        self.admitted = 0
        self.dropped = 0

    def admit(self, size: int, now: float) -> float | None:
        while self._queue and self._queue[0][0] <= now:
            self._queued -= self._queue.popleft()[1]
        if self._queue and self._queued + size > self.queue_bytes:
            self.dropped += 1
            return None
        last = now if self._time is None else self._time
        start = max(now, last)
        tokens = min(self.burst, self._tokens + (start - last) * self.rate)
        need = min(float(size), self.burst)
        if tokens < need:
            start += (need - tokens) / self.rate
            tokens = need
        self._tokens, self._time = tokens - size, start
        self._queue.append((start, size))
        self._queued += size
        self.admitted += 1
        return start

    @property
    def queued_bytes(self) -> int:
        return self._queued
