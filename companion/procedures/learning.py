"""Tuning during ordinary missions inside ``companion run --learn``: the application side of
:class:`behaviors.mission_learning.MissionLearner` — the designer it asks, the vehicle's original
gains, its writes through the link and its records in the store.

* **Designer**: the campaign's design by prediction (eq. D.1, ``companion.procedures.heading_design``)
  over the bands' validated models, under the autopilot's own heading controller (the simulator's PI,
  ArduPilot's cascade) with the limits read from the vehicle, the original gains a candidate. The
  schedule kind's fit over the validated bands gives the gains at a speed (one band: the same gains
  at every speed); the prediction for any gains at a speed is the step on the schedule's model there.
  On a skid-steered boat that step goes through its mixer, the thrust the steering leaves and the
  speed it costs (eq. A.2k), from the throttle the mission holds on its straights
  (:class:`StraightRunning`) and the speed loop's gains as read, as a campaign predicts it.
* **Which gains, verified how**: the heading kind's scheduled gains, never its trims. On ArduRover in
  AUTO the navigation controller asks for a turn rate, so the rate loop's FF/P/I carry the turns: they
  are verified by how the rate loop tracks the turn rates the navigation asks for (PID_TUNING, the
  profile's ``learning_verification = "turn_rate"``; the mask parameter of its ``pid_tuning`` report
  gets the report's bit for the session and its own value back at the end). ArduSub in AUTO alike:
  its angle loop turns the vehicle toward the next waypoint through the yaw rate loop, whose
  PID_TUNING (axis YAW) reports the rates it is asked for. The whole design is written, the cascade's angle P
  with them: that is the pairing its predictions are of (eq. D.1; writing the rate gains alone under
  the vehicle's own angle P was predicted to overshoot 9.5 % on a 20° step in GUIDED on ArduRover's
  boat, beyond the acceptable). The angle P acts only where a heading is held (GUIDED), which AUTO's
  verification does not fly: there it stands on the prediction of the validated model, as the
  campaign's predicted steps do.
* **The speed loop** (eq. L.4), where the profile names a speed loop the companion designs
  (``speed_unlearned``: ArduRover's): :class:`behaviors.mission_speed.SpeedLearner` inside the
  heading learner, designing with :class:`SpeedLoopDesigner` (the campaign's ``design_speed_gains``
  on the surge model fitted and validated on the mission's speed changes), its four gains in the same
  restore point and trail, its PID_TUNING bit set in the same mask; elsewhere the record says why
  nothing is learned for speed.
* **Records**: one campaign of kind ``learning`` per session. Its restore point (the original
  gains) is stored as a trail before the first write and every write is recorded before it is sent
  (:class:`companion.procedures.trail.TrailRecorder`), so a ``kill -9`` mid-learning is followed by
  ``companion recover``, which writes the original gains back. Events (designs, writes, verdicts) are
  ``learning_event`` results as they happen, and the session's end a ``learning`` result.
* **The end of a session** (a signal, ``max_vehicle_s``): gains verified and kept stay on the
  vehicle (that was the goal; the trail is closed); gains still being verified, or waiting to be
  reverted, are reverted first.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from behaviors.base import Footprint
from behaviors.gain_scheduling import ScheduleKind
from behaviors.mission_learning import DesignOutcome, LearningConfig, LearningResult, MissionLearner, Phase
from behaviors.mission_speed import SPEED_LOOP_GAINS, SpeedDesignOutcome, SpeedLearner
from companion.checks import require_positive
from companion.link.errors import ParamError
from companion.link.port import VehiclePort
from companion.link.profile import AutopilotProfile
from companion.interface import Command, SetParameters
from companion.numerics.identification import YawModel
from companion.numerics.mission_speed import FlownSpeedSegment, SpeedFit
from companion.numerics.mission_turns import FlownSegment
from companion.numerics.speed_gains import (SpeedDesign, SpeedLoopGains, SpeedRules, design_speed_gains,
                                            simulate_speed_tracking)
from companion.numerics.schedule import YawSchedule
from companion.numerics.speed_law import LAW_EXPONENTS
from companion.numerics.step_response import predict_step, simulate_rate_tracking
from companion.procedures.campaign import CampaignConfig
from companion.procedures.heading_design import choose_heading_design, optimisable, step_case, with_design
from companion.procedures.restore import RestorePoint
from companion.procedures.trail import TrailRecorder, vehicle_identity
from companion.procedures.verified_design import CONTROLLERS, LIMIT_PARAMETERS, HeadingLimits, skid_plant
from companion.records.store import Store

log = logging.getLogger(__name__)

#: a predicted step's length (vehicle seconds), as the campaign's objective
PREDICTED_S = 30.0


@dataclass(frozen=True)
class _BandModel:
    """A validated band in the shape the campaign's designer reads (an accepted yaw attempt)."""

    speed: float
    model: YawModel
    axis: str = "yaw"
    accepted: bool = True
    thrust: float | None = None


