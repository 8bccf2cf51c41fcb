"""Tuning while the vehicle works: the heading gains learned, written and verified from an ordinary
mission's own course changes (``companion run --learn``). A step function of vehicle time and
telemetry that never asks for a manoeuvre: it only writes gains, at safe moments.

Phases (:class:`Phase`):

1. **learning** — every closed window of the passive estimator goes to the speed bands of
   :class:`companion.numerics.parameter_tracking.MissionModels` (eq. L.1); every completed turn is
   kept as flown on the original gains: a course change (``verification="course_changes"``,
   :class:`companion.numerics.mission_turns.TurnRecorder`: an autopilot that reports its heading
   set-point) or a turn-rate segment (``"turn_rate"``, ``RateSegmentRecorder``: a navigation that asks
   the rate loop for turn rates, ArduRover in AUTO, whose rate loop carries the turns). When the set of validated bands grows, the ``designer`` is asked (the campaign's
   design by prediction, eq. D.1, under the autopilot's own controller with the original gains as a
   candidate). A design predicted no better than the original gains is said and nothing is written.
2. **waiting to write** — the design's gains at the current speed are written at the next *safe
   moment*: the mode is one in which the autopilot steers itself (``LearningConfig.modes``; never a
   mode the pilot flies by hand) and has been for ``steady_s``, the vehicle is on a straight — its
   heading changed by less than ``max_turn_rate_deg_s`` on average over ``steady_s`` (a turn is a net
   change of course; a boat weaving about a straight leg is on it) — and, where the autopilot
   reports its heading set-point, the heading stayed within ``max_heading_error_deg`` of it. A turn
   whose record is still open then is dropped: it would be flown on two gain sets. Each write is announced by STATUSTEXT and queued as an event for the store.
3. **verifying** — the next ``verify_turns`` course changes (``verify_segments`` turn-rate
   segments) are judged against the turns flown on the original gains at the same speed and
   against their prediction (eq. L.2); from ``min_verify`` on, the verdict comes early when each
   turn alone gives the same verdict as all of them together. Turn-rate segments also need the
   legs held no worse than on the original gains (eq. L.2h): a keep waits for a leg flown on the
   learned gains. Kept: **kept**.
   Else **waiting to revert**, then the original gains are written at the next safe moment:
   **reverted**, and this session writes nothing more (the reason is said and stored). Kept gains
   are those verified at the speed flown: they are not rescheduled to speeds the turns did not
   verify.

A ground station may accept (the verification ends, the gains stay) or revert at any time
(:meth:`MissionLearner.accept`, :meth:`MissionLearner.revert`; ``companion run`` maps them onto
MAV_CMD_USER_4). A revert asked for by the ground station is written at once: the operator chose
the moment.
"""
from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Callable, Protocol, Sequence

from behaviors.base import Behaviour, Footprint
from behaviors.learning_records import GainWrite, Phase
from behaviors.mission_speed import SpeedLearner, SpeedLearningConfig, SpeedLearningResult
import numpy as np

from companion.checks import require_choice, require_positive
from companion.interface import Command, SetParameters, StatusText, Telemetry
from companion.numerics.angles import wrap_pi
from companion.numerics.drift import DriftConfig, PassiveYawEstimator
from companion.numerics.identification import YawModel
from companion.numerics.mission_turns import (RATE_ERROR, STEP_ERROR, FlownSegment, FlownTurn, RateSegmentRecorder,
                                              TurnFigures, TurnRecorder, TurnVerdict, VerdictConfig, judge_turns)
from companion.numerics.parameter_tracking import MissionModels, TrackingConfig, WindowOutcome

log = logging.getLogger(__name__)


class LearnedDesign(Protocol):
    """What the designer hands over: the gains at a speed, a predicted step under the autopilot's
    controller for any gains (normalised IAE s, overshoot %), and the predicted turn-rate error (RMS
    deg/s) of its rate loop asked for a flown segment's turn rates (``replay``: the turn rates it would
    achieve) and the steady turn rate the rudder gives at full deflection (``rate_limit``, rad/s)."""

    @property
    def summary(self) -> str: ...

    def gains_at(self, speed: float) -> dict[str, float]: ...

    def predict(self, gains: dict[str, float], speed: float, step: float) -> tuple[float, float]: ...

    def replay(self, gains: dict[str, float], speed: float, segment: FlownSegment) -> np.ndarray: ...

    def rate_limit(self, speed: float) -> float: ...


