"""The speed loop learned, written and verified from an ordinary mission's own speed changes (eq. L.4;
``companion run --learn`` on an autopilot whose speed loop the companion designs: ArduRover). Part of
:class:`behaviors.mission_learning.MissionLearner`, which owns the safe moment and the records; a step
function of vehicle time and telemetry that never asks for a manoeuvre: it only writes gains.

Phases (:class:`behaviors.learning_records.Phase`, as the heading's):

1. **learning** — the running in a mode the autopilot steers (corners included: ArduRover's AUTO
   makes its speed changes in them) goes to
   :class:`companion.numerics.mission_speed.MissionSpeedRecorder`: once it holds two stretches with
   a speed change (the start of AUTO, a corner's slow-down and re-acceleration) the surge model (eq. S.4) is
   fitted on all but the newest of them and validated on that one (output error, R² ≥ 0.9). Every
   speed-change segment (PID_TUNING's asked-for and measured speed) is kept as flown on the original
   gains. A validated model goes to the ``designer``: the campaign's speed design (eq. S.5, scored by
   eq. S.5r with the vehicle's own gains a candidate). Original gains predicted best: said, nothing
   written, learning goes on for nothing more.
2. **waiting to write** — the design's gains (CRUISE_SPEED, CRUISE_THROTTLE, ATC_SPEED_P, ATC_SPEED_I)
   are written at the heading learner's safe moment (a straight, in a mode the autopilot steers,
   never one flown by hand) while the vehicle runs straight (|yaw rate| < 3°/s), announced by
   STATUSTEXT and recorded.
3. **verifying** — the next speed-change segments flown on them (``verify_segments``, or
   ``min_verify`` when each alone gives the verdict all give) are judged by eq. L.2's rule on the speed
   error (``judge_turns`` with ``SPEED_ERROR``): flown RMS speed error against the original gains
   replayed through ArduRover's speed loop on the same asked-for speeds (not worse), and against the
   design's own replay (as predicted, within 30 %). Kept: **kept**; else **waiting to revert**, and
   the original gains go back at the next safe moment: **reverted**.

The ground station's accept and revert (MAV_CMD_USER_4) and someone else's PARAM_SET of a learned
gain (:meth:`SpeedLearner.overridden`) act as on the heading learner.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Callable, Protocol, Sequence

import numpy as np

from behaviors.learning_records import GainWrite, Phase
from companion.checks import require_count, require_positive
from companion.interface import Command, SetParameters, StatusText, Telemetry
from companion.numerics.mission_speed import (FlownSpeedSegment, SpeedFit, SpeedRecordConfig, SpeedSegmentRecorder,
                                              MissionSpeedRecorder)
from companion.numerics.mission_turns import (SPEED_ERROR, TurnFigures, TurnVerdict, VerdictConfig, holding_worse,
                                              judge_turns)

log = logging.getLogger(__name__)

#: the speed loop's gains learning writes (neutral names; ``behaviors.speed_tuning.SPEED_GAINS``)
SPEED_LOOP_GAINS = ("cruise_speed", "cruise_thrust", "speed_p", "speed_i")
#: a write waits for straight running (|yaw rate| below this, deg/s: the campaign's straight)
WRITE_STRAIGHT_DEG_S = 3.0


class LearnedSpeedDesign(Protocol):
    """What the speed designer hands over: the gains to write (neutral names) and the speeds its loop
    achieves on the surge model for any gains asked for a flown segment's speeds (eq. L.4's replay)."""

    @property
    def summary(self) -> str: ...

    @property
    def gains(self) -> dict[str, float]: ...

    def replay(self, gains: dict[str, float], segment: FlownSpeedSegment) -> np.ndarray: ...


@dataclass(frozen=True)
class SpeedDesignOutcome:
    """The speed designer's answer over a validated fit: a design to write, or None with the reason."""

    design: LearnedSpeedDesign | None
    reason: str
    original_best: bool = False  # eq. S.5r keeps the vehicle's own gains


SpeedDesigner = Callable[[SpeedFit], SpeedDesignOutcome]