@dataclass(frozen=True)
class ScheduledDesign:
    """A design over the validated bands: the kind's schedule (its gains at a speed) and the
    controller's limits for predictions (``behaviors.mission_learning.LearnedDesign``)."""

    kind: ScheduleKind
    schedule: YawSchedule  # a heading kind's fit (``schedule_from_models``)
    limits: HeadingLimits
    summary: str

    def _within(self, speed: float) -> float:
        """``speed`` held to the validated bands' range (the schedule is not extrapolated)."""
        low, high = self.schedule.speed_range
        return min(max(speed, low), high)

    def _case(self, speed: float):
        speed = self._within(speed)
        return step_case(CONTROLLERS[self.kind.name], self.schedule.model_at(speed), speed, self.limits)

    def gains_at(self, speed: float) -> dict[str, float]:
        return self.kind.scheduled_gains(self.schedule, self._within(speed))

    def predict(self, gains: dict[str, float], speed: float, step: float) -> tuple[float, float]:
        case = self._case(speed)
        figures = predict_step(case.plant, case.controller, dict(gains), step, PREDICTED_S, skid=case.skid,
                               **case.limits).figures
        return figures.iae_s, figures.overshoot_pct

    def replay(self, gains: dict[str, float], speed: float, segment: FlownSegment) -> np.ndarray:
        """The turn rates the rate loop with ``gains`` achieves on the model at the segment's speed,
        asked for the segment's turn rates (the rate loop alone: on a skid boat without its mixer,
        which eq. A.2k's steps carry but this replay does not)."""
        case = self._case(speed)
        return simulate_rate_tracking(case.plant, dict(gains), segment.times, segment.desired,
                                      float(segment.achieved[0]), rudder0=segment.rudder0,
                                      rate_loop=self.limits.rate_loop, **case.limits)

    def rate_limit(self, speed: float) -> float:
        """The steady turn rate at full rudder on the model at ``speed`` (rad/s): b2·δmax/|a22| (eq. 3.6)."""
        model = self.schedule.model_at(self._within(speed))
        return abs(model.b2 * self.limits.rudder_max / model.a22) if model.a22 != 0.0 else math.inf


class StraightRunning:
    """The throttle and speed the mission holds on its straights, by speed bin: a skid-steered boat's
    steady law for eq. A.2k, as a campaign takes it from its settles (``behaviors.speed_tuning``)."""

    #: straight: |yaw rate| below this (rad/s), as the campaign's surge record
    STRAIGHT_RATE = math.radians(3.0)
    BIN_M_S = 0.25
    MIN_SAMPLES = 25  # a second of snapshots at 25 Hz

    def __init__(self) -> None:
        self._sums: dict[int, list[float]] = {}  # bin → [n, Σ throttle, Σ speed]

    def add(self, telemetry) -> None:
        if not (telemetry.finite("yaw_rate") and telemetry.finite("thrust_ratio") and telemetry.finite("speed_water")):
            return
        if abs(telemetry.yaw_rate) >= self.STRAIGHT_RATE or telemetry.thrust_ratio <= 0.0 or telemetry.speed_water <= 0.0:
            return
        sums = self._sums.setdefault(int(round(telemetry.speed_water / self.BIN_M_S)), [0.0, 0.0, 0.0])
        sums[0] += 1.0
        sums[1] += telemetry.thrust_ratio
        sums[2] += telemetry.speed_water

    def levels(self) -> list[tuple[float, float]]:
        """(mean throttle, mean speed) of each bin with at least a second of straight running."""
        return [(t / n, u / n) for n, t, u in (self._sums[k] for k in sorted(self._sums)) if n >= self.MIN_SAMPLES]


