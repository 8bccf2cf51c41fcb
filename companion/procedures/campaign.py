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

Outcome: SUCCESS when at least one model was accepted and every requested schedule whose axis was
identified could be designed; FAILURE otherwise, with the reason (the runner then restores every
parameter, so no gain from a failed campaign stays on the vehicle).
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field, replace
from typing import Sequence, Union

import numpy as np

from behaviors.base import Behaviour, Footprint, Status
from behaviors.gain_scheduling import GainDesign, ScheduleKind
from behaviors.heading_steps import HeadingStepTest, StepTestConfig, reengage_hold
from behaviors.identification import IdentificationAttempt, IdentificationManoeuvre, ManoeuvreConfig, thesis_estimator
from behaviors.sequence import Deferred, Instant, ParallelBehavior, SequenceBehavior
from behaviors.steadiness import SteadinessRule
from companion.interface import Command, SetDepth, SetHeading, SetMode, SetParameters, SetThrust, StatusText, Telemetry
from companion.numerics.cascade_gains import CascadeRules, quicktune_feed_forward
from behaviors.schedules import CASCADE_RULED, schedule_kind
from companion.checks import check_thrust_levels, require_choice, require_non_negative, require_positive
from companion.numerics.gains import CAMPAIGN_DAMPING, GainBounds
from companion.procedures.results import ProcedureResult

log = logging.getLogger(__name__)

DEFAULT_THRUSTS = (0.60, 0.70, 0.80, 0.90, 1.00)
#: the quick procedure's yaw stopping rule (ConvergenceRule.noise_band): Θ within 0.5 σ of itself over
#: 1 s, at the earliest 1.5 s after the doublet (≈ 1.5 yaw time constants 1/|a22|). Chosen by replaying
#: 50 full-window yaw records (seeds 1-10, 5 thrusts) through the estimator: stop median 7.7 s,
#: a22 error median 2.4 % (max 4.0 %) against 10.8 s and 2.3 % for eq. 3.39. Measured, not taken:
#: the drift rule (ConvergenceRule.relative_drift) 1 % over 1.5 s stopped at 6.0-6.9 s but a22 median
#: error rose to 2.5-3.9 % (max 7.5 %); the noise band without the 1.5 s delay stopped at 6.4 s with
#: a22 up to 6.7 %. Pitch keeps eq. 3.39: its estimates are still moving by 100 % when the band holds
#: (the 2nd-order pitch model does not hold the heave coupling), so it trains its whole window.
QUICK_NOISE_BAND = 0.5
QUICK_CONVERGENCE_DELAY_S = 1.5
#: the quick procedure's acceptance threshold (the thesis: 0.61): a model below it is retried with a
#: fresh doublet. Pitch R² was bound twice (over MAVLink, seeds 1-10): by noise, the thesis' 0.06 rad
#: validation doublet moving pitch by ~1°, a few times the 0.3° attitude noise (pitch R² 0.98-1.00 on
#: noise-free runs), and by the yaw doublet flown at the same time (turning changes speed, and the
#: pitch moment goes with speed²): with yaw and pitch in turn the 0.10 rad doublets failed 0.9 only
#: twice (0.89, 0.899), together 5 times (0.56-0.85). A 0.15 rad pitch doublet (training and
#: validation) lifts the signal over both: 3 retries in 53 pitch attempts, 0.30 m of depth excursion
#: at 2 m (0.10 rad: 0.23 m). Measured, not taken: the pitch doublet after the yaw one (4.5 or 6 s in:
#: 10-13 retries), a shorter pitch record (6 s after the doublet: 9-19 retries in 20 seeds)
QUICK_R2_THRESHOLD = 0.9
QUICK_PITCH_DOUBLET = 0.15  # rad, the quick procedure's pitch training and validation doublet
#: the campaign procedures: the quick one (the application's default) and the seeds' (thesis §3.3.1)
PROCEDURES = ("quick", "thesis")
AXES = ("yaw", "pitch")


# --------------------------------------------------------------------------- events
@dataclass(frozen=True)
class AttemptRecorded:
    """An identification attempt ended (accepted or not): stored as a run."""

    attempt: IdentificationAttempt


@dataclass(frozen=True)
class StepsChecked:
    """A heading-step check ended: its figures."""

    result: dict


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


