"""A mission's own course changes as heading steps, and the verdict on learned gains (eq. L.2). Pure.

**Turns.** A turn starts when the heading set-point the autopilot reports jumps by at least
``min_step_deg`` within one sample; it is complete after ``turn_s`` seconds without another jump
(an interrupted turn is dropped: it was not a step). Its figures are those of a flown step
(:func:`companion.numerics.step_response.step_metrics`): overshoot in % of the change and the
integrated absolute error normalised by the change (``iae_s``, seconds), from the set-point before
the jump to the one after.

**eq. L.2: the verdict.** The learned gains are judged on ``after`` (turns flown on them) against
``before`` (turns flown on the original gains in the same speed band) and their prediction:

* *not worse*: mean flown IAE after ≤ mean flown IAE before (without turns before, the original
  gains' predicted IAE at the same changes stands in, said in the reason);
* *as predicted*: the mean flown IAE after within ``iae_tolerance`` (relative) of its prediction,
  and the worst flown overshoot at most ``overshoot_margin_pct`` points above the worst predicted.

Either failing reverts, with the figure that failed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from companion.checks import require_non_negative, require_positive
from .angles import wrap_pi
from .step_response import step_metrics


@dataclass(frozen=True)
class TurnFigures:
    """One flown turn: when, at what speed, how large, on which gains, and what it scored (flown, and
    predicted for the gains flown and for the original gains when a prediction was made)."""

    t_start: float
    speed: float
    step_deg: float
    gains: str  # "original" or "learned"
    iae_s: float
    overshoot_pct: float
    predicted_iae_s: float = math.nan
    predicted_overshoot_pct: float = math.nan
    original_iae_s: float = math.nan  # the original gains' predicted IAE for this change

    def to_dict(self) -> dict:
        return {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in self.__dict__.items()}


@dataclass
class _Turn:
    t_start: float
    start: float  # unwrapped set-point before the jump
    target: float  # unwrapped set-point after it
    times: list[float] = field(default_factory=list)
    heading: list[float] = field(default_factory=list)
    speeds: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class FlownTurn:
    """A complete turn's samples: times, unwrapped heading, set-points before and after (unwrapped)."""

    t_start: float
    times: np.ndarray
    heading: np.ndarray
    start: float
    target: float
    speed: float

    @property
    def step(self) -> float:
        return self.target - self.start

    def figures(self) -> dict:
        return step_metrics(self.times, self.heading, self.start, self.target)


class TurnRecorder:
    """Streams (time, heading, set-point, speed); :meth:`add` returns a :class:`FlownTurn` when one
    completes (module docstring)."""

    def __init__(self, min_step_deg: float = 10.0, turn_s: float = 25.0, max_gap_s: float = 1.0) -> None:
        if not (min_step_deg > 0 and turn_s > 0 and max_gap_s > 0):
            raise ValueError("TurnRecorder needs a positive step, turn length and gap")
        self.min_step = math.radians(min_step_deg)
        self.turn_s = turn_s
        self.max_gap_s = max_gap_s
        self._last: tuple[float, float] | None = None  # (time, set-point) of the last sample
        self._turn: _Turn | None = None
        self.interrupted = 0

    @property
    def turning(self) -> bool:
        return self._turn is not None

    def discard(self) -> None:
        """Drop the turn being recorded (the gains changed during it)."""
        if self._turn is not None:
            self.interrupted += 1
        self._turn = None

    def add(self, t: float, heading: float, target: float, speed: float) -> FlownTurn | None:
        if not all(math.isfinite(v) for v in (t, heading, target)):
            self._last, self._turn = None, None
            return None
        last, self._last = self._last, (t, target)
        if last is None or t - last[0] > self.max_gap_s:
            self._turn = None
            return None
        jump = wrap_pi(target - last[1])
        if abs(jump) >= self.min_step:
            if self._turn is not None:
                self.interrupted += 1
            start = heading + wrap_pi(last[1] - heading)  # the set-point before, near the heading
            self._turn = _Turn(t_start=t, start=start, target=start + jump)
        turn = self._turn
        if turn is None:
            return None
        previous = turn.heading[-1] if turn.heading else turn.start
        turn.times.append(t)
        turn.heading.append(previous + wrap_pi(heading - previous))
        turn.speeds.append(speed)
        if t - turn.t_start < self.turn_s:
            return None
        self._turn = None
        speeds = [s for s in turn.speeds if math.isfinite(s)]
        return FlownTurn(turn.t_start, np.asarray(turn.times), np.asarray(turn.heading), turn.start, turn.target,
                         float(np.mean(speeds)) if speeds else math.nan)


@dataclass(frozen=True)
class VerdictConfig:
    """eq. L.2's tolerances: the prediction's overshoot margin (points, the profile's measured
    margin) and its relative IAE tolerance."""

    overshoot_margin_pct: float = 3.0
    iae_tolerance: float = 0.3

    def __post_init__(self) -> None:
        require_non_negative(self, "overshoot_margin_pct")
        require_positive(self, "iae_tolerance")


@dataclass(frozen=True)
class TurnVerdict:
    """eq. L.2's outcome with its figures (means over the turns; NaN where none)."""

    keep: bool
    reason: str
    before_iae_s: float
    after_iae_s: float
    predicted_iae_s: float
    after_overshoot_pct: float
    predicted_overshoot_pct: float
    turns_before: int
    turns_after: int

    def to_dict(self) -> dict:
        return {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in self.__dict__.items()}


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def judge_turns(before: Sequence[TurnFigures], after: Sequence[TurnFigures], config: VerdictConfig) -> TurnVerdict:
    """eq. L.2 (module docstring); ValueError without a turn after."""
    if not after:
        raise ValueError("no turn flown on the learned gains")
    after_iae = _mean([t.iae_s for t in after])
    predicted = _mean([t.predicted_iae_s for t in after])
    worst_after = max(t.overshoot_pct for t in after)
    worst_predicted = max((t.predicted_overshoot_pct for t in after if math.isfinite(t.predicted_overshoot_pct)),
                          default=math.nan)
    if before:
        reference, source = _mean([t.iae_s for t in before]), f"{len(before)} turns flown on the original gains"
    else:
        reference, source = _mean([t.original_iae_s for t in after]), "the original gains' prediction (no turn before)"
    figures = dict(before_iae_s=reference, after_iae_s=after_iae, predicted_iae_s=predicted,
                   after_overshoot_pct=worst_after, predicted_overshoot_pct=worst_predicted,
                   turns_before=len(before), turns_after=len(after))
    if not after_iae <= reference:
        return TurnVerdict(False, f"worse than the original gains: step error {after_iae:.2f} s against "
                                  f"{reference:.2f} s ({source})", **figures)
    if math.isfinite(predicted) and abs(after_iae - predicted) > config.iae_tolerance * predicted:
        return TurnVerdict(False, f"not as predicted: step error {after_iae:.2f} s flown, {predicted:.2f} s "
                                  f"predicted (tolerance {100 * config.iae_tolerance:.0f} %)", **figures)
    if math.isfinite(worst_predicted) and worst_after > worst_predicted + config.overshoot_margin_pct:
        return TurnVerdict(False, f"not as predicted: overshoot {worst_after:.1f} % flown, {worst_predicted:.1f} % "
                                  f"predicted (margin {config.overshoot_margin_pct:.1f} points)", **figures)
    return TurnVerdict(True, f"step error {after_iae:.2f} s against {reference:.2f} s ({source}); predicted "
                             f"{predicted:.2f} s", **figures)