class HeadingDesigner:
    """eq. D.1 over the validated bands (module docstring); on a skid-steered boat (``config.skid_mixer``)
    every step is predicted through its mixer, thrust and speed (eq. A.2k), from the straights' steady
    throttle (``straights``) and the speed loop as found (``speed_gains``), as a campaign predicts it."""

    def __init__(self, config: CampaignConfig, kind: ScheduleKind, original: dict[str, float],
                 limits: HeadingLimits, straights: StraightRunning | None = None,
                 speed_gains: dict[str, float] | None = None) -> None:
        self.config, self.kind, self.original, self.limits = config, kind, original, limits
        self.straights, self.speed_gains = straights, dict(speed_gains or {})

    def limits_for(self, validated: Sequence[tuple[float, YawModel]]) -> HeadingLimits:
        """The limits the predictions use: a skid boat's carry its drive (eq. A.2k) once a straight's
        throttle is known; any other's, as read."""
        mixer = self.config.skid_mixer
        if mixer is None or self.straights is None:
            return self.limits
        plant = skid_plant(mixer, self.straights.levels(), None, [u for u, _ in validated],
                           [m.a22 for _, m in validated], [m.b2 for _, m in validated], self.config.speed_law or "u",
                           self.speed_gains)
        return replace(self.limits, skid=plant) if plant is not None else self.limits

    def __call__(self, validated: Sequence[tuple[float, YawModel]]) -> DesignOutcome:
        attempts = [_BandModel(speed, model) for speed, model in validated]
        limits = self.limits_for(validated)
        try:
            choice = choose_heading_design(self.kind, self.config.cascade, self.config.bounds, attempts, limits,
                                           self.config.objective, self.original)
        except ValueError as exc:
            return DesignOutcome(None, f"no design: {exc}")
        if choice.keeps_original:
            return DesignOutcome(None, f"the original gains are predicted best ({choice.choice.reason()})",
                                 original_best=True)
        kind = next(k for k in with_design(self.config, choice).kinds() if k.axis == "yaw")
        try:
            schedule = kind.fit([a.speed for a in attempts], [a.model for a in attempts])
        except ValueError as exc:
            return DesignOutcome(None, f"no schedule: {exc}")
        best = choice.choice.chosen
        summary = (f"{best.name}: predicted step error {best.score.iae_s:.2f} s, overshoot "
                   f"{best.score.worst_overshoot_pct:.1f} %")
        return DesignOutcome(ScheduledDesign(kind, schedule, limits, summary), choice.choice.reason())


@dataclass(frozen=True)
class LearnedSpeedLoop:
    """A speed-loop design on the mission's validated surge model (eq. S.5 scored by eq. S.5r), in the
    shape the speed learner reads (``behaviors.mission_speed.LearnedSpeedDesign``): the gains to write
    and eq. L.4's replay of any gains through ArduRover's speed loop on the model."""

    design: SpeedDesign
    summary: str

    @property
    def gains(self) -> dict[str, float]:
        return self.design.gains.params()

    def replay(self, gains: dict[str, float], segment: FlownSpeedSegment) -> np.ndarray:
        """The speeds the loop with ``gains`` achieves on the surge model asked for the segment's speeds,
        from the segment's first measured speed and throttle (``simulate_speed_tracking``)."""
        return simulate_speed_tracking(self.design.surge, SpeedLoopGains.from_params(gains), segment.times,
                                       segment.desired, float(segment.achieved[0]), segment.throttle0)


@dataclass(frozen=True)
class SpeedContext:
    """What the speed design reads from the vehicle and never writes: WP_SPEED (m/s, the steps stay
    below it; inf when not read or 0) and ATC_ACCEL_MAX (m/s², 1.0 when not read, as the campaign)."""

    speed_max: float = math.inf
    accel_max: float = 1.0

    def __post_init__(self) -> None:
        require_positive(self, "accel_max")
        if not self.speed_max > 0.0:  # inf: no WP_SPEED to stay below
            raise ValueError(f"SpeedContext.speed_max must be > 0 (inf for none), not {self.speed_max!r}")

    @classmethod
    def from_params(cls, values: dict[str, float]) -> "SpeedContext":
        """From the neutral names read (``speed_default``, ``accel_max``); a missing, zero or negative
        value keeps the default."""
        speed, accel = values.get("speed_default", math.nan), values.get("accel_max", math.nan)
        return cls(speed_max=speed if speed > 0.0 else math.inf, accel_max=accel if accel > 0.0 else 1.0)


