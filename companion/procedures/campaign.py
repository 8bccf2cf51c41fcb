"""The pre-mission self-identification campaign (SPEC C4, C5; thesis §3.3, §3.5).

One behaviour (a sequence under one restore point) that runs, in order:

1. the heading-and-depth holding mode at the campaign depth, on the current course;
2. for each thrust setting: the yaw identification manoeuvre (and the pitch one, if asked);
3. the gain design of every requested schedule (``CampaignConfig.schedules``; the registered kinds
   are in ``companion.procedures.registry``) from the accepted models — for the heading schedule
   the laws a22(u) (constant or with its significant trend) and b2(u) = k·u² + c, PI gains per speed;
4. optional heading-step checks at every thrust with the original gains, one constant gain tuned at
   the lowest thrust, and the speed-scheduled gains (thesis Fig. 3.16);
5. the scheduled gains for the current speed written to the autopilot.

The records travel typed: each attempt is an :class:`IdentificationAttempt`, each design a
:class:`GainDesign` holding the very schedule whose gains are written; :attr:`events` hands them,
as :data:`CampaignEvent` records, to the application after every step
(``companion.procedures.app``), which stores them through the one serialiser, so nothing already
measured is lost if the process dies.

Outcome: SUCCESS when at least one model was accepted and every loop ended with gains verified at
least as good as the original ones: designed, verified and written, or the original gains kept
because nothing was predicted (heading, eq. D.1) or flown (speed) better. FAILURE otherwise, with the
reason; what one loop verified stays on the vehicle even when another loop was refused (the runner
restores everything else, and everything after an abort).
"""
from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, replace
from typing import Sequence, Union

from behaviors.background import BackgroundStep
from behaviors.base import Behaviour, Footprint, Status, footprint_of
from behaviors.gain_scheduling import GainDesign, ScheduleKind
from behaviors.heading_steps import HeadingStepTest, reengage_hold
from behaviors.identification import IdentificationAttempt, IdentificationManoeuvre, IdentificationResult
from behaviors.sequence import Deferred, Instant, ParallelBehavior, SequenceBehavior
from behaviors.speed_tuning import SPEED_CONTEXT, SPEED_GAINS, SpeedTuning, SpeedTuningResult, SurgeRecorder
from behaviors.verification import VerificationStep
from companion.interface import Command, SetDepth, SetHeading, SetMode, SetParameters, SetThrust, StatusText, Telemetry
from companion.numerics.identification import YawEstimate, YawModel
from companion.numerics.quicktune import quicktune_gains, record_feed_forward
from companion.numerics.skid_step import SkidPlant
from companion.numerics.surge import SurgeModel, fit_surge_model
from companion.numerics.thrust_levels import respaced, same_speed_as
from companion.procedures.campaign_config import (AXES, CHECKS, DEFAULT_THRUSTS, PROCEDURES,  # noqa: F401 - re-exported
                                                  QUICK_CONVERGENCE_DELAY_S, QUICK_NOISE_BAND, QUICK_PITCH_DOUBLET,
                                                  QUICK_R2_THRESHOLD, CampaignConfig, GainCheck)
from companion.procedures.campaign_figures import (CampaignFigures, HeadingCheck, LoopOutcome, ThrustLevels,
                                                   designs_to_json)
from companion.procedures.campaign_phases import PhaseClock, add_times, phase_of
from companion.procedures.campaign_verification import CampaignVerification
from companion.procedures.heading_design import HeadingDesign, choose_heading_design, optimisable, with_design
from companion.procedures.results import ProcedureResult
from companion.procedures.verified_design import CONTROLLERS, LIMIT_PARAMETERS, HeadingLimits, skid_plant

log = logging.getLogger(__name__)

# --------------------------------------------------------------------------- events
@dataclass(frozen=True)
class AttemptRecorded:
    """An identification attempt ended (accepted or not): stored as a run."""

    attempt: IdentificationAttempt


@dataclass(frozen=True)
class StepsChecked:
    """A heading-step check ended: its result."""

    result: HeadingCheck


@dataclass(frozen=True)
class DesignMade:
    """A gain schedule was designed from the accepted models."""

    design: GainDesign


@dataclass(frozen=True)
class GainsWritten:
    """The campaign's final gains went to the autopilot (``before``: what they replaced)."""

    speed: float
    before: dict
    after: dict


@dataclass(frozen=True)
class SpeedTuned:
    """The speed loop was identified, designed and checked (or could not be): its figures."""

    status: str
    result: SpeedTuningResult


#: what the campaign hands the application to store, in order
CampaignEvent = Union[AttemptRecorded, StepsChecked, DesignMade, GainsWritten, SpeedTuned]