#: what the campaign hands the application to store, in order
CampaignEvent = Union[AttemptRecorded, StepsChecked, DesignMade, GainsWritten]


@dataclass(frozen=True)
class CampaignConfig:
    """Everything that shapes a campaign; stored with it."""

    thrusts: tuple[float, ...] = DEFAULT_THRUSTS
    depth: float | None = 2.0  # m (thesis §3.3.1: straight runs at 2 m); None: no depth set-point
    axes: tuple[str, ...] = ("yaw", "pitch")
    yaw: ManoeuvreConfig = ManoeuvreConfig()
    pitch: ManoeuvreConfig = ManoeuvreConfig(axis="pitch", settle_s=15.0, training_amplitude=0.10,
                                             validation_amplitude=0.06)
    bounds: GainBounds = GainBounds()  # heading gain bounds
    # gain schedules designed and written (registry names); the pitch schedule is opt-in: it
    # changes the autopilot's depth behaviour, which the seeds' procedure does not touch
    schedules: tuple[str, ...] = ("heading",)
    cascade: CascadeRules = CascadeRules()  # design targets of the native ArduPilot heading gains
    write_gains: bool = True
    # heading-step checks: the original gains, one constant gain tuned at the lowest thrust (or, on
    # ArduPilot, Rover QuickTune's feed-forward rule) and the scheduled gains; () skips them, and
    # then no gain is written (nothing unverified is left on a vehicle)
    step_labels: tuple[str, ...] = ("original", "constant", "scheduled")
    step_test: StepTestConfig = StepTestConfig()
    verify: "GainCheck" = field(default_factory=lambda: GainCheck())
    # identify yaw and pitch at one thrust together (their doublets staggered) instead of in turn
    parallel_axes: bool = False
    # fields the user set explicitly: the autopilot's campaign defaults do not replace them
    user_set: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "thrusts", check_thrust_levels(self.thrusts, "CampaignConfig.thrusts"))
        if not self.axes or len(set(self.axes)) != len(self.axes) or any(a not in AXES for a in self.axes):
            raise ValueError(f"CampaignConfig.axes must be yaw and/or pitch, each once, not {self.axes!r}")
        if self.depth is not None:
            require_positive(self, "depth")
        for label in self.step_labels:
            if label not in ("original", "constant", "quicktune", "scheduled"):
                raise ValueError(f"CampaignConfig.step_labels: unknown check {label!r} "
                                 "(original, constant, quicktune, scheduled)")

    def to_dict(self) -> dict:
        return asdict(self)

    def quick(self) -> "CampaignConfig":
        """The quick procedure (the application's default; ``--procedure thesis`` keeps the seeds'):

        - settles and resettles end once the vehicle is steady (the thesis' 40/15 s become the maximum);
        - the pre-excitation is 0.5 s, validation records end 4 s after their doublet (the slowest
          yaw/pitch time constant is ~1 s);
        - yaw and pitch run together, the pitch doublet half a period after the yaw one;
        - yaw training stops on the noise-aware rule (:data:`QUICK_NOISE_BAND`), pitch on eq. 3.39;
        - heading gains are designed for ζ = 0.75 instead of eq. 3.57's 0.7071, a margin for the
          doublet's |a22| bias (``companion.numerics.gains``, CAMPAIGN_DAMPING);
        - a model is accepted at validation R² ≥ 0.9 (the thesis: 0.61), and the pitch doublets are
          0.15 rad (the thesis: 0.10 training, 0.06 validation; :data:`QUICK_R2_THRESHOLD`).

        The configuration itself (this dataclass's defaults) is the thesis procedure."""
        rule = SteadinessRule()
        yaw = replace(self.yaw, steadiness=rule, pre_excitation_s=0.5, validation_post_s=4.0,
                      convergence_noise_band=QUICK_NOISE_BAND, convergence_delay_s=QUICK_CONVERGENCE_DELAY_S,
                      r2_threshold=max(self.yaw.r2_threshold, QUICK_R2_THRESHOLD))
        pitch = replace(self.pitch, steadiness=rule, pre_excitation_s=0.5 + self.yaw.doublet_period_s / 2,
                        validation_post_s=4.0, r2_threshold=max(self.pitch.r2_threshold, QUICK_R2_THRESHOLD),
                        training_amplitude=QUICK_PITCH_DOUBLET, validation_amplitude=QUICK_PITCH_DOUBLET)
        return replace(self, yaw=yaw, pitch=pitch, parallel_axes=True,
                       bounds=replace(self.bounds, damping=CAMPAIGN_DAMPING))

    def for_procedure(self, procedure: str) -> "CampaignConfig":
        """``"quick"`` (:meth:`quick`) or ``"thesis"`` (unchanged: the seeds' fixed timings and eq. 3.57)."""
        if procedure == "quick":
            return self.quick()
        if procedure == "thesis":
            return self
        raise ValueError(f"unknown procedure {procedure!r}: use one of {', '.join(PROCEDURES)}")

    def with_thesis_estimator(self) -> "CampaignConfig":
        """The seeds' exact estimator on both axes (P0 = 100·I, zero-order holds)."""
        return replace(self, yaw=thesis_estimator(self.yaw), pitch=thesis_estimator(self.pitch))

    def kinds(self) -> list[ScheduleKind]:
        """The requested gain schedules (heading with this config's bounds, cascade with its rules)."""
        options = {"heading": self.bounds, **{name: self.cascade for name in CASCADE_RULED}}
        return [schedule_kind(name, options.get(name)) for name in self.schedules]

    def with_profile_defaults(self, profile) -> "CampaignConfig":
        """This configuration with the autopilot's campaign defaults (``profile.campaign_defaults``:
        thrusts, axes and doublet amplitudes it can fly), except the fields in ``user_set``.
        Without a profile, or with no defaults, unchanged."""
        defaults = getattr(profile, "campaign_defaults", None)
        given = {k: v for k, v in (defaults.given() if defaults is not None else {}).items() if k not in self.user_set}
        config = self
        if "thrusts" in given:
            config = replace(config, thrusts=tuple(given["thrusts"]))
        if "axes" in given:
            config = replace(config, axes=tuple(given["axes"]))
        amplitudes = {k: given[k] for k in ("training_amplitude", "validation_amplitude") if k in given}
        if amplitudes:
            config = replace(config, yaw=replace(config.yaw, **amplitudes))
        return config

    def resolved_for(self, profile) -> "CampaignConfig":
        """This configuration for one autopilot, applied once by ``run_campaign``: its campaign
        defaults (:meth:`with_profile_defaults`), "heading" naming the profile's heading schedule
        (the PI on the simulator, the native cascade on ArduPilot, designed for its rudder full
        scale), no depth set-point where the autopilot has none, and QuickTune's rule as the
        comparison on cascaded autopilots."""
        if profile is None:
            return self
        config = self.with_profile_defaults(profile)
        heading = getattr(profile, "heading_schedule", "heading")
        schedules = tuple(heading if name == "heading" else name for name in config.schedules)
        config = replace(config, schedules=schedules,
                         cascade=replace(config.cascade, full_scale=profile.angle_full_scale_rad,
                                         **getattr(profile, "gain_ranges", {})))
        if not getattr(profile, "depth_setpoint", True):
            config = replace(config, depth=None)
        # a modelled servo deflection is continuous (first-order hold); a raw loop output is held (zero-order)
        hold = "foh" if getattr(profile, "actuator_rate_rad_s", None) else getattr(profile, "actuator_hold", "foh")
        if hold != "foh":
            config = replace(config, yaw=replace(config.yaw, input_hold=hold), pitch=replace(config.pitch, input_hold=hold))
        if getattr(profile, "train_full_window", False):
            config = replace(config, yaw=replace(config.yaw, stop_on_convergence=False),
                             pitch=replace(config.pitch, stop_on_convergence=False))
        if heading == "cascade":
            config = replace(config, step_labels=tuple("quicktune" if label == "constant" else label
                                                       for label in config.step_labels))
        return config