class SpeedLoopDesigner:
    """The campaign's speed design (``design_speed_gains``, eq. S.5 and S.5r) on a surge model fitted and
    validated on the mission's own speed changes (eq. L.4), the vehicle's own gains a candidate; its
    speed range the mission's steady speeds, its steps below WP_SPEED (:class:`SpeedContext`)."""

    def __init__(self, original: dict[str, float], context: SpeedContext, rules: SpeedRules) -> None:
        self.original, self.context, self.rules = dict(original), context, rules

    def __call__(self, fit: SpeedFit) -> SpeedDesignOutcome:
        try:
            design = design_speed_gains(fit.model, self.original["cruise_speed"], fit.speed_range, self.rules,
                                        self.context.accel_max, SpeedLoopGains.from_params(self.original),
                                        speed_max=self.context.speed_max)
        except ValueError as exc:
            return SpeedDesignOutcome(None, f"no speed design: {exc}")
        if design.keeps_original:
            return SpeedDesignOutcome(None, design.reason(), original_best=True)
        gains = design.gains
        summary = (f"CRUISE_SPEED {gains.cruise_speed:.2f}, CRUISE_THROTTLE {100 * gains.cruise_throttle:.0f} %, "
                   f"P {gains.p:.3g}, I {gains.i:.3g} on {fit.model.describe()}")
        return SpeedDesignOutcome(LearnedSpeedLoop(design, summary), design.reason())


def speed_unlearned(profile: AutopilotProfile, campaign: CampaignConfig) -> str | None:
    """Why the speed loop learns nothing on this autopilot (None when it learns, eq. L.4): its profile
    must name a speed loop the companion designs (ArduRover's, eq. S.5), its gains and the PID_TUNING
    report of it."""
    report = profile.speed_loop_report
    if not (report is not None and report.mask_param in profile.params
            and all(name in profile.params for name in SPEED_LOOP_GAINS)):
        return f"nothing is learned for speed: {profile.name} has no speed loop the companion designs"
    if not campaign.speed.enabled:
        return "nothing is learned for speed: the speed loop's tuning is off in the campaign's configuration"
    return None


def heading_kind_for(config: CampaignConfig) -> ScheduleKind | None:
    return next((k for k in config.kinds() if k.axis == "yaw"), None)


def unverifiable(profile: AutopilotProfile) -> str | None:
    """Why learned gains could not be verified on this autopilot (None when they can): it must report
    its heading set-point (course changes as steps) or its rate loop's turn rates (PID_TUNING)."""
    report = profile.pid_tuning
    if profile.learning_verification == "turn_rate" and report is not None and report.mask_param in profile.params:
        return None
    if profile.learning_verification == "course_changes" and profile.reports_heading_target:
        return None
    return (f"{profile.name} reports neither the heading set-point it holds nor its rate loop's turn rates, so "
            "learned gains could not be verified on the mission's turns; tune it with a campaign (companion identify)")