@dataclass(frozen=True)
class SpeedLearningConfig:
    """The record, the segments and the verdict (module docstring)."""

    record: SpeedRecordConfig = SpeedRecordConfig()
    segment_s: float = 20.0
    min_segment_s: float = 5.0
    min_change_m_s: float = 0.3
    verify_segments: int = 3
    min_verify: int = 2
    verdict: VerdictConfig = VerdictConfig()
    #: eq. L.4h (eq. L.2h on the speed): a keep waits for a lane held on the learned gains, and is
    #: refused when the lanes' speed error on them exceeds the original gains' by this factor and this
    #: much (the speed estimate alone drifts 0.03 m/s: eq. S.5r)
    holding_ratio: float = 1.5
    holding_floor_m_s: float = 0.02

    def __post_init__(self) -> None:
        require_positive(self, "segment_s", "min_segment_s", "min_change_m_s", "holding_ratio", "holding_floor_m_s")
        require_count(self, "verify_segments", "min_verify")
        if self.min_verify > self.verify_segments:
            raise ValueError("SpeedLearningConfig.min_verify is at most verify_segments")


@dataclass(frozen=True)
class SpeedLearningResult:
    """Where the speed loop's learning ended (a part of the store's ``learning`` record): the phase
    (``Phase.value``) and why, the fits tried, the writes, the segments, the verdict, the design, the
    gains verified."""

    phase: str
    reason: str
    fits: tuple[SpeedFit, ...]
    writes: tuple[GainWrite, ...]  # loop "speed"
    segments: tuple[TurnFigures, ...]
    verdict: TurnVerdict | None
    design: str
    original_best: bool
    verified: tuple[str, ...]
    verdict_at_s: float

    @property
    def in_force(self) -> bool:
        return self.phase == "kept"

    def to_dict(self) -> dict:
        return {"phase": self.phase, "reason": self.reason, "in_force": self.in_force,
                "original_best": self.original_best, "verified": list(self.verified),
                "fits": [f.to_dict() for f in self.fits], "writes": [w.to_dict() for w in self.writes],
                "segments": [s.to_dict() for s in self.segments],
                "verdict": self.verdict.to_dict() if self.verdict else None, "design": self.design,
                "verdict_at_s": self.verdict_at_s if math.isfinite(self.verdict_at_s) else None}