@dataclass(frozen=True)
class DesignOutcome:
    """The designer's answer over the validated bands: a design to write, or None with the reason."""

    design: LearnedDesign | None
    reason: str
    original_best: bool = False  # no design because the vehicle's own gains are predicted best


Designer = Callable[[Sequence[tuple[float, YawModel]]], DesignOutcome]


@dataclass(frozen=True)
class LearningConfig:
    """When to write and how to verify (module docstring)."""

    modes: tuple[str, ...] = ("auto", "guided", "hold")
    verification: str = "course_changes"  # or "turn_rate" (module docstring)
    window: DriftConfig = DriftConfig()
    tracking: TrackingConfig = TrackingConfig()
    min_step_deg: float = 10.0
    turn_s: float = 25.0
    verify_turns: int = 3
    segment_s: float = 20.0  # a turn-rate segment
    min_segment_rate_deg_s: float = 2.0
    # a segment is judged where it asked for at most this fraction of the rudder's full-deflection
    # turn rate, and only if that leaves ``min_segment_s`` of it
    rate_fraction: float = 0.8
    min_segment_s: float = 5.0
    verify_segments: int = 4
    # the verdict may come after this many turns or segments, when each one alone gives the same
    # verdict as all of them together (unanimous); otherwise after verify_turns / verify_segments
    min_verify: int = 2
    steady_s: float = 8.0
    max_turn_rate_deg_s: float = 1.5
    max_heading_error_deg: float = 5.0
    verdict: VerdictConfig = VerdictConfig()
    #: the speed loop's learning (eq. L.4), where the autopilot has a speed loop the companion designs
    speed: SpeedLearningConfig = SpeedLearningConfig()

    def __post_init__(self) -> None:
        require_positive(self, "min_step_deg", "turn_s", "verify_turns", "segment_s", "min_segment_rate_deg_s",
                         "verify_segments", "min_verify", "steady_s", "max_turn_rate_deg_s", "max_heading_error_deg")
        if self.min_verify > min(self.verify_turns, self.verify_segments):
            raise ValueError(f"LearningConfig.min_verify ({self.min_verify}) is at most verify_turns and "
                             "verify_segments")
        require_choice(self, "verification", ("course_changes", "turn_rate"))
        if not self.modes:
            raise ValueError("LearningConfig.modes: at least one mode in which the autopilot steers itself")


@dataclass(frozen=True)
class BandSummary:
    """One speed band as learned: centre speed, windows absorbed, validated, the model, validation R²s."""

    speed: float
    windows: int
    validated: bool
    a22: float
    b2: float
    delta0: float
    validations: tuple[float, ...]

    def to_dict(self) -> dict:
        return {"speed": self.speed, "windows": self.windows, "validated": self.validated, "a22": self.a22,
                "b2": self.b2, "delta0": self.delta0, "validations": list(self.validations)}


@dataclass(frozen=True)
class LearningResult:
    """Where learning ended and what it did (the store's record; ``to_dict`` is its JSON)."""

    phase: Phase
    reason: str
    writes: tuple[GainWrite, ...]
    turns: tuple[TurnFigures, ...]
    windows: tuple[WindowOutcome, ...]
    bands: tuple[BandSummary, ...]
    verdict: TurnVerdict | None
    design: str
    mode_left_s: float  # vehicle seconds spent outside the learning modes

    original_best: bool = False
    verified: tuple[str, ...] = ()  # the learned gains verified by the mission's turns (they stay)
    verdict_at_s: float = math.nan  # vehicle time of the verdict (NaN: none yet)
    #: the speed loop's learning (eq. L.4; ``behaviors.mission_speed``), None where none runs
    speed: SpeedLearningResult | None = None
    #: why the speed loop learns nothing on this vehicle ("" where it learns)
    speed_off: str = ""

    @property
    def in_force(self) -> bool:
        """Verified learned gains are on the vehicle."""
        return self.phase is Phase.KEPT

    @property
    def goal_reached(self) -> bool:
        """The vehicle flies gains verified at least as good as its own: learned and kept, or its own
        predicted best on a validated model (nothing to change)."""
        return (self.phase is Phase.KEPT or bool(self.verified)
                or (self.phase is Phase.LEARNING and self.original_best))

    def to_dict(self) -> dict:
        return {"phase": self.phase.value, "reason": self.reason, "in_force": self.in_force,
                "goal_reached": self.goal_reached, "original_best": self.original_best,
                "verified": list(self.verified),
                "writes": [w.to_dict() for w in self.writes], "turns": [t.to_dict() for t in self.turns],
                "windows": [w.to_dict() for w in self.windows], "bands": [b.to_dict() for b in self.bands],
                "verdict": self.verdict.to_dict() if self.verdict else None, "design": self.design,
                "mode_left_s": self.mode_left_s,
                "verdict_at_s": self.verdict_at_s if math.isfinite(self.verdict_at_s) else None,
                "speed": self.speed.to_dict() if self.speed is not None else None, "speed_off": self.speed_off}