class LearningSession:
    """One ``companion run --learn`` session: the learner, its trail and its records."""

    def __init__(self, link: VehiclePort, store: Store, vehicle_id: int, config: LearningConfig = LearningConfig(),
                 campaign: CampaignConfig = CampaignConfig()) -> None:
        self.link, self.store, self.vehicle_id, self.config = link, store, vehicle_id, config
        self.campaign = campaign.resolved_for(link.profile)
        self.learner: MissionLearner | None = None
        self.campaign_id: int | None = None
        self.trail_id: int | None = None
        self.recorder: TrailRecorder | None = None
        self.restore: RestorePoint | None = None
        self.result: LearningResult | None = None
        self._foreign_seen: set[str] = set()
        self.restore_problems: list[str] = []  # what the session's end could not put back
        self.straights: StraightRunning | None = None  # a skid boat's steady throttle (eq. A.2k)

    def start(self) -> str | None:
        """Read the original gains and open the records; the reason when learning cannot run."""
        refused = unverifiable(self.link.profile)
        if refused is not None:
            return refused
        kind = heading_kind_for(self.campaign)
        if kind is None or not optimisable(kind):
            return f"no model of this autopilot's heading controller to design with ({kind.name if kind else 'none'})"
        profile = self.link.profile
        limit_names = tuple(name for name in LIMIT_PARAMETERS if name in profile.params)
        report = profile.pid_tuning
        mask = (report.mask_param,) if report is not None and report.mask_param in profile.params else ()
        speed_off = speed_unlearned(profile, self.campaign)
        speed_names = SPEED_LOOP_GAINS if speed_off is None else ()
        # the speed loop's gains are in the restore point (and so in the trail) before anything is written
        self.restore = RestorePoint.capture(self.link, Footprint.of(
            parameters=kind.scheduled + limit_names + mask + speed_names))
        values = self.restore.parameters
        original = {name: values[name] for name in kind.scheduled if name in values}
        if len(original) != len(kind.scheduled):
            return f"the vehicle did not give its heading gains ({', '.join(sorted(set(kind.scheduled) - set(original)))})"
        limits = HeadingLimits.from_vehicle(values, full_scale=self.campaign.cascade.full_scale,
                                            rudder_rate=self.campaign.rudder_rate,
                                            output_scale_base=self.campaign.cascade.output_scale_base
                                            if kind.name == "cascade" else None, rate_loop=profile.rate_loop)
        margin = profile.prediction_margin_pct
        config = replace(self.config, verification=profile.learning_verification)
        if profile.yaw_from_thrusters:
            # a thruster's yaw moment does not depend on the speed: the rows as they are (eq. L.3 with
            # p = n = 0), a window whose speed changed in a corner still teaches, and one band spans
            # every speed the mission flies (up to twice its first window's)
            config = replace(config, tracking=replace(config.tracking, a22_speed_exponent=0.0, b2_speed_exponent=0.0,
                                                      speed_tolerance=math.inf, band_width=1.0))
        else:
            # the windows' rows are written at their band's speed by the vehicle's own speed law of b2
            # (eq. L.3; the actuation read from the vehicle: a rudder's u², a skid pair's u, eq. S.3)
            law = self.campaign.speed_law or "u2"
            config = replace(config, tracking=replace(config.tracking, b2_speed_exponent=LAW_EXPONENTS[law]))
        if margin is not None:  # the prediction's measured margin on this autopilot (eq. L.2)
            config = replace(config, verdict=replace(config.verdict, overshoot_margin_pct=float(margin)))
        # the whole design is written (what its predictions are of); a turn-rate verification flies
        # the rate loop's part, the angle P acts where a heading is held (module docstring)
        speed_gains: dict[str, float] = {}
        if self.campaign.skid_mixer is not None:  # eq. A.2k: the steps go through the mixer and the speed loop
            self.straights = StraightRunning()
            speed_gains = self._speed_gains(profile)
        designer = HeadingDesigner(self.campaign, kind, original, limits, self.straights, speed_gains)
        speed = self._speed_learner(values, speed_off)
        if speed is None and speed_off is None:
            speed_off = "nothing is learned for speed: the vehicle did not give its speed-loop gains"
        self.learner = MissionLearner(designer, original, config, speed=speed, speed_off=speed_off or "")
        if speed_off:
            log.info("learning: %s", speed_off)
        self.campaign_id = self.store.start_campaign(self.vehicle_id, "learning", {
            "original": original, "modes": list(config.modes), "heading_kind": kind.name,
            "speed_original": dict(speed.original) if speed is not None else None, "speed_off": speed_off or None})
        self.trail_id = self.store.save_restore_point(self.campaign_id, self.restore.as_json(), vehicle_identity(self.link))
        self.recorder = TrailRecorder(self.store, self.trail_id, self.link)
        masks = [r for r in (report, profile.speed_loop_report if speed is not None else None)
                 if r is not None and r.mask_param in values]
        if masks:  # the rate loop's (and the speed loop's) PID_TUNING, for the verifications; put back at the end
            value = values[masks[0].mask_param]
            for item in masks:
                value = item.with_bit(value)
            self._send([SetParameters({masks[0].mask_param: value})])
        self.link.status_text(f"LEARN: on, original {kind.name} gains recorded"[:50])
        log.info("learning on: original gains %s, limits %s", original, limits)
        return None

    def _speed_learner(self, values: dict[str, float], speed_off: str | None) -> SpeedLearner | None:
        """The speed loop's learner (eq. L.4) over its original gains from the restore point and the
        context it designs with (WP_SPEED, ATC_ACCEL_MAX, read only); None where the speed learns nothing."""
        if speed_off is not None:
            return None
        original = {name: values[name] for name in SPEED_LOOP_GAINS if name in values}
        if len(original) != len(SPEED_LOOP_GAINS):
            return None
        names = [name for name in ("speed_default", "accel_max") if name in self.link.profile.params]
        try:
            context = SpeedContext.from_params(self.link.get_params(names) if names else {})
        except ParamError as exc:
            log.info("learning: WP_SPEED/ATC_ACCEL_MAX not read (%s): the speed design takes none", exc)
            context = SpeedContext()
        return SpeedLearner(SpeedLoopDesigner(original, context, self.campaign.speed.rules), original,
                            self.config.speed)

    def _speed_gains(self, profile) -> dict[str, float]:
        """The speed loop's gains as found, for eq. A.2k's speed hold (the speed learner's writes, eq. L.4,
        are not followed by the heading's predictions); empty when the vehicle does not give them (the throttle is then taken as held)."""
        names = [name for name in ("speed_p", "speed_i") if name in profile.params]
        try:
            return self.link.get_params(names) if len(names) == 2 else {}
        except ParamError as exc:
            log.info("learning: the speed loop's gains not read (%s); a skid boat's throttle is taken as held", exc)
            return {}

    def status(self) -> dict:
        """What the status page shows: the phase and why, the bands, the writes, the verdict."""
        if self.learner is None:
            result = self.result
            if result is None:
                return {"on": False, "reason": "learning has not started"}
            return {"on": False, "phase": result.phase.value, "reason": result.reason,
                    "writes": [w.to_dict() for w in result.writes[-5:]]}
        result = self.learner.result()
        return {"on": True, "phase": result.phase.value, "reason": result.reason, "campaign_id": self.campaign_id,
                "bands": [{"speed": band.speed, "windows": band.windows, "validated": band.validated}
                          for band in result.bands],
                "turns": len(result.turns), "writes": [w.to_dict() for w in result.writes[-5:]],
                "verdict": result.verdict.to_dict() if result.verdict else None,
                "speed": self._speed_status(result)}

    @staticmethod
    def _speed_status(result: LearningResult) -> dict:
        """The speed loop's part of the status page (eq. L.4): its phase and why, its writes, its verdict."""
        speed = result.speed
        if speed is None:
            return {"on": False, "reason": result.speed_off}
        fit = speed.fits[-1] if speed.fits else None
        return {"on": True, "phase": speed.phase, "reason": speed.reason, "segments": len(speed.segments),
                "fit": fit.to_dict() if fit is not None else None,
                "writes": [w.to_dict() for w in speed.writes[-5:]],
                "verdict": speed.verdict.to_dict() if speed.verdict else None}

    @property
    def phase(self) -> Phase | None:
        return self.learner.phase if self.learner is not None else None

    def step(self, telemetry) -> None:
        """One snapshot. A write the vehicle refused or lost (or any failure of a step) ends the
        session through its restore point, said; the resident loop goes on."""
        if self.learner is None:
            return
        try:
            changed = self._changed_by_others()
            if changed:
                natives = ", ".join(f"{c.name} {c.value:g}" for c in changed.values())
                reason = f"set by someone else: {natives}"
                speed = self.learner.speed
                heading = tuple(name for name in changed if name in self.learner.original)
                if heading:
                    self._send(self.learner.overridden(heading, reason))
                theirs = tuple(name for name in changed if speed is not None and name in speed.original)
                if theirs and speed is not None:  # a learned speed gain: the speed learner stops (eq. L.4)
                    self._send(speed.overridden(theirs, reason))
                    self.learner.events += speed.drain()
            if self.straights is not None:
                self.straights.add(telemetry)
            self._send(self.learner.tick(telemetry))
            self._drain()
        except Exception as exc:  # noqa: BLE001 - the resident loop must outlive a failed write
            log.warning("learning stopped: %s", exc)
            self.learner.note = f"stopped: {type(exc).__name__}: {exc}"
            self.link.status_text(f"LEARN: stopped, {exc}"[:50], 4)
            self.finish()

    def _changed_by_others(self) -> dict:
        """neutral name → the link's record of a learned gain someone else changed, not seen before."""
        learner, restore = self.learner, self.restore
        if learner is None or restore is None:  # start() takes the restore point before it makes the learner
            raise RuntimeError("learning has not started")
        foreign = self.link.parameters.foreign
        found = {}
        for neutral in (*learner.original, *(learner.speed.original if learner.speed is not None else ())):
            for native in restore.natives_of.get(neutral, ()):
                if native in foreign and native not in self._foreign_seen:
                    self._foreign_seen.add(native)
                    found[neutral] = foreign[native]
        return found

    def accept(self) -> bool:
        deciding = (Phase.VERIFYING, Phase.KEPT)
        if self.learner is None or not (self.learner.phase in deciding or self._speed_phase() in deciding):
            return False
        self._send(self.learner.accept())
        self._drain()
        return True

    def revert(self) -> bool:
        """The ground station's revert: the original gains at the next step (at once), or a design
        waiting to be written dropped; False when there was nothing to revert."""
        undoable = (Phase.WAITING_TO_WRITE, Phase.VERIFYING, Phase.KEPT)
        if self.learner is None or not (self.learner.phase in undoable or self._speed_phase() in undoable):
            return False
        self.learner.revert()
        self._drain()
        return True

    def _speed_phase(self) -> Phase | None:
        learner = self.learner
        return learner.speed.phase if learner is not None and learner.speed is not None else None

    def _send(self, commands: Sequence[Command]) -> None:
        if not commands:
            return
        if self.recorder is None:  # start() opens the trail before anything is sent
            raise RuntimeError("learning has not started: no trail to record in")
        self.recorder(commands)
        self.link.execute(list(commands))

    def _drain(self) -> None:
        learner = self.learner
        if learner is None:
            raise RuntimeError("learning has not started")
        while learner.events:
            event = learner.events.pop(0)
            self.store.add_behavior_result(self.campaign_id, "learning_event", event["type"], event)

    def finish(self) -> LearningResult | None:
        """The vehicle put back as found except what stays on purpose — learned gains the mission's
        turns verified, and what someone else set meanwhile — by the restore point (each parameter
        read back; the PID_TUNING mask included), the result stored, the trail closed (idempotent). A
        restore that could not finish leaves the trail open (``companion recover`` follows it) and
        :attr:`restore_problems` says what is not back."""
        if self.learner is None:
            return self.result
        learner = self.learner
        try:
            self._drain()
        except Exception as exc:  # noqa: BLE001 - the restore below matters more than a record
            log.error("learning: events not stored: %s", exc)
        speed = learner.speed
        keep = tuple(learner.verified) + (tuple(speed.verified) if speed is not None else ())
        if learner.phase is Phase.LEARNING and not learner.original_best:
            learner.note = learner.nothing_learned() or learner.note
        if learner.written is not None and set(learner.written) - set(keep):
            learner.note = f"{learner.note}; the session ended before the verification: original gains written back"
            learner.phase = Phase.REVERTED
        if speed is not None and speed.written is not None and set(speed.written) - set(keep):
            speed.note = f"{speed.note}; the session ended before the verification: original speed gains written back"
            speed.phase = Phase.REVERTED
        restore = self.restore
        if restore is None:  # start() takes the restore point before it makes the learner
            raise RuntimeError("learning has no restore point")
        self.restore_problems = restore.restore(self.link, mode=False, keep=keep)
        learner.written = None
        if speed is not None:
            speed.written = None
        if self.restore_problems:
            log.error("learning: the vehicle could not be put back: %s", "; ".join(self.restore_problems))
            self._close(learner, "failed", f"not put back: {'; '.join(self.restore_problems)}", close_trail=False)
            return self.result
        status = "completed" if learner.result().goal_reached else "failed"
        self._close(learner, status, learner.note, close_trail=True, notes=restore.notes)
        return self.result

    def _close(self, learner: MissionLearner, status: str, reason: str, *, close_trail: bool,
               notes: Sequence[str] = ()) -> None:
        self.result = learner.result()
        self.store.add_behavior_result(self.campaign_id, "learning", self.result.phase.value, self.result.to_dict())
        if self.recorder is not None:
            self.recorder.close()
        if close_trail and self.trail_id is not None:
            self.store.finish_restore(self.trail_id, [], [f"learning ended: {self.result.phase.value}", *notes])
        if self.campaign_id is not None:  # None only when start() could not open its campaign
            self.store.finish_campaign(self.campaign_id, status, reason)
        self.learner = None

