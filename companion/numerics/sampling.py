"""Whether a record's sampling is good enough to identify from (link quality, pure).

The state-variable filter is discretised at each actual sample interval (eq. 3.26–3.28), so an
uneven record is filtered exactly as long as the signals are close to their hold between samples;
a long gap across a doublet switch is not. A record is judged by the time stamps it holds, against
its own nominal period (the median interval): the fraction of samples missing and the longest gap.

The rule's thresholds are measured (``bench/bench_sampling_gaps.py``: full STARFISH training records
identified again with samples taken out, 18 records): random loss of 10 % moved a22 by at most
1.5 % and b2 by 0.9 %, 20 % by up to 5.5 % and 4.7 %; one gap across the doublet's switch moved a22
by under 1 % up to 0.20 s, 1.8 % at 0.25 s, 2.8 % at 0.30 s and 15 % at 1 s. The clean-link spread
of a22 over seeds is about 2–4 %, so a record passes with at most 10 % of its samples missing and
no gap longer than 0.25 s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from companion.checks import require_positive, require_range


@dataclass(frozen=True)
class SamplingRule:
    """The most a record may miss and still be used (module docstring)."""

    max_missing_fraction: float = 0.10
    max_gap_s: float = 0.25

    def __post_init__(self) -> None:
        require_range(self, "max_missing_fraction", 0.0, 1.0)
        require_positive(self, "max_gap_s")


@dataclass(frozen=True)
class SamplingQuality:
    """How a record was sampled: ``samples`` held, the ``period_s`` they were sent at (median
    interval), the fraction ``missing`` of the samples that period implies, the longest gap."""

    samples: int
    period_s: float
    missing: float
    max_gap_s: float

    def verdict(self, rule: SamplingRule) -> str | None:
        """None when the record may be used, else why not (one sentence)."""
        if self.samples < 3 or not math.isfinite(self.period_s):
            return f"only {self.samples} samples"
        problems = []
        if self.missing > rule.max_missing_fraction:
            problems.append(f"{self.missing:.0%} of its samples lost (at most {rule.max_missing_fraction:.0%})")
        if self.max_gap_s > rule.max_gap_s:
            problems.append(f"a {self.max_gap_s:.2f} s gap (at most {rule.max_gap_s:.2f} s)")
        return "the link lost too much of the record: " + " and ".join(problems) if problems else None

    def as_json(self) -> dict:
        return {"samples": self.samples, "period_s": self.period_s, "missing": self.missing,
                "max_gap_s": self.max_gap_s}


def sampling_quality(times: Sequence[float]) -> SamplingQuality:
    """The sampling of a record from its time stamps (seconds, increasing)."""
    if len(times) < 3:
        return SamplingQuality(len(times), math.nan, math.nan, math.nan)
    intervals = sorted(b - a for a, b in zip(times, times[1:]))
    period = intervals[len(intervals) // 2]
    if not period > 0.0:
        return SamplingQuality(len(times), math.nan, math.nan, math.nan)
    expected = (times[-1] - times[0]) / period + 1.0
    missing = max(0.0, 1.0 - len(times) / expected)
    return SamplingQuality(len(times), period, missing, intervals[-1])