@dataclass(frozen=True)
class GainCheck:
    """When the heading steps let the scheduled gains stay on the vehicle: at every thrust the
    scheduled gains overshoot at most ``max_overshoot_pct`` and do not oscillate, and (with
    ``better_than_original``) their summed step error (IAE) is below the original gains'."""

    max_overshoot_pct: float = 10.0
    max_oscillations: int = 1
    better_than_original: bool = True

    def __post_init__(self) -> None:
        require_non_negative(self, "max_overshoot_pct")
        if not (isinstance(self.max_oscillations, int) and self.max_oscillations >= 0):
            raise ValueError(f"GainCheck.max_oscillations must be an integer ≥ 0, not {self.max_oscillations!r}")

    def verdict(self, steps: Sequence[dict]) -> str | None:
        """None when the check passes, else the reason."""
        scheduled = [s for s in steps if s["label"] == "scheduled"]
        if not scheduled:
            return "no heading-step check of the scheduled gains"
        for result in scheduled:
            overshoot = result["max_overshoot_pct"]
            if not (isinstance(overshoot, float) and math.isfinite(overshoot)):
                return f"thrust {result['thrust']:.2f}: no overshoot measured"
            if overshoot > self.max_overshoot_pct:
                return f"thrust {result['thrust']:.2f}: overshoot {overshoot:.1f} % > {self.max_overshoot_pct:.0f} %"
            if result.get("oscillations", 0) > self.max_oscillations:
                return f"thrust {result['thrust']:.2f}: the heading oscillates ({result['oscillations']} reversals)"
        original = [s for s in steps if s["label"] == "original"]
        if self.better_than_original and original:
            new, old = sum(s["iae_s"] for s in scheduled), sum(s["iae_s"] for s in original)
            if not new < old:
                return f"the scheduled gains are not better than the original ones (step IAE {new:.1f} s vs {old:.1f} s)"
        return None