class MissionLearner(Behaviour):
    """The module docstring's phases over ``designer`` and the vehicle's ``original`` gains (neutral
    names, read before anything was written)."""

    def __init__(self, designer: Designer, original: dict[str, float], config: LearningConfig = LearningConfig(),
                 speed: SpeedLearner | None = None, speed_off: str = "") -> None:
        super().__init__("learning")
        if not original:
            raise ValueError("MissionLearner needs the vehicle's original gains")
        self.designer = designer
        self.original = dict(original)
        self.config = config
        #: the speed loop's learner (eq. L.4), written at this learner's safe moments; None: ``speed_off`` says why
        self.speed = speed
        self.speed_off = "" if speed is not None else (speed_off or "no speed loop learned")
        self.footprint = Footprint.of(parameters=tuple(original) + (tuple(speed.original) if speed is not None else ()))
        self.estimator = PassiveYawEstimator(config.window, keep_records=True, speed_exponents=(
            config.tracking.a22_speed_exponent, config.tracking.b2_speed_exponent))
        self.models = MissionModels(config.tracking)
        self.by_rate = config.verification == "turn_rate"
        self.recorder: TurnRecorder | RateSegmentRecorder = (
            RateSegmentRecorder(config.segment_s, config.min_segment_rate_deg_s) if self.by_rate
            else TurnRecorder(config.min_step_deg, config.turn_s))
        self.phase = Phase.LEARNING
        self.note = "learning from the mission's course changes"
        self.design: LearnedDesign | None = None
        self.design_summary = ""
        self.written: dict[str, float] | None = None  # the learned gains on the vehicle now
        self.verified: dict[str, float] = {}  # learned gains the mission's turns verified (they stay)
        self.written_at = math.nan
        self.writes: list[GainWrite] = []
        self.turns: list[TurnFigures] = []
        self._straights_seen: list[tuple[str | None, float]] = []  # (gains in force, turn-rate error deg/s)
        self.windows: list[WindowOutcome] = []
        self.verdict: TurnVerdict | None = None
        self.verdict_at_s = math.nan
        self.events: list[dict] = []  # drained by the procedure into the store
        self._designed_bands = 0
        self._recent: deque[tuple[float, float]] = deque()  # (time, unwrapped heading) over steady_s
        self._unwrapped = math.nan
        self._last_yaw = math.nan
        self._last_t = math.nan
        self._outside_s = 0.0
        self._revert_now = False
        self._overridden_revert: dict[str, float] = {}  # what goes back after someone else's change
        self.original_best = False  # the last design found the vehicle's own gains best

    # ------------------------------------------------------------------ ground station
    def accept(self) -> list[Command]:
        """The ground station accepts the gains being verified (or kept): they stay (the speed loop's too)."""
        speed = self._speed_accept()
        if self.phase not in (Phase.VERIFYING, Phase.KEPT):
            return speed
        self.verified = dict(self.written or self.verified)
        self._set(Phase.KEPT, "accepted by the ground station")
        return [StatusText("LEARN: gains accepted by the ground station")] + speed

    def _speed_accept(self) -> list[Command]:
        if self.speed is None:
            return []
        commands = self.speed.accept()
        self.events += self.speed.drain()
        return commands

    def revert(self, reason: str = "reverted by the ground station") -> None:
        """The original gains go back at the next step, at once (the operator chose the moment); a
        design not yet written is dropped. Either way this session writes nothing more. The speed
        loop's learned gains go back alike (eq. L.4)."""
        if self.speed is not None:
            self.speed.revert(reason)
            self.events += self.speed.drain()
        if self.phase in (Phase.REVERTED, Phase.OVERRIDDEN):
            return
        if self.written is None and self.verified:  # kept gains: the ground station takes them back
            self.written = dict(self.verified)
        if self.written is None:
            self.events.append({"type": "revert", "reason": reason, "written": False})
            self._set(Phase.REVERTED, reason)
            return
        self._revert_now = True
        self._set(Phase.WAITING_TO_REVERT, reason)

    def overridden(self, names: Sequence[str], reason: str) -> list[Command]:
        """Someone else (a ground station, a script) changed the learned gains ``names``: their values
        stay, and learning writes nothing of its own any more; unverified learned gains they did not
        touch go back to the original ones at the next safe moment, like any revert (verified ones
        stay; the session's end puts back whatever is still due)."""
        if self.phase in (Phase.REVERTED, Phase.OVERRIDDEN):
            return []
        if self.written is not None and self.phase is not Phase.KEPT:
            self._overridden_revert = {k: v for k, v in self.original.items() if k not in names}
        for name in names:  # theirs now, verified or not
            self.verified.pop(name, None)
        self.written = None
        self.events.append({"type": "overridden", "names": list(names), "reason": reason})
        self._set(Phase.OVERRIDDEN, reason)
        return [StatusText(f"LEARN: stopped, {reason}"[:50], 4)]

    # ------------------------------------------------------------------ the step function
    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        commands: list[Command] = []
        t = telemetry.time_s
        allowed = telemetry.mode in self.config.modes
        if math.isfinite(self._last_t) and not allowed:
            self._outside_s += max(0.0, t - self._last_t)
        self._last_t = t
        # the rate channel of eq. L.3 is the heading's own difference quotient (the signal the target
        # ψ̈f is made of), not a gyro that may read another frame or lag otherwise
        window = self.estimator.add(t, telemetry.yaw, telemetry.rudder, telemetry.speed_water)
        if window is not None:
            self.windows.append(self.models.add(window))
        recorder = self.recorder
        if isinstance(recorder, RateSegmentRecorder):  # by_rate
            segment = recorder.add(t, telemetry.turn_rate_target if allowed else math.nan,
                                   telemetry.turn_rate_achieved, telemetry.speed_water, telemetry.rudder)
            if segment is not None:
                self._segment_flown(segment)
            self._straights_flown(recorder)
        else:
            turn = recorder.add(t, telemetry.yaw, telemetry.heading_target if allowed else math.nan,
                                telemetry.speed_water)
            if turn is not None:
                self._turn_flown(turn)
        steady = self._steady(telemetry, allowed)
        if self.speed is not None:  # the speed loop (eq. L.4), written at the same safe moments
            commands += self.speed.update(telemetry, allowed, steady)
            self.events += self.speed.drain()
        if self._revert_now and self.phase is Phase.WAITING_TO_REVERT:
            return commands + self._write_original(t, telemetry.speed_water)
        if self.phase is Phase.LEARNING:
            commands += self._maybe_design()
        elif self.phase is Phase.WAITING_TO_WRITE and steady and math.isfinite(telemetry.speed_water):
            commands += self._write_design(t, telemetry.speed_water, "design")
            what = (f"{self.config.min_verify}–{self.config.verify_segments} turn-rate segments" if self.by_rate
                    else f"{self.config.min_verify}–{self.config.verify_turns} course changes")
            self._set(Phase.VERIFYING, f"verifying on the next {what}")
        elif self.phase is Phase.VERIFYING:
            commands += self._maybe_judge(t)
        elif self.phase is Phase.WAITING_TO_REVERT and steady:
            commands += self._write_original(t, telemetry.speed_water)
        elif self.phase is Phase.OVERRIDDEN and self._overridden_revert and steady:
            commands += self._write(t, telemetry.speed_water, "revert", self._overridden_revert)
            self._overridden_revert = {}
        return commands

    def _set(self, phase: Phase, reason: str) -> None:
        if phase is not self.phase or reason != self.note:
            log.info("learning: %s (%s)", phase.value, reason)
        self.phase, self.note = phase, reason

    def _steady(self, telemetry: Telemetry, allowed: bool) -> bool:
        """A safe moment to write (module docstring, phase 2)."""
        c = self.config
        t = telemetry.time_s
        target_known = math.isfinite(telemetry.heading_target)
        quiet = (allowed and math.isfinite(telemetry.yaw)
                 and (not target_known
                      or abs(math.degrees(wrap_pi(telemetry.heading_target - telemetry.yaw))) <= c.max_heading_error_deg))
        if not quiet:
            self._recent.clear()
            return False
        self._unwrapped = telemetry.yaw if not math.isfinite(self._unwrapped) else \
            self._unwrapped + wrap_pi(telemetry.yaw - self._last_yaw)
        self._last_yaw = telemetry.yaw
        self._recent.append((t, self._unwrapped))
        while self._recent and t - self._recent[0][0] > c.steady_s:
            self._recent.popleft()
        if len(self._recent) < 2 or t - self._recent[0][0] < 0.9 * c.steady_s:
            return False
        net = math.degrees(self._recent[-1][1] - self._recent[0][1]) / (t - self._recent[0][0])
        return abs(net) <= c.max_turn_rate_deg_s

    # ------------------------------------------------------------------ design and writes
    def _maybe_design(self) -> list[Command]:
        validated = self.models.validated()
        if len(validated) <= self._designed_bands:
            return []
        self._designed_bands = len(validated)
        outcome = self.designer(validated)
        self.events.append({"type": "design", "bands": [s for s, _ in validated], "reason": outcome.reason,
                            "written": outcome.design is not None})
        if outcome.design is None:
            self.original_best = outcome.original_best
            self.note = f"nothing to write: {outcome.reason}"
            log.info("learning: %s", self.note)
            return [StatusText(f"LEARN: keeping the gains ({outcome.reason})"[:50])]
        self.design, self.design_summary = outcome.design, outcome.design.summary
        self._set(Phase.WAITING_TO_WRITE, f"designed at {len(validated)} speed(s): {outcome.reason}")
        return [StatusText(f"LEARN: designed at {len(validated)} speed(s), waiting"[:50])]

    def _write(self, t: float, speed: float, why: str, gains: dict[str, float]) -> list[Command]:
        self.recorder.discard()  # a course change flown on two gain sets is no step of either
        write = GainWrite(t, why, speed, dict(gains))
        self.writes.append(write)
        self.events.append({"type": "write", **write.to_dict()})
        return [SetParameters(dict(gains))]

    def _write_design(self, t: float, speed: float, why: str) -> list[Command]:
        if self.design is None:  # WAITING_TO_WRITE comes with a design (_maybe_design)
            raise RuntimeError("no learned design to write")
        gains = self.design.gains_at(speed)
        self.written, self.written_at = gains, t
        text = "LEARN: wrote " + " ".join(f"{k.replace('heading_', '')}={v:.3g}" for k, v in gains.items())
        return self._write(t, speed, why, gains) + [StatusText(text[:50])]

    def _write_original(self, t: float, speed: float) -> list[Command]:
        self._revert_now = False
        self.verified = {}
        self.events.append({"type": "revert", "reason": self.note, "written": True})
        self.written = None
        commands = self._write(t, speed, "revert", self.original)
        self._set(Phase.REVERTED, self.note)
        return commands + [StatusText(f"LEARN: reverted ({self.note})"[:50], 4)]

    # ------------------------------------------------------------------ turns and the verdict
    def _turn_flown(self, turn: FlownTurn) -> None:
        figures = turn.figures()
        if not math.isfinite(figures.iae_s):
            return
        written = self.written
        learned = written is not None and turn.t_start >= self.written_at
        predicted, predicted_overshoot, original = math.nan, math.nan, math.nan
        if self.design is not None and math.isfinite(turn.speed):
            if learned and written is not None:
                predicted, predicted_overshoot = self.design.predict(written, turn.speed, turn.step)
            original = self.design.predict(self.original, turn.speed, turn.step)[0]
        self.turns.append(TurnFigures(t_start=turn.t_start, speed=turn.speed, size=math.degrees(turn.step),
                                      gains="learned" if learned else "original", error=figures.iae_s,
                                      overshoot_pct=figures.overshoot_pct, predicted_error=predicted,
                                      predicted_overshoot_pct=predicted_overshoot, original_error=original,
                                      metric=STEP_ERROR))

    def _segment_flown(self, segment: FlownSegment) -> None:
        written = self.written
        learned = written is not None and segment.t_start >= self.written_at
        predicted, original, within = math.nan, math.nan, math.inf
        if self.design is not None and math.isfinite(segment.speed):
            within = self.config.rate_fraction * self.design.rate_limit(segment.speed)
            if segment.seconds_within(within) < self.config.min_segment_s:
                return  # a turn the rudder flies at its stop: no gains would change it
            if learned and written is not None:
                predicted = segment.error_deg_s(self.design.replay(written, segment.speed, segment), within)
            original = segment.error_deg_s(self.design.replay(self.original, segment.speed, segment), within)
        self.turns.append(TurnFigures(t_start=segment.t_start, speed=segment.speed, size=segment.size_deg_s,
                                      gains="learned" if learned else "original",
                                      error=segment.error_deg_s(within=within), predicted_error=predicted,
                                      original_error=original, metric=RATE_ERROR))

    def _straights_flown(self, recorder: RateSegmentRecorder) -> None:
        """Each straight window the recorder closed, as flown on the original or the learned gains
        (eq. L.2h; one that began before a write is on neither)."""
        for start, error in recorder.straights[len(self._straights_seen):]:
            written = self.written
            gains = "original" if written is None else "learned" if start >= self.written_at else None
            self._straights_seen.append((gains, error))

    def _holding(self) -> tuple[list[float], list[float]]:
        """The straights' turn-rate errors (deg/s) on the original and on the learned gains."""
        finite = [(gains, e) for gains, e in self._straights_seen if math.isfinite(e)]
        return [e for g, e in finite if g == "original"], [e for g, e in finite if g == "learned"]

    def _maybe_judge(self, now: float) -> list[Command]:
        """eq. L.2 over the turns (segments) flown on the learned gains: after ``verify_turns``
        (``verify_segments``), or from ``min_verify`` on when every one of them alone gives the same
        verdict as all of them together (the ones still to come could only outvote a unanimous
        record, not reverse a mean every member agrees with)."""
        after = [t for t in self.turns if t.gains == "learned"]
        full = self.config.verify_segments if self.by_rate else self.config.verify_turns
        if len(after) < self.config.min_verify:
            return []
        speeds = [t.speed for t in after if math.isfinite(t.speed)]
        speed = sum(speeds) / len(speeds) if speeds else math.nan
        width = self.config.tracking.band_width
        before = [t for t in self.turns if t.gains == "original" and abs(t.speed - speed) <= width * speed]
        verdict = judge_turns(before, after, self.config.verdict, flown_reference=not self.by_rate)
        if len(after) < full:
            alone = [judge_turns(before, [turn], self.config.verdict, flown_reference=not self.by_rate).keep
                     for turn in after]
            if any(keep != verdict.keep for keep in alone):
                return []
        if verdict.keep and self.by_rate:  # eq. L.2h: the legs too, once one was flown on the learned gains
            before_legs, after_legs = self._holding()
            if before_legs and not after_legs:
                return []
            worse = self.config.verdict.holding_worse(before_legs, after_legs)
            if worse is not None:
                verdict = replace(verdict, keep=False, reason=worse)
        self.verdict, self.verdict_at_s = verdict, now
        self.events.append({"type": "verdict", "time_s": now, **self.verdict.to_dict()})
        if self.verdict.keep:
            self.verified = dict(self.written or {})
            self._set(Phase.KEPT, f"verified: {self.verdict.reason}")
            return [StatusText(f"LEARN: kept, {self.verdict.after_error:.2f} vs {self.verdict.before_error:.2f}"[:50])]
        self._set(Phase.WAITING_TO_REVERT, self.verdict.reason)
        return [StatusText("LEARN: verification failed, reverting"[:50], 4)]

    def nothing_learned(self) -> str | None:
        """Why the session has no model to design from (None once a band is validated): the windows
        skipped, by reason, and what would teach it."""
        if self.models.validated():
            return None
        skipped: dict[str, int] = {}
        for outcome in self.windows:
            if outcome.reason is not None:
                key = outcome.reason.split(" (")[0]
                skipped[key] = skipped.get(key, 0) + 1
        counts = ", ".join(f"{n} {why}" for why, n in sorted(skipped.items(), key=lambda item: -item[1]))
        return (f"no model validated from {len(self.windows)} windows ({counts or 'none skipped'}): it learns from "
                f"course changes of {self.config.tracking.min_heading_span_deg:.0f}° or more at a steady speed; "
                "or tune it with a campaign (companion identify)")

    # ------------------------------------------------------------------ the record
    def result(self) -> LearningResult:
        bands = tuple(BandSummary(speed=b.speed, windows=b.tracker.windows, validated=b.validated(self.config.tracking),
                                  a22=(model := b.model()).a22, b2=model.b2, delta0=model.delta0,
                                  validations=tuple(r2 for _, r2 in b.validations)) for b in self.models.bands)
        return LearningResult(phase=self.phase, reason=self.note, writes=tuple(self.writes), turns=tuple(self.turns),
                              windows=tuple(self.windows), bands=bands, verdict=self.verdict, design=self.design_summary,
                              mode_left_s=self._outside_s, original_best=self.original_best,
                              verified=tuple(self.verified), verdict_at_s=self.verdict_at_s,
                              speed=self.speed.result() if self.speed is not None else None, speed_off=self.speed_off)