def unstable_estimates(attempts: Sequence[IdentificationAttempt]) -> str:
    """Why no yaw model passed, when every yaw estimate came out unstable or inverted (a22 ≥ 0 or
    b2 ≤ 0). Measured on ArduPilot's own motorboat (a yaw time constant of 0.06–0.09 s at 3–5 m/s,
    telemetry every 0.04 s): 27 of 33 estimates over four campaigns were, and 7 of 20 campaigns failed;
    at a third of the speed (`--thrusts 0.3,0.4,0.5`) 3 of 3 completed, though 19 of 24 estimates
    there were unstable too: the cause is not established, the slower yaw is what helped. Empty
    otherwise."""
    yaw = [(a, a.model) for a in attempts if a.axis == "yaw" and isinstance(a.model, YawEstimate)]
    if not yaw or any(model.a22 < 0.0 and model.b2 > 0.0 for _, model in yaw):
        return ""
    periods = [a.training_s / a.samples for a, _ in yaw if a.samples > 1 and a.training_s > 0.0]
    period = f" (one every {min(periods):.3f} s here)" if periods else ""
    return (": every yaw estimate came out unstable or inverted (a22 >= 0 or b2 <= 0), as when the yaw "
            f"settles within a few telemetry samples{period}; fly slower (lower --thrusts), where the yaw is slower")