class SpeedLearner:
    """The module docstring's phases over ``designer`` and the vehicle's ``original`` speed gains
    (neutral names, read before anything was written). Its writes are :class:`GainWrite` of loop
    ``speed``, recorded as events for the store as the heading learner's are."""

    def __init__(self, designer: SpeedDesigner, original: dict[str, float],
                 config: SpeedLearningConfig = SpeedLearningConfig()) -> None:
        missing = set(SPEED_LOOP_GAINS) - set(original)
        if missing:
            raise ValueError(f"SpeedLearner needs the vehicle's speed gains ({', '.join(sorted(missing))} missing)")
        self.designer, self.original, self.config = designer, dict(original), config
        self.record = MissionSpeedRecorder(config.record)
        self.segments = SpeedSegmentRecorder(config.segment_s, config.min_segment_s, config.min_change_m_s)
        self.phase: Phase = Phase.LEARNING
        self.note = "learning from the mission's speed changes"
        self.fits: list[SpeedFit] = []
        self.design: LearnedSpeedDesign | None = None
        self.design_summary = ""
        self.written: dict[str, float] | None = None
        self.written_at = math.nan
        self.verified: dict[str, float] = {}
        self.figures: list[TurnFigures] = []
        self.writes: list[GainWrite] = []
        self.events: list[dict] = []
        self.verdict: TurnVerdict | None = None
        self.verdict_at_s = math.nan
        self.original_best = False
        self._revert_now = False
        self._overridden_revert: dict[str, float] = {}

    # ------------------------------------------------------------------ ground station, others
    def accept(self) -> list[Command]:
        if self.phase not in (Phase.VERIFYING, Phase.KEPT):
            return []
        self.verified = dict(self.written or self.verified)
        self._set(Phase.KEPT, "accepted by the ground station")
        return [StatusText("LEARN: speed gains accepted by the ground station"[:50])]

    def revert(self, reason: str = "reverted by the ground station") -> None:
        """The original speed gains at the next step, at once; a design not yet written dropped."""
        if self.phase in (Phase.REVERTED, Phase.OVERRIDDEN):
            return
        if self.written is None and self.verified:
            self.written = dict(self.verified)
        if self.written is None:
            self.events.append({"type": "revert", "loop": "speed", "reason": reason, "written": False})
            self._set(Phase.REVERTED, reason)
            return
        self._revert_now = True
        self._set(Phase.WAITING_TO_REVERT, reason)

    def overridden(self, names: Sequence[str], reason: str) -> list[Command]:
        """Someone else changed the learned speed gains ``names``: theirs stay, learning of the speed
        stops; unverified learned gains they did not touch go back at the next safe moment."""
        if self.phase in (Phase.REVERTED, Phase.OVERRIDDEN):
            return []
        if self.written is not None and self.phase is not Phase.KEPT:
            self._overridden_revert = {k: v for k, v in self.original.items() if k not in names}
        for name in names:
            self.verified.pop(name, None)
        self.written = None
        self.events.append({"type": "overridden", "loop": "speed", "names": list(names), "reason": reason})
        self._set(Phase.OVERRIDDEN, reason)
        return [StatusText(f"LEARN: speed stopped, {reason}"[:50], 4)]

    # ------------------------------------------------------------------ the step function
    def update(self, telemetry: Telemetry, allowed: bool, safe: bool) -> list[Command]:
        """One snapshot; ``allowed``: a mode the autopilot steers; ``safe``: the heading learner's
        safe moment to write (a straight in such a mode)."""
        t = telemetry.time_s
        self.record.add(t, telemetry.thrust_ratio, telemetry.speed_water, telemetry.yaw_rate, allowed)
        turning = abs(telemetry.yaw_rate) if telemetry.finite("yaw_rate") else math.inf
        recorded = allowed and turning < math.radians(self.config.record.max_yaw_rate_deg_s)
        straight = allowed and turning < math.radians(WRITE_STRAIGHT_DEG_S)
        segment = self.segments.add(t, telemetry.speed_target, telemetry.speed_achieved, telemetry.thrust_ratio,
                                    recorded)
        if segment is not None:
            self._segment_flown(segment)
        # the heading learner's safe moment (no net course change over its window, in a mode the
        # autopilot steers), and straight now: not at the first second of a corner
        safe = safe and straight
        if self._revert_now and self.phase is Phase.WAITING_TO_REVERT:
            return self._write_original(t, telemetry.speed_water)
        if self.phase is Phase.LEARNING:
            return self._maybe_design()
        if self.phase is Phase.WAITING_TO_WRITE and safe:
            return self._write_design(t, telemetry.speed_water)
        if self.phase is Phase.VERIFYING:
            return self._maybe_judge(t)
        if self.phase is Phase.WAITING_TO_REVERT and safe:
            return self._write_original(t, telemetry.speed_water)
        if self.phase is Phase.OVERRIDDEN and self._overridden_revert and safe:
            gains, self._overridden_revert = self._overridden_revert, {}
            return self._write(t, telemetry.speed_water, "revert", gains)
        return []

    def _set(self, phase: Phase, reason: str) -> None:
        if phase is not self.phase or reason != self.note:
            log.info("speed learning: %s (%s)", phase.value, reason)
        self.phase, self.note = phase, reason

    def _maybe_design(self) -> list[Command]:
        fit = self.record.fit()
        if fit is None:
            return []
        self.fits.append(fit)
        self.events.append({"type": "speed_fit", "loop": "speed", **fit.to_dict()})
        if not fit.validated:
            self.note = (f"surge model not validated: R² {fit.validation_r2:.3f} on the held-out speed change "
                         f"(needs {self.config.record.min_r2:g}); waiting for the next one")
            log.info("speed learning: %s", self.note)
            return []
        if self.original_best:  # the design already kept the vehicle's own gains: nothing more to do
            return []
        outcome = self.designer(fit)
        self.events.append({"type": "design", "loop": "speed", "reason": outcome.reason,
                            "written": outcome.design is not None})
        if outcome.design is None:
            self.original_best = outcome.original_best
            self.note = f"nothing to write: {outcome.reason}"
            log.info("speed learning: %s", self.note)
            return [StatusText(f"LEARN: keeping the speed gains ({outcome.reason})"[:50])]
        self.design, self.design_summary = outcome.design, outcome.design.summary
        self._set(Phase.WAITING_TO_WRITE, f"designed on the mission's speed changes: {outcome.reason}")
        return [StatusText("LEARN: speed loop designed, waiting"[:50])]

    def _write(self, t: float, speed: float, why: str, gains: dict[str, float]) -> list[Command]:
        self.segments.discard()  # a speed change flown on two gain sets is a segment of neither
        write = GainWrite(t, why, speed, dict(gains), loop="speed")
        self.writes.append(write)
        self.events.append({"type": "write", **write.to_dict()})
        return [SetParameters(dict(gains))]

    def _write_design(self, t: float, speed: float) -> list[Command]:
        if self.design is None:
            raise RuntimeError("no learned speed design to write")
        gains = dict(self.design.gains)
        self.written, self.written_at = gains, t
        text = ("LEARN: wrote speed " + " ".join(f"{k.replace('speed_', '').replace('cruise_', 'c')}={v:.3g}"
                                                 for k, v in gains.items()))
        self._set(Phase.VERIFYING,
                  f"verifying on the next {self.config.min_verify}–{self.config.verify_segments} speed changes")
        return self._write(t, speed, "design", gains) + [StatusText(text[:50])]

    def _write_original(self, t: float, speed: float) -> list[Command]:
        self._revert_now = False
        self.verified = {}
        self.events.append({"type": "revert", "loop": "speed", "reason": self.note, "written": True})
        self.written = None
        commands = self._write(t, speed, "revert", self.original)
        self._set(Phase.REVERTED, self.note)
        return commands + [StatusText(f"LEARN: speed reverted ({self.note})"[:50], 4)]

    # ------------------------------------------------------------------ segments and the verdict
    def _segment_flown(self, segment: FlownSpeedSegment) -> None:
        written = self.written
        learned = written is not None and segment.t_start >= self.written_at
        predicted, original = math.nan, math.nan
        if self.design is not None:
            if learned and written is not None:
                predicted = segment.error_m_s(self.design.replay(written, segment))
            original = segment.error_m_s(self.design.replay(self.original, segment))
        self.figures.append(TurnFigures(t_start=segment.t_start, speed=segment.speed, size=segment.change_m_s,
                                        gains="learned" if learned else "original", error=segment.error_m_s(),
                                        predicted_error=predicted, original_error=original, metric=SPEED_ERROR))

    def _maybe_judge(self, now: float) -> list[Command]:
        """eq. L.4's verdict (eq. L.2's rule on the speed error) over the segments flown on the
        learned gains: after ``verify_segments``, or from ``min_verify`` on when each alone gives the
        verdict all of them give."""
        after = [f for f in self.figures if f.gains == "learned"]
        if len(after) < self.config.min_verify:
            return []
        verdict = judge_turns([], after, self.config.verdict, flown_reference=False)
        if len(after) < self.config.verify_segments:
            alone = [judge_turns([], [f], self.config.verdict, flown_reference=False).keep for f in after]
            if any(keep != verdict.keep for keep in alone):
                return []
        if verdict.keep:  # eq. L.4h: the lanes too, once one was held on the learned gains
            before_holds = [e for start, e in self.segments.holds if start < self.written_at and math.isfinite(e)]
            after_holds = [e for start, e in self.segments.holds if start >= self.written_at and math.isfinite(e)]
            if before_holds and not after_holds:
                return []
            worse = holding_worse(before_holds, after_holds, self.config.holding_ratio, self.config.holding_floor_m_s,
                                  "speed error", "m/s", digits=3)
            if worse is not None:
                verdict = replace(verdict, keep=False, reason=worse)
        self.verdict, self.verdict_at_s = verdict, now
        self.events.append({"type": "verdict", "loop": "speed", "time_s": now, **verdict.to_dict()})
        if verdict.keep:
            self.verified = dict(self.written or {})
            self._set(Phase.KEPT, f"verified: {verdict.reason}")
            return [StatusText(f"LEARN: speed kept, {verdict.after_error:.3f} vs {verdict.before_error:.3f}"[:50])]
        self._set(Phase.WAITING_TO_REVERT, verdict.reason)
        return [StatusText("LEARN: speed verification failed, reverting"[:50], 4)]

    def drain(self) -> list[dict]:
        events, self.events = self.events, []
        return events

    def result(self) -> SpeedLearningResult:
        return SpeedLearningResult(phase=self.phase.value, reason=self.note, fits=tuple(self.fits),
                                   writes=tuple(self.writes), segments=tuple(self.figures), verdict=self.verdict,
                                   design=self.design_summary, original_best=self.original_best,
                                   verified=tuple(self.verified), verdict_at_s=self.verdict_at_s)