class IdentificationCampaign(Behaviour):
    """The campaign as one behaviour (see module docstring)."""

    def __init__(self, config: CampaignConfig = CampaignConfig(), original_gains: dict[str, float] | None = None) -> None:
        super().__init__("identification campaign")
        self.config = config
        self.kinds = config.kinds()
        self.original_gains = dict(original_gains or {})
        self.events: list[CampaignEvent] = []  # drained by the application (companion.procedures.app)
        self.accepted: list[IdentificationAttempt] = []
        self.manoeuvres: list[dict] = []
        self.designs: dict[str, GainDesign] = {}
        self.design_errors: dict[str, str] = {}
        self.step_results: list[dict] = []
        self.vehicle_time_by_phase: dict[str, float] = {}  # see _count_phase_time
        self.phase_times: dict[str, float] = {}  # per identification stage, summed over manoeuvres
        self.final_gains: dict[str, float] | None = None
        self._sequence: SequenceBehavior | None = None
        self._total = 0
        parameters = {name for kind in self.kinds for name in kind.parameters}
        self.heading_kind = next((k for k in self.kinds if k.axis == "yaw"), None)
        if config.step_labels and self.heading_kind is not None:
            parameters |= set(self.heading_kind.parameters)
        self.verification: str | None = None
        self.footprint = Footprint.of(parameters, ("mode", "thrust", "heading", "depth", "rudder", "elevator"))

    @property
    def heading_design(self) -> GainDesign | None:
        return self.designs.get(self.heading_kind.name) if self.heading_kind is not None else None

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
        for index, thrust in enumerate(cfg.thrusts):
            prefix = f"[{index + 1}/{len(cfg.thrusts)} T{thrust * 100:.0f}] "
            items.append(Instant(SetThrust(thrust), SetHeading(course), name=f"thrust {thrust:.2f}"))
            manoeuvres = [IdentificationManoeuvre(replace(cfg.yaw if axis == "yaw" else cfg.pitch, axis=axis),
                                                  thrust=thrust, status_prefix=prefix) for axis in cfg.axes]
            if cfg.parallel_axes and len(manoeuvres) > 1:
                items.append(ParallelBehavior(manoeuvres, name=f"yaw and pitch at {thrust:.2f}"))
            else:
                items.extend(manoeuvres)
        items.append(Deferred(self._design_step))
        heading_gains = Footprint.of(self.heading_kind.parameters if self.heading_kind else (),
                                     ("mode", "thrust", "heading"))
        for thrust in cfg.thrusts:
            for label in cfg.step_labels:
                items.append(Deferred(self._step_test_factory(thrust, label), heading_gains))
        items.append(Deferred(self._final_gains_step, self.footprint))
        # progress counts the manoeuvres and the step checks (the design and the final write are instants)
        self._total = len(cfg.thrusts) * (len(cfg.axes) + len(cfg.step_labels))
        return SequenceBehavior(items, on_complete=self._on_complete, name="campaign")

    def _design_step(self) -> Behaviour:
        texts: list[Command] = []
        for kind in self.kinds:
            if kind.axis not in self.config.axes:
                continue
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
        return Instant(*texts, name="design")

    def _gains_for(self, label: str, thrust: float) -> dict[str, float] | None:
        """Gains of one heading-step check: the originals, one constant set, or the scheduled set."""
        design = self.heading_design
        if design is None:
            return None
        names = self.heading_kind.parameters
        if label == "original":
            return {k: v for k, v in self.original_gains.items() if k in names} or None
        if label == "quicktune":
            feed_forward = self._quicktune_feed_forward(thrust)
            if feed_forward is None:
                return None
            return {**{k: v for k, v in self.original_gains.items() if k in names}, "heading_rate_ff": feed_forward}
        if label == "constant":  # one gain tuned at the lowest identified thrust, used everywhere
            lowest = min(design.points, key=lambda point: point.thrust)
            return dict(lowest.scheduled)
        point = next((p for p in design.points if p.thrust == thrust), None)
        if point is not None:  # the design point's gains, as designed (computed once, carried here)
            return dict(point.scheduled)
        # this thrust has no accepted model: the schedule at the nearest identified speed
        nearest = min(design.points, key=lambda p: abs(p.thrust - thrust))
        return dict(nearest.scheduled)

    def _quicktune_feed_forward(self, thrust: float) -> float | None:
        """ArduRover QuickTune's FF rule on this thrust's training data (the nearest thrust with a model)."""
        attempts = [a for a in self.accepted if a.axis == "yaw"]
        if not attempts:
            return None
        attempt = min(attempts, key=lambda a: abs((a.thrust or 0.0) - thrust))
        series = attempt.training
        times, heading, rudder = (np.asarray(series.get(k, []), dtype=float) for k in ("time", "signal", "actuator"))
        if len(times) < 3:
            return None
        turn_rate = np.gradient(np.unwrap(heading), times)
        try:
            value = quicktune_feed_forward(list(rudder / self.config.cascade.full_scale), list(turn_rate))
        except ValueError:
            return None
        low, high = self.config.cascade.rate_ff_range
        return float(min(max(value, low), high))

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
        """Write every designed schedule's gains for the speed measured now (the resident loop
        keeps them matched later), only once the heading steps passed :class:`GainCheck`."""
        if not self.config.write_gains or not self.designs:
            return None
        if self.heading_kind is not None and self.heading_kind.name in self.designs:
            if not self.config.step_labels:
                self.verification = "not verified: the heading-step checks were skipped, so no gain is written"
                return Instant(StatusText("gains not written: not verified (no heading-step checks)", 4), name="write gains")
            self.verification = self.config.verify.verdict(self.step_results)
            if self.verification is not None:
                self.design_errors["verification"] = self.verification
                return Instant(StatusText(f"gains rejected: {self.verification}"[:50], 4), name="write gains")
        return Instant(name="write gains", make=self._write_scheduled_gains, touches=self.footprint)

    def _write_scheduled_gains(self, telemetry: Telemetry) -> list[Command]:
        gains: dict[str, float] = {}
        speeds: list[float] = []
        for name, design in self.designs.items():
            low = min(point.speed for point in design.points)
            speed = telemetry.speed_water if telemetry.finite("speed_water") else low
            speeds.append(speed)
            gains.update(self._kind(name).gains(design.schedule, speed))
        self.final_gains = gains
        speed = speeds[0]
        before = {k: v for k, v in self.original_gains.items() if k in gains}
        self.events.append(GainsWritten(speed, before, gains))
        thrust = telemetry.thrust_ratio if telemetry.finite("thrust_ratio") else self.config.thrusts[-1]
        text = " ".join(f"{k} {v:.3f}" for k, v in gains.items())
        commands: list[Command] = [SetParameters(gains)]
        if "rudder_trim" in gains:
            commands += reengage_hold(thrust, telemetry.yaw)
        return commands + [StatusText(f"gains written for {speed:.2f} m/s: {text}"[:50])]

    # ------------------------------------------------------------------ events
    def _on_complete(self, behavior: Behaviour) -> None:
        if isinstance(behavior, ParallelBehavior):
            for child in behavior.children:
                self._on_complete(child)
            return
        if isinstance(behavior, IdentificationManoeuvre):
            self.phase_times = _add_times(self.phase_times, behavior.stage_times)
            self.manoeuvres.append({k: v for k, v in behavior.result().items() if k != "attempts"})
            for attempt in behavior.attempts:
                self.events.append(AttemptRecorded(attempt))
                if attempt.accepted:
                    self.accepted.append(attempt)
        elif isinstance(behavior, HeadingStepTest):
            result = behavior.result()
            self.step_results.append(result)
            self.events.append(StepsChecked(result))

    def progress(self) -> float:
        """Fraction of the campaign's manoeuvres and checks completed (0..1), for COMMAND_ACK."""
        if self.status is Status.SUCCESS:
            return 1.0
        if self._sequence is None or not self._total:
            return 0.0
        done = sum(len(b.children) if isinstance(b, ParallelBehavior) else 1 for b in self._sequence.completed
                   if isinstance(b, (IdentificationManoeuvre, HeadingStepTest, ParallelBehavior)))
        return min(1.0, done / self._total)

    @property
    def current_step(self) -> Behaviour | None:
        return self._sequence.current if self._sequence is not None else None

    def design_summary(self) -> dict | None:
        """Each designed schedule as stored (the one serialiser), keyed by kind; None when none."""
        from companion.records.serialise import to_json

        return {name: to_json(design) for name, design in self.designs.items()} or None

    # ------------------------------------------------------------------ lifecycle
    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        if self._sequence is None:
            if not telemetry.finite("yaw"):
                return []
            self._sequence = self._build(telemetry.yaw)
        self._count_phase_time(telemetry.time_s)
        commands = list(self._sequence.tick(telemetry))
        if self._sequence.done:
            commands += self._conclude()
        return commands

    def _count_phase_time(self, now: float) -> None:
        """Vehicle seconds per phase of the campaign (what the campaign costs at sea):
        identification (settles, records), checks (heading steps) and the rest (design, writes)."""
        last = getattr(self, "_phase_clock", None)
        current = self._sequence.current if self._sequence is not None else None
        if isinstance(current, (IdentificationManoeuvre, ParallelBehavior)):
            phase = "identification"
        elif isinstance(current, HeadingStepTest):
            phase = "heading_steps"
        else:
            phase = "other"
        if last is not None and now > last[0]:
            self.vehicle_time_by_phase[last[1]] = self.vehicle_time_by_phase.get(last[1], 0.0) + (now - last[0])
        self._phase_clock = (now, phase)

    def _conclude(self) -> list[Command]:
        if not self.accepted:
            self.finish(Status.FAILURE, "no model passed validation")
        elif self.design_errors:
            self.finish(Status.FAILURE, "; ".join(f"gains rejected: {v}" if k == "verification" else f"{k} design: {v}"
                                                  for k, v in self.design_errors.items()))
        else:
            self.finish(Status.SUCCESS)
        verdict = "complete" if self.status is Status.SUCCESS else f"failed: {self.reason}"
        return [StatusText(f"campaign {verdict}; {len(self.accepted)} models accepted"[:50],
                           6 if self.status is Status.SUCCESS else 4)]

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is Status.ABORTED and self._sequence is not None:
            return self._sequence.stop(self.reason or "aborted")
        return []

    def result(self) -> ProcedureResult:
        figures = {
            "config": self.config.to_dict(),
            "manoeuvres": self.manoeuvres,
            "accepted": [a.summary() for a in self.accepted],
            "design": self.design_summary(),
            "design_errors": self.design_errors,
            "verification": self.verification or ("passed" if self.final_gains else None),
            "steps": [{k: v for k, v in r.items() if k != "series"} for r in self.step_results],
            "final_gains": self.final_gains,
        }
        return ProcedureResult.of("identification", self.status, self.reason, figures)


def _add_times(total: dict[str, float], more: dict[str, float]) -> dict[str, float]:
    """Vehicle seconds per identification stage, summed over manoeuvres (run together, a parallel
    pair's stages overlap: their sum is the axes' time, not the campaign's)."""
    out = dict(total)
    for stage, seconds in more.items():
        out[stage] = out.get(stage, 0.0) + seconds
    return out
