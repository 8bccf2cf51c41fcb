"""A mission's own course changes as heading steps, or its turn-rate requests as segments, and the
verdict on learned gains (eq. L.2). Pure.

**Turns.** A turn starts when the heading set-point the autopilot reports jumps by at least
``min_step_deg`` within one sample; it is complete after ``turn_s`` seconds without another jump
(an interrupted turn is dropped: it was not a step). Its figures are those of a flown step
(:func:`companion.numerics.step_response.step_metrics`): overshoot in % of the change and the
integrated absolute error normalised by the change (``iae_s``, seconds), from the set-point before
the jump to the one after.

**Turn-rate segments** (a navigation that asks the rate loop for a turn rate: ArduRover in AUTO).
A segment is cut at the mission's own turns: it opens when the asked-for turn rate reaches
``min_rate_deg_s``, with the ``lead_s`` seconds before it (the rate loop's state before the turn, which
a replay starts from), and closes once the asked-for rate has stayed below ``min_rate_deg_s`` for
``quiet_s`` seconds, or after ``window_s`` seconds of turning (the next segment then opens at once).
So each turn of a lane-end corner (two 90° turns a short leg apart) is a segment of its own, where
fixed windows fell across the corner at a phase the clock chose: one segment or two. A closed
segment whose asked-for rate has an RMS below ``min_rate_deg_s`` (a blip) is dropped. The legs are
counted apart, on consecutive ``window_s`` windows of the stream: one whose asked-for rate has an RMS
below ``min_rate_deg_s`` is a straight (eq. L.2h), brief asks included. (Measured on SITL's ArduSub
ROV: with the legs taken only between the turns' cut, every leg window holding a brief ask of 2°/s
was lost, and learned gains whose heading loop asked for more on the lanes lost exactly their worse
windows: kept with the lanes held 2.2× worse.) A
segment's figure is the RMS of the
tracking error (deg/s) over the samples that asked for no more than the rudder can give (a
fraction of the model's steady turn rate at full rudder): beyond it the rudder is at its stop
whatever the gains, and a lane-end turn asking for 100°/s of a boat that turns at 17°/s would
otherwise decide the verdict by its saturation alone. Its prediction replays the asked-for rate
through the rate loop on the model (``simulate_rate_tracking``).

**eq. L.2: the verdict.** The learned gains are judged on ``after`` (turns flown on them) against
``before`` (turns flown on the original gains in the same speed band) and their prediction:

* *not worse*: mean flown IAE after ≤ mean flown IAE before (without turns before, the original
  gains' predicted IAE at the same changes stands in, said in the reason); for turn-rate segments the
  original gains' replay on the same asked-for rates is the reference (other legs ask for other
  rates: a lane-end turn asks for more than any rudder gives, a straight for almost nothing);
* *as predicted*: the mean flown figure after within ``error_tolerance`` (relative) of its prediction,
  and the worst flown overshoot at most ``overshoot_margin_pct`` points above the worst predicted.

Either failing reverts, with the figure that failed. The speed loop's learned gains are judged by the
same rule on speed-change segments (``SPEED_ERROR``, eq. L.4: ``companion.numerics.mission_speed``).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from companion.checks import require_non_negative, require_positive
from .angles import wrap_pi
from .step_figures import StepFigures
from .step_response import step_metrics


#: the figure of merit of a course change (IAE/|Δψ|) and of a turn-rate segment (RMS tracking error)
STEP_ERROR, RATE_ERROR = "step error s", "turn-rate error deg/s"
#: the figure of merit of a speed-change segment (RMS speed-tracking error of the speed loop, eq. L.4)
SPEED_ERROR = "speed error m/s"
#: each metric's name and unit in a verdict's words, and what its replay is asked for
_METRIC_WORDS = {STEP_ERROR: ("step error", "s", "course changes"),
                 RATE_ERROR: ("turn-rate error", "deg/s", "turn rates"),
                 SPEED_ERROR: ("speed error", "m/s", "speeds")}


@dataclass(frozen=True)
class TurnFigures:
    """One flown turn (a course change, or a turn-rate segment): when, at what speed, how large (deg,
    or the asked-for rate's RMS in deg/s), on which gains, and its figure of merit (``metric``):
    flown, predicted for the gains flown, and predicted for the original gains."""

    t_start: float
    speed: float
    size: float
    gains: str  # "original" or "learned"
    error: float
    overshoot_pct: float = math.nan  # a course change's only
    predicted_error: float = math.nan
    predicted_overshoot_pct: float = math.nan
    original_error: float = math.nan
    metric: str = STEP_ERROR

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

    def figures(self) -> StepFigures:
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
class FlownSegment:
    """A turn-rate segment's samples (rad/s): times, asked-for and measured turn rate, mean speed, and
    the rudder at its start (rad; NaN when unknown): the state a replay starts from."""

    t_start: float
    times: np.ndarray
    desired: np.ndarray
    achieved: np.ndarray
    speed: float
    rudder0: float = math.nan

    @property
    def size_deg_s(self) -> float:
        return math.degrees(float(np.sqrt(np.mean(self.desired ** 2))))

    def error_deg_s(self, achieved: np.ndarray | None = None, within: float = math.inf) -> float:
        """RMS of asked-for minus measured (or ``achieved``, a prediction) turn rate, deg/s, over the
        samples that asked for at most ``within`` rad/s (NaN when none did)."""
        got = self.achieved if achieved is None else achieved
        kept = np.abs(self.desired) <= within
        if not kept.any():
            return math.nan
        return math.degrees(float(np.sqrt(np.mean((self.desired[kept] - got[kept]) ** 2))))

    def seconds_within(self, within: float) -> float:
        """Vehicle seconds of the segment that asked for at most ``within`` rad/s."""
        if self.times.size < 2:
            return 0.0
        step = float(np.median(np.diff(self.times)))
        return step * int(np.count_nonzero(np.abs(self.desired) <= within))


class RateSegmentRecorder:
    """Streams (time, asked-for rate, measured rate, speed, rudder); :meth:`add` returns a
    :class:`FlownSegment` when a turn asked for closes, and keeps the legs' windows in
    :attr:`straights` (module docstring, "Turn-rate segments")."""

    def __init__(self, window_s: float = 20.0, min_rate_deg_s: float = 2.0, max_gap_s: float = 1.0,
                 lead_s: float = 2.0, quiet_s: float = 3.0) -> None:
        if not (window_s > 0 and min_rate_deg_s > 0 and max_gap_s > 0 and lead_s >= 0 and quiet_s > 0):
            raise ValueError("RateSegmentRecorder needs a positive window, rate, gap and quiet time, and a lead ≥ 0")
        self.window_s, self.min_rate, self.max_gap_s = window_s, math.radians(min_rate_deg_s), max_gap_s
        self.lead_s, self.quiet_s = lead_s, quiet_s
        self._lead: deque[tuple[float, float, float, float, float]] = deque()  # the last lead_s s outside a turn
        self._turn: list[tuple[float, float, float, float, float]] = []  # the open segment's rows
        self._calm_since = math.nan  # in a segment: since when the asked-for rate stayed below min_rate
        self._leg: list[tuple[float, float, float]] = []  # the open leg window: (time, asked, measured)
        self._last_t = math.nan
        self.interrupted = 0
        #: the ``window_s`` windows whose asked-for rate has an RMS below ``min_rate`` (the legs, brief
        #: asks included): (start, turn-rate error RMS in deg/s), for how the rate loop holds a leg (eq. L.2h)
        self.straights: list[tuple[float, float]] = []

    @property
    def turning(self) -> bool:
        return bool(self._turn)

    def discard(self) -> None:
        """Drop the open segment and leg window (the gains changed during them)."""
        if self._turn:
            self.interrupted += 1
        self._reset()

    def _reset(self) -> None:
        self._turn, self._leg = [], []
        self._lead.clear()

    def add(self, t: float, desired: float, achieved: float, speed: float,
            rudder: float = math.nan) -> FlownSegment | None:
        if not all(math.isfinite(v) for v in (t, desired, achieved)):
            self._reset()
            return None
        if math.isfinite(self._last_t) and t - self._last_t > self.max_gap_s:
            self._reset()
        self._last_t = t
        self._add_to_leg(t, desired, achieved)
        row = (t, desired, achieved, speed, rudder)
        asking = abs(desired) >= self.min_rate
        if not self._turn:
            if asking:  # a turn opens, with the lead before it
                self._turn, self._calm_since = [*self._lead, row], math.nan
                self._lead.clear()
            else:
                self._lead.append(row)
                while t - self._lead[0][0] > self.lead_s:
                    self._lead.popleft()
            return None
        self._turn.append(row)
        if asking:
            self._calm_since = math.nan
        elif not math.isfinite(self._calm_since):
            self._calm_since = t
        calm = math.isfinite(self._calm_since) and t - self._calm_since >= self.quiet_s
        if not calm and t - self._turn[0][0] < self.window_s:
            return None
        flown, self._turn = np.asarray(self._turn), []
        if calm:  # the calm tail may lead the next turn
            self._lead.extend((t_, d_, a_, s_, r_) for t_, d_, a_, s_, r_ in flown[flown[:, 0] >= t - self.lead_s])
        segment = FlownSegment(float(flown[0, 0]), flown[:, 0], flown[:, 1], flown[:, 2],
                               float(np.nanmean(flown[:, 3])) if np.isfinite(flown[:, 3]).any() else math.nan,
                               float(flown[0, 4]))
        return segment if math.radians(segment.size_deg_s) >= self.min_rate else None

    def _add_to_leg(self, t: float, desired: float, achieved: float) -> None:
        """The legs: consecutive ``window_s`` windows of the stream, whatever the turns' cut; a window
        whose asked-for rate has an RMS below ``min_rate`` is a straight (a brief ask on a leg stays
        in it: a leg flown on gains that make the heading loop ask for more is judged, not dropped)."""
        self._leg.append((t, desired, achieved))
        if t - self._leg[0][0] < self.window_s:
            return
        rows, self._leg = np.asarray(self._leg), []
        if float(np.sqrt(np.mean(rows[:, 1] ** 2))) < self.min_rate:
            self.straights.append((float(rows[0, 0]), math.degrees(float(np.sqrt(np.mean((rows[:, 1] - rows[:, 2]) ** 2))))))


@dataclass(frozen=True)
class VerdictConfig:
    """eq. L.2's tolerances: the prediction's overshoot margin (points, the profile's measured
    margin) and its relative IAE tolerance."""

    overshoot_margin_pct: float = 3.0
    error_tolerance: float = 0.3
    #: eq. L.2h: learned gains are not kept while the legs' turn-rate error on them exceeds the
    #: original gains' by this factor and this many deg/s (measured on SITL's ArduSub ROV: kept gains
    #: that tracked its corners better held its lanes at 0.67–0.69 deg/s against 0.27–0.30)
    holding_ratio: float = 1.5
    holding_floor_deg_s: float = 0.2

    def __post_init__(self) -> None:
        require_non_negative(self, "overshoot_margin_pct", "holding_floor_deg_s")
        require_positive(self, "error_tolerance", "holding_ratio")

    def holding_worse(self, before: Sequence[float], after: Sequence[float]) -> str | None:
        """Why the legs flown on learned gains (``after``: each window's turn-rate error, deg/s) are
        held worse than those on the original gains (``before``) beyond eq. L.2h's tolerance; None
        when they are not, or when either side has no leg."""
        return holding_worse(before, after, self.holding_ratio, self.holding_floor_deg_s, "turn-rate error", "deg/s")


def holding_worse(before: Sequence[float], after: Sequence[float], ratio: float, floor: float, figure: str,
                  unit: str, digits: int = 2) -> str | None:
    """eq. L.2h's rule on any loop's legs: why the mean ``figure`` on the legs flown on learned gains
    (``after``) exceeds ``ratio`` times and ``floor`` more than on the original gains (``before``);
    None when it does not, or when either side has no leg."""
    old, new = _mean(before), _mean(after)
    if not (math.isfinite(old) and math.isfinite(new)):
        return None
    if new > max(ratio * old, old + floor):
        return (f"worse on the legs: {figure} {new:.{digits}f} {unit} on {len(after)} straight windows against "
                f"{old:.{digits}f} {unit} on the original gains ({len(before)})")
    return None


@dataclass(frozen=True)
class TurnVerdict:
    """eq. L.2's outcome with its figures (means over the turns; NaN where none)."""

    keep: bool
    reason: str
    before_error: float
    after_error: float
    predicted_error: float
    after_overshoot_pct: float
    predicted_overshoot_pct: float
    turns_before: int
    turns_after: int
    metric: str = STEP_ERROR

    def to_dict(self) -> dict:
        return {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in self.__dict__.items()}


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def judge_turns(before: Sequence[TurnFigures], after: Sequence[TurnFigures], config: VerdictConfig,
                *, flown_reference: bool = True) -> TurnVerdict:
    """eq. L.2 (module docstring); ValueError without a turn after. ``flown_reference`` False: the
    original gains are judged by their prediction on the very turns flown after (turn-rate segments:
    a navigation asks for other turn rates on other legs, so earlier segments are no like-for-like
    reference)."""
    if not after:
        raise ValueError("no turn flown on the learned gains")
    name, unit, asked = _METRIC_WORDS[after[0].metric]
    after_error = _mean([t.error for t in after])
    predicted = _mean([t.predicted_error for t in after])
    worst_after = max((t.overshoot_pct for t in after if math.isfinite(t.overshoot_pct)), default=math.nan)
    worst_predicted = max((t.predicted_overshoot_pct for t in after if math.isfinite(t.predicted_overshoot_pct)),
                          default=math.nan)
    if before and flown_reference:
        reference, source = _mean([t.error for t in before]), f"{len(before)} flown on the original gains"
    elif not flown_reference:
        reference = _mean([t.original_error for t in after])
        source = f"the original gains replayed on the same {asked}"
    else:
        reference, source = _mean([t.original_error for t in after]), "the original gains' prediction (none flown before)"

    def verdict(keep: bool, reason: str) -> TurnVerdict:
        return TurnVerdict(keep, reason, before_error=reference, after_error=after_error, predicted_error=predicted,
                           after_overshoot_pct=worst_after, predicted_overshoot_pct=worst_predicted,
                           turns_before=len(before), turns_after=len(after), metric=after[0].metric)

    if not (math.isfinite(after_error) and math.isfinite(predicted)):  # fail safe: nothing to judge by
        return verdict(False, f"not as predicted: {name} {after_error:.2f} {unit} flown, no prediction to "
                              "compare with")
    if not after_error <= reference:
        return verdict(False, f"worse than the original gains: {name} {after_error:.2f} {unit} against "
                              f"{reference:.2f} {unit} ({source})")
    if abs(after_error - predicted) > config.error_tolerance * predicted:
        return verdict(False, f"not as predicted: {name} {after_error:.2f} {unit} flown, {predicted:.2f} {unit} "
                              f"predicted (tolerance {100 * config.error_tolerance:.0f} %)")
    if after[0].metric == STEP_ERROR and not worst_after <= worst_predicted + config.overshoot_margin_pct:
        return verdict(False, f"not as predicted: overshoot {worst_after:.1f} % flown, {worst_predicted:.1f} % "
                              f"predicted (margin {config.overshoot_margin_pct:.1f} points)")
    return verdict(True, f"{name} {after_error:.2f} {unit} against {reference:.2f} {unit} ({source}); "
                         f"predicted {predicted:.2f} {unit}")