class IdentificationCampaign(Behaviour):
    """The campaign as one behaviour (see module docstring)."""

    def __init__(self, config: CampaignConfig = CampaignConfig(), original_gains: dict[str, float] | None = None,
                 *, background_design: bool = False) -> None:
        """``background_design``: compute the heading design beside the loop (a vehicle that does not
        wait for the companion: real firmware); False computes it in the loop (lockstep, in-process)."""
        super().__init__("identification campaign")
        self.background_design = background_design
        self.config = config
        self.kinds = config.kinds()
        self.original_gains = dict(original_gains or {})
        self.events: list[CampaignEvent] = []  # drained by the application (companion.procedures.app)
        self.accepted: list[IdentificationAttempt] = []
        self.attempts: list[IdentificationAttempt] = []  # every attempt, accepted or not
        self.manoeuvres: list[IdentificationResult] = []
        self.designs: dict[str, GainDesign] = {}
        self.design_errors: dict[str, str] = {}
        self.step_results: list[HeadingCheck] = []
        self._phases = PhaseClock()  # vehicle seconds per phase (companion.procedures.campaign_phases)
        self.phase_times: dict[str, float] = {}  # per identification stage, summed over manoeuvres
        self.final_gains: dict[str, float] | None = None
        self._sequence: SequenceBehavior | None = None
        self._total = 0
        parameters = {name for kind in self.kinds for name in kind.parameters}
        self.heading_kind = next((k for k in self.kinds if k.axis == "yaw"), None)
        #: the checks flown: the configuration's, except that a heading controller the predictions do
        #: not model (CONTROLLERS: PX4's) has every check flown ("compare") rather than predicted
        self.checks = config.checked
        if self.checks == "verify" and self.heading_kind is not None and self.heading_kind.name not in CONTROLLERS:
            self.checks = "compare"
        if self.checks != "none" and self.heading_kind is not None:
            parameters |= set(self.heading_kind.parameters)
        self.verification: str | None = None
        self.heading_choice: HeadingDesign | None = None  # eq. D.1's decision ("optimised" designs)
        #: why the original heading gains stayed after the design was flown against them (None: they did not)
        self.heading_original_flown: str | None = None
        self._plan: list[float | None] = list(config.thrusts)  # the thrust of each level, re-planned in flight
        self._settled: dict[float, float] = {}  # thrust → speed when its yaw settle ended
        self.respacing: list[str] = []  # what re-planned the thrust levels, and how
        self.surge = SurgeRecorder()  # the settles' speed and throttle, for the speed loop
        self.speed: SpeedTuning | None = None
        if config.speed.enabled:
            parameters |= set(SPEED_GAINS + SPEED_CONTEXT)
        self.verifier: CampaignVerification | None = None  # the short campaign's ("verify")
        self._skid: tuple[tuple[int, int], SkidPlant | None] | None = None  # eq. A.2k's, and what it was made from
        if self.checks == "verify" and self.heading_kind is not None:
            parameters |= set(LIMIT_PARAMETERS)  # read for the predictions (restored unchanged)
        if config.cascade.output_scale_base is not None:
            parameters.add("steering_scale_speed")  # read for the design (restored unchanged)
        self.footprint = Footprint.of(parameters, ("mode", "thrust", "heading", "depth", "rudder", "elevator"))

    def adopt_original(self, parameters: dict[str, float]) -> bool:
        """The vehicle's parameters as found (the step checks' original gains and the predictions'
        limits). A heading design on an autopilot that scales its steering output with speed
        (``CascadeRules.output_scale_base``) takes the vehicle's own base speed: returns True when
        that changed the configuration (the caller stores the resolved one)."""
        self.original_gains = dict(parameters)
        base = parameters.get("steering_scale_speed")
        cascade = self.config.cascade
        if cascade.output_scale_base is None or base is None or not math.isfinite(base) \
                or base == cascade.output_scale_base:
            return False
        self.config = replace(self.config, cascade=replace(cascade, output_scale_base=float(base)))
        self.kinds = self.config.kinds()
        self.heading_kind = next((k for k in self.kinds if k.axis == "yaw"), None)
        log.info("heading design for a steering output scaled by base/U above base = %.2f m/s", base)
        return True

    @property
    def heading_design(self) -> GainDesign | None:
        return self.designs.get(self.heading_kind.name) if self.heading_kind is not None else None

    @property
    def records_rejected_for_link(self) -> int:
        """Attempts not used because the link lost too much of their records."""
        return sum(1 for attempt in self.attempts if attempt.spoiled_by_link)

    @property
    def kept_parameters(self) -> frozenset[str]:
        """What a successful campaign leaves on the vehicle: the final gains it wrote."""
        return frozenset(self.final_gains or ())

    # ------------------------------------------------------------------ construction
    def _build(self, course: float) -> SequenceBehavior:
        cfg = self.config
        depth = [SetDepth(cfg.depth)] if cfg.depth is not None else []
        items: list = [Instant(SetMode("hold"), *depth, SetHeading(course), SetThrust(cfg.thrusts[0]),
                               StatusText(f"identification campaign: {len(cfg.thrusts)} thrusts, axes {','.join(cfg.axes)}"),
                               name="prepare")]
        self._plan = list(cfg.thrusts)
        level_footprint = Footprint.union(footprint_of(m) for m in self._level_manoeuvres(0, course))
        for index, thrust in enumerate(cfg.thrusts):
            # each level is built when its turn comes: a level that repeats a lower one's speed
            # re-plans the thrusts still to fly (_settled_speed)
            items.append(Deferred(functools.partial(self._level_thrust, index, course),
                                  Footprint.of(setpoints=("thrust", "heading"))))
            if cfg.parallel_axes and len(cfg.axes) > 1:
                items.append(Deferred(functools.partial(self._level_parallel, index, course), level_footprint))
            else:
                for position in range(len(cfg.axes)):
                    items.append(Deferred(functools.partial(self._level_manoeuvre, index, position, course),
                                          level_footprint))
            if self.verifier_wanted and index == 0 and len(cfg.thrusts) > 1 and not self.optimised_design:
                # the lowest speed's own design, while the vehicle is there and steady (an optimised
                # design is chosen over every speed's model, so it is not known yet here)
                items.append(Deferred(functools.partial(self._own_step, thrust), self._heading_gains))
        items.append(Deferred(self._design_step))
        if self.verifier_wanted:
            # the highest first: where the identification ends, so no thrust change before it
            for slot in (lambda: self._verifier().scheduled_step(self.heading_design, "highest"),
                         lambda: self._verifier().scheduled_step(self.heading_design, "lowest"),
                         lambda: self._verifier().original_step(self.original_heading(), "highest", self.heading_design),
                         lambda: self._verifier().original_step(self.original_heading(), "lowest", self.heading_design)):
                items.append(Deferred(slot, self._heading_gains))
        elif self.checks == "compare":
            for thrust in cfg.thrusts:
                for label in cfg.step_labels:
                    items.append(Deferred(self._step_test_factory(thrust, label), self._heading_gains))
        if cfg.speed.enabled:
            items.append(Deferred(lambda: SpeedTuning(self.surge.record, self.original_gains, cfg.speed,
                                                          fly_original=self.checks == "compare"),
                                  Footprint.of(SPEED_GAINS, ("mode", "thrust", "heading"))))
        items.append(Deferred(self._final_gains_step, self.footprint))
        # progress counts the manoeuvres and the checks (the design and the final write are instants)
        checks = {"verify": 2, "compare": len(cfg.thrusts) * len(cfg.step_labels)}.get(self.checks, 0)
        self._total = len(cfg.thrusts) * len(cfg.axes) + checks
        return SequenceBehavior(items, on_complete=self._on_complete, name="campaign")

    # ------------------------------------------------------------------ thrust levels
    def _level_thrust(self, index: int, course: float) -> Behaviour | None:
        thrust = self._plan[index]
        if thrust is None:  # dropped by a re-plan: nothing left to fly there
            return None
        return Instant(SetThrust(thrust), SetHeading(course), name=f"thrust {thrust:.2f}")

    def _level_manoeuvres(self, index: int, course: float) -> list[IdentificationManoeuvre]:
        cfg = self.config
        thrust = self._plan[index]
        if thrust is None:  # dropped by a re-plan: the caller flies nothing there
            return []
        prefix = f"[{index + 1}/{len(cfg.thrusts)} T{thrust * 100:.0f}] "
        return [IdentificationManoeuvre(replace(cfg.yaw if axis == "yaw" else cfg.pitch, axis=axis), thrust=thrust,
                                        status_prefix=prefix,
                                        settled_speed=self._settled_speed if axis == "yaw" else None)
                for axis in cfg.axes]

    def _level_manoeuvre(self, index: int, position: int, course: float) -> Behaviour | None:
        return self._level_manoeuvres(index, course)[position] if self._plan[index] is not None else None

    def _level_parallel(self, index: int, course: float) -> Behaviour | None:
        if self._plan[index] is None:
            return None
        return ParallelBehavior(self._level_manoeuvres(index, course), name=f"yaw and pitch at {self._plan[index]:.2f}")

    def _settled_speed(self, thrust: float, speed: float) -> str | None:
        """A level settled at the speed of a lower one (the boat's top speed, or WP_SPEED above what it
        can do): skip it and re-space the levels not yet flown within the thrusts that gave distinct
        speeds (``companion.numerics.thrust_levels``). The reason, None to identify this level."""
        repeated = same_speed_as(self._settled, thrust, speed)  # before this level joins them
        self._settled[thrust] = speed
        if repeated is None:
            return None
        index = self._plan.index(thrust) if thrust in self._plan else len(self._plan)
        remaining = len(self._plan) - index
        new = [t for t in respaced(self._settled, remaining) if t not in self._settled]
        self._plan[index:] = new + [None] * (remaining - len(new))  # a level without a thrust is not flown
        note = (f"thrust {thrust:.2f} gives the speed of thrust {repeated:.2f} ({speed:.2f} m/s): the boat is at its "
                f"top speed, or WP_SPEED asks for more than it can do")
        note += f"; the levels left are flown at {', '.join(f'{t:.2f}' for t in new)}" if new else \
            "; no level is left to fly below it"
        self.respacing.append(note)
        log.warning(note)
        return note

    # ------------------------------------------------------------------ verification ("verify")
    @property
    def verifier_wanted(self) -> bool:
        return self.checks == "verify" and self.heading_kind is not None

    @property
    def optimised_design(self) -> bool:
        """The heading gains are chosen on their predicted steps (eq. D.1), not by the rule alone."""
        return self.config.design == "optimised" and optimisable(self.heading_kind) and self.checks != "none"

    @property
    def _heading_gains(self) -> Footprint:
        return Footprint.of(self.heading_kind.parameters if self.heading_kind else (), ("mode", "thrust", "heading"))

    def original_heading(self) -> dict[str, float]:
        names = self.heading_kind.parameters if self.heading_kind else ()
        return {k: v for k, v in self.original_gains.items() if k in names}

    def _yaw_kind(self) -> ScheduleKind:
        """The heading schedule kind (the campaign identifies yaw: it has one)."""
        if self.heading_kind is None:
            raise RuntimeError("the campaign has no heading schedule kind (yaw is not among its axes)")
        return self.heading_kind

    def _own_step(self, thrust: float):
        return self._verifier().own_step(self.accepted, thrust)

    def _limits(self) -> HeadingLimits:
        """What bounds a heading step besides the gains, read with the original gains; on a
        skid-steered boat also its mixer, thrust and speed (eq. A.2k) from what has been measured."""
        limits = HeadingLimits.from_vehicle(self.original_gains, full_scale=self.config.cascade.full_scale,
                                            rudder_rate=self.config.rudder_rate,
                                            output_scale_base=self.config.cascade.output_scale_base
                                            if self._yaw_kind().name == "cascade" else None)
        skid = self._skid_plant()
        if skid is not None:
            limits = replace(limits, skid=skid)
        if CONTROLLERS.get(self._yaw_kind().name) == "px4_uuv":  # eq. A.5a: the surge thrust at each speed
            limits = replace(limits, forward_thrust=tuple(
                (a.speed, a.thrust) for a in self.accepted
                if a.axis == "yaw" and a.thrust is not None and math.isfinite(a.speed)))
        return limits

    def _skid_plant(self) -> SkidPlant | None:
        """Eq. A.2k's knowledge of a skid-steered boat (None for any other): the surge model fitted on
        the settles flown so far (as the speed loop's design will be), the accepted yaw models' speed
        laws and the speed loop as found; computed again only when a model or a level was added."""
        mixer = self.config.skid_mixer
        if mixer is None:
            return None
        yaw = [(a.speed, a.model) for a in self.accepted
               if a.axis == "yaw" and isinstance(a.model, YawModel) and math.isfinite(a.speed)]
        record = self.surge.record
        key = (len(yaw), len(record.levels))
        if self._skid is not None and self._skid[0] == key:
            return self._skid[1]
        levels = list(record.levels.values())
        try:
            surge: SurgeModel | None = fit_surge_model(record.time, record.throttle, record.speed, levels,
                                                       record.stretches())
        except ValueError as exc:
            log.info("skid step predictions without a surge model (the speed held): %s", exc)
            surge = None
        plant = skid_plant(mixer, levels, surge, [u for u, _ in yaw], [m.a22 for _, m in yaw],
                           [m.b2 for _, m in yaw], self.config.speed_law, self.original_gains)
        self._skid = (key, plant)
        return plant

    def _verifier(self) -> CampaignVerification:
        """The verification's bookkeeping, made once the original gains (and limits) are known; its
        limits follow what has been measured since (a skid boat's, eq. A.2k)."""
        if self.verifier is None:
            self.verifier = CampaignVerification(self._yaw_kind(), self.config.verification, self.config.keep,
                                                 self._limits())
        elif self.config.skid_mixer is not None or CONTROLLERS.get(self._yaw_kind().name) == "px4_uuv":
            self.verifier.limits = self._limits()  # what has been measured since: eq. A.2k, A.5a
        return self.verifier

    def _score_heading_design(self) -> HeadingDesign | None:
        """eq. D.1: the rule's parameters optimised on the predicted steps, against the rule's
        default, the original gains and QuickTune's rule (pure computation on what the campaign
        has measured: it may run beside the loop, ``BackgroundStep``). None when nothing could be
        scored (the rule as configured stands)."""
        quicktune = self._gains_for("quicktune", self._middle_thrust()) \
            if self._yaw_kind().name == "cascade" and self.original_heading() else None
        try:
            return choose_heading_design(self._yaw_kind(), self.config.cascade, self.config.bounds, self.accepted,
                                         self._limits(), self.config.objective, self.original_heading(), quicktune)
        except ValueError as exc:
            log.warning("heading design by prediction: %s; the rule as configured is used", exc)
            return None

    def _adopt_heading_design(self, choice: HeadingDesign | None) -> list[Command]:
        """The campaign designs with the chosen rules (its configuration, stored with it), or keeps
        the original gains; the line for the ground station."""
        if choice is None:
            return []
        self.heading_choice = choice
        log.info("heading design by prediction: %s", choice.choice.reason())
        if not choice.keeps_original:
            self.config = with_design(self.config, choice)
            self.kinds = self.config.kinds()
            self.heading_kind = next((k for k in self.kinds if k.axis == "yaw"), None)
            if self.verifier is not None:
                self.verifier.kind = self._yaw_kind()
        best = choice.choice.chosen
        return [StatusText(f"heading: {best.name}, predicted {best.score.iae_s:.2f} s "
                           f"{best.score.worst_overshoot_pct:.1f}%"[:50])]

    def _middle_thrust(self) -> float:
        thrusts = sorted(a.thrust for a in self.accepted if a.axis == "yaw" and a.thrust is not None)
        return thrusts[len(thrusts) // 2] if thrusts else self.config.thrusts[0]

    @property
    def keeps_original_heading(self) -> bool:
        """The design by prediction found nothing better than the vehicle's own heading gains."""
        return self.heading_choice is not None and self.heading_choice.keeps_original

    def _design_step(self) -> Behaviour:
        """The gain design of every requested schedule. The heading design by prediction takes a
        second or two of computation: beside a vehicle that does not wait for the companion it runs
        beside the loop (``BackgroundStep``), so the vehicle keeps its course and speed meanwhile."""
        if self.optimised_design and any(a.axis == "yaw" for a in self.accepted):
            if self.background_design:
                return BackgroundStep(self._score_heading_design,
                                      lambda choice: self._adopt_heading_design(choice) + self._design_kinds(),
                                      name="heading design by prediction")
            return Instant(*self._adopt_heading_design(self._score_heading_design()), *self._design_kinds(),
                           name="design")
        return Instant(*self._design_kinds(), name="design")

    def _design_kinds(self) -> list[Command]:
        texts: list[Command] = []
        for kind in self.kinds:
            if kind.axis not in self.config.axes:
                continue
            if kind is self.heading_kind and self.keeps_original_heading:
                continue  # nothing to design: the vehicle's own gains stay (nothing written, nothing flown)
            try:
                design = kind.design(self.accepted)
            except ValueError as exc:
                self.design_errors[kind.name] = str(exc)
                log.warning("%s gain design: %s", kind.name, exc)
                texts.append(StatusText(f"{kind.name} design skipped: {exc}"[:50], 4))
                continue
            self.designs[kind.name] = design
            self.events.append(DesignMade(design))
            texts.append(StatusText(f"{kind.name} schedule designed at {len(design.points)} speeds"))
            if self.verifier_wanted and kind is self.heading_kind:
                self._verifier().predict(design, self.accepted, self.original_heading())
        return texts

    def _gains_for(self, label: str, thrust: float) -> dict[str, float] | None:
        """Gains of one heading-step check: the originals, one constant set, or the scheduled set."""
        design = self.heading_design
        if design is None:
            return None
        names = self._yaw_kind().parameters
        if label == "original":
            return {k: v for k, v in self.original_gains.items() if k in names} or None
        if label == "quicktune":
            feed_forward = self._quicktune_feed_forward(thrust)
            if feed_forward is None:
                return None
            return {**{k: v for k, v in self.original_gains.items() if k in names},
                    **quicktune_gains(feed_forward, self.config.cascade)}
        if label == "constant":  # one gain tuned at the lowest identified thrust, used everywhere
            lowest = min((p for p in design.points if p.thrust is not None), key=lambda p: p.thrust or 0.0)
            return dict(lowest.scheduled)
        point = next((p for p in design.points if p.thrust == thrust), None)
        if point is not None:  # the design point's gains, as designed (computed once, carried here)
            return dict(point.scheduled)
        # this thrust has no accepted model: the schedule at the nearest identified speed
        nearest = min(design.points, key=lambda p: abs(p.thrust - thrust) if p.thrust is not None else math.inf)
        return dict(nearest.scheduled)

    def _quicktune_feed_forward(self, thrust: float) -> float | None:
        """ArduRover QuickTune's FF rule on this thrust's training data (the nearest thrust with a model);
        its P and I follow from it (``quicktune_gains``)."""
        attempts = [a for a in self.accepted if a.axis == "yaw"]
        if not attempts:
            return None
        attempt = min(attempts, key=lambda a: abs((a.thrust or 0.0) - thrust))
        series = attempt.training
        return record_feed_forward(series.get("time", []), series.get("signal", []), series.get("actuator", []),
                                   self.config.cascade)

    def _kind(self, name: str) -> ScheduleKind:
        return next(kind for kind in self.kinds if kind.name == name)

    def _step_test_factory(self, thrust: float, label: str):
        def build() -> Behaviour | None:
            gains = self._gains_for(label, thrust)
            if gains is None:
                return None
            return HeadingStepTest(thrust, gains, self.config.step_test, label=label)
        return build

    def _final_gains_step(self) -> Behaviour | None:
        """Write what each loop verified, for the speed measured now (the resident loop keeps the
        schedules matched later): the designed schedules once the heading steps passed (the keep
        rule, or :class:`GainCheck` for the full comparison), and the speed loop's gains once its
        own steps passed — each loop keeps what it verified, whatever the other's verdict. A heading
        design that keeps the vehicle's own gains writes nothing for that loop."""
        if not self.config.write_gains:
            return None
        texts: list[Command] = []
        refused: set[str] = set()
        if self.heading_kind is not None and self.heading_kind.name in self.designs:
            if self.checks == "none":
                self.verification = "not verified: the heading-step checks were skipped, so no gain is written"
                texts.append(StatusText("gains not written: not verified (no heading-step checks)", 4))
            elif self.verifier_wanted:
                self.verification = self._verifier().decide()
            else:
                self.verification = self.config.verify.verdict(self.step_results)
            if self.verification is not None:
                refused.add(self.heading_kind.name)
                if self.verifier_wanted and self._verifier().originals_stand():
                    # flown, the design was no better than the vehicle's own gains, which pass the
                    # checks themselves: those stay, verified at least as good as any design
                    self.heading_original_flown = self.verification
                    texts.append(StatusText("heading: own gains kept, no design flew better"[:50]))
                elif self.checks != "none":
                    self.design_errors["verification"] = self.verification
                    texts.append(StatusText(f"gains rejected: {self.verification}"[:50], 4))
        writable = tuple(name for name in self.designs if name not in refused)
        speed_kept = bool(self.speed is not None and self.speed.kept)
        if not writable and not speed_kept:
            return Instant(*texts, name="write gains") if texts else None
        return Instant(*texts, name="write gains", make=lambda telemetry: self._write_scheduled_gains(telemetry, writable),
                       touches=self.footprint)

    def _write_scheduled_gains(self, telemetry: Telemetry, names: Sequence[str] | None = None) -> list[Command]:
        gains: dict[str, float] = {}
        speeds: list[float] = []
        for name, design in self.designs.items():
            if names is not None and name not in names:
                continue
            low = min(point.speed for point in design.points)
            speed = telemetry.speed_water if telemetry.finite("speed_water") else low
            speeds.append(speed)
            gains.update(self._kind(name).gains(design.schedule, speed))
        if self.speed is not None and self.speed.kept:  # verified by its own speed steps
            gains.update(self.speed.kept)
        if not gains:
            return []
        self.final_gains = gains
        speed = speeds[0] if speeds else (telemetry.speed_water if telemetry.finite("speed_water") else math.nan)
        before = {k: v for k, v in self.original_gains.items() if k in gains}
        self.events.append(GainsWritten(speed, before, gains))
        thrust = telemetry.thrust_ratio if telemetry.finite("thrust_ratio") else self.config.thrusts[-1]
        text = " ".join(f"{k} {v:.3f}" for k, v in gains.items())
        commands: list[Command] = [SetParameters(gains)]
        if "rudder_trim" in gains:
            commands += reengage_hold(thrust, telemetry.yaw)
        where = f"for {speed:.2f} m/s" if math.isfinite(speed) else "(speed loop)"
        return commands + [StatusText(f"gains written {where}: {text}"[:50])]

    def _speed_refused(self) -> str | None:
        """Why the speed loop, which was to be tuned, ended with neither verified gains nor the
        original gains shown to be the better ones (exit 1; what the heading verified stays); None
        when it did not."""
        speed = self.loop_outcomes().get("speed") if self.speed is not None else None
        return speed.why if speed is not None and speed.outcome == "refused" else None

    def loop_outcomes(self) -> dict[str, LoopOutcome]:
        """Loop by loop (heading, speed): its :class:`LoopOutcome` (written, original kept, refused,
        not tuned, and why), for the result and the summary."""
        out: dict[str, LoopOutcome] = {}
        if self.heading_kind is not None and "yaw" in self.config.axes:
            written = self.final_gains is not None and any(k in self.final_gains for k in self.heading_kind.parameters)
            if self.heading_choice is not None and self.heading_choice.keeps_original:
                out["heading"] = LoopOutcome("original kept", "no design is predicted better than the vehicle's own "
                                                              "gains: " + self.heading_choice.choice.reason())
            elif self.heading_original_flown:
                out["heading"] = LoopOutcome("original kept", "the design flew no better than the vehicle's own "
                                                              "gains, which pass the checks themselves: "
                                                              f"{self.heading_original_flown}")
            elif written:
                out["heading"] = LoopOutcome("written", self.verification or "verified")
            elif self.verification or self.heading_kind.name in self.design_errors:
                out["heading"] = LoopOutcome("refused", self.verification
                                             or self.design_errors.get(self.heading_kind.name, ""))
            else:
                out["heading"] = LoopOutcome("not tuned", "no heading design")
        if self.speed is not None:
            kept = bool(self.speed.kept) and self.final_gains is not None
            why = self.speed.verdict or self.speed.reason or ""
            if kept:
                out["speed"] = LoopOutcome("written", "verified by its own speed steps")
            elif self.speed.keeps_original:
                out["speed"] = LoopOutcome("original kept", why)
            elif (self.speed.verdict or "").startswith("not faster than the original"):
                out["speed"] = LoopOutcome("original kept", why)
            else:
                out["speed"] = LoopOutcome("refused", why or "the speed loop was not tuned")
        return out

    # ------------------------------------------------------------------ events
    def _on_complete(self, behavior: Behaviour) -> None:
        if isinstance(behavior, ParallelBehavior):
            for child in behavior.children:
                self._on_complete(child)
            return
        if isinstance(behavior, IdentificationManoeuvre):
            self.phase_times = add_times(self.phase_times, behavior.stage_times)
            self.manoeuvres.append(behavior.result())
            for attempt in behavior.attempts:
                self.attempts.append(attempt)
                self.events.append(AttemptRecorded(attempt))
                if attempt.accepted:
                    self.accepted.append(attempt)
        elif isinstance(behavior, HeadingStepTest):
            self._checked(behavior.result())
        elif isinstance(behavior, SpeedTuning):
            self.speed = behavior
            self.events.append(SpeedTuned(behavior.status.value, behavior.result()))
        elif isinstance(behavior, VerificationStep):
            self._checked(self._verifier().record(behavior, self.accepted))

    def _checked(self, check: HeadingCheck) -> None:
        self.step_results.append(check)
        self.events.append(StepsChecked(check))

    def progress(self) -> float:
        """Fraction of the campaign's manoeuvres and checks completed (0..1), for COMMAND_ACK."""
        if self.status is Status.SUCCESS:
            return 1.0
        if self._sequence is None or not self._total:
            return 0.0
        done = sum(len(b.children) if isinstance(b, ParallelBehavior) else 1 for b in self._sequence.completed
                   if isinstance(b, (IdentificationManoeuvre, HeadingStepTest, VerificationStep, ParallelBehavior)))
        return min(1.0, done / self._total)

    @property
    def current_step(self) -> Behaviour | None:
        return self._sequence.current if self._sequence is not None else None

    def design_summary(self) -> dict | None:
        """Each designed schedule as stored (the one serialiser), keyed by kind; None when none."""
        return designs_to_json(self.designs)

    # ------------------------------------------------------------------ lifecycle
    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        if self._sequence is None:
            if not telemetry.finite("yaw"):
                return []
            self._sequence = self._build(telemetry.yaw)
        self._phases.count(telemetry.time_s, phase_of(self.current_step))
        self._record_surge(telemetry)
        commands = list(self._sequence.tick(telemetry))
        if self._sequence.done:
            commands += self._conclude()
        return commands

    def _record_surge(self, telemetry: Telemetry) -> None:
        """The yaw manoeuvre's settles feed the surge model (behaviors/speed_tuning.py)."""
        current = self._sequence.current if self._sequence is not None else None
        if isinstance(current, ParallelBehavior):
            current = next((c for c in current.children if isinstance(c, IdentificationManoeuvre)
                            and c.config.axis == "yaw"), None)
        if isinstance(current, IdentificationManoeuvre):
            self.surge.add(telemetry, current.thrust, current.stage)
        else:
            self.surge.add(telemetry, None, None)

    def _conclude(self) -> list[Command]:
        speed_refused = self._speed_refused()
        if not self.accepted:
            spoiled = self.records_rejected_for_link
            if spoiled and spoiled == len(self.attempts):  # the real cause is the link, not the vehicle
                last = next(a.rejected_for for a in reversed(self.attempts) if a.spoiled_by_link)
                self.finish(Status.FAILURE, f"no model: the link spoiled all {spoiled} records ({last}); fix the "
                                            "link (a radio's range or air rate, a serial port's baud rate) and fly "
                                            "again")
            else:
                self.finish(Status.FAILURE, "no model passed validation"
                            + (f" ({spoiled} of {len(self.attempts)} records spoiled by the link)" if spoiled else "")
                            + unstable_estimates(self.attempts))
        elif self.design_errors or speed_refused is not None:
            reasons = [f"gains rejected: {v}" if k == "verification" else f"{k} design: {v}"
                       for k, v in self.design_errors.items()]
            if speed_refused is not None:
                reasons.append(f"speed loop: {speed_refused}")
            self.finish(Status.FAILURE, "; ".join(reasons))
        else:
            self.finish(Status.SUCCESS)
        verdict = "complete" if self.status is Status.SUCCESS else f"failed: {self.reason}"
        return [StatusText(f"campaign {verdict}; {len(self.accepted)} models accepted"[:50],
                           6 if self.status is Status.SUCCESS else 4)]

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is Status.ABORTED and self._sequence is not None:
            return self._sequence.stop(self.reason or "aborted")
        return []

    def phases_in_order(self) -> dict[str, float]:
        """Vehicle seconds per phase in the order a campaign flies them, then any other."""
        return self._phases.in_order()

    def result(self) -> ProcedureResult[CampaignFigures]:
        figures = CampaignFigures(
            config=self.config, manoeuvres=tuple(self.manoeuvres), accepted=tuple(self.accepted),
            designs=dict(self.designs), design_errors=dict(self.design_errors),
            verification=self.verification or ("passed" if self.final_gains else None),
            steps=tuple(self.step_results), checks=self.checks,
            verified=self.verifier.verified() if self.verifier is not None else None,
            vehicle_time_by_phase=self.phases_in_order(),
            final_gains=dict(self.final_gains) if self.final_gains is not None else None,
            speed_loop=self.speed.result() if self.speed is not None else None,
            heading_design=self.heading_choice.choice if self.heading_choice is not None else None,
            loops=self.loop_outcomes(),
            thrust_levels=ThrustLevels(tuple(t for t in self._plan if t is not None), tuple(self.respacing)))
        return ProcedureResult.of("identification", self.status, self.reason, figures)
