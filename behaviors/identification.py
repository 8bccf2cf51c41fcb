"""The identification manoeuvre at one thrust setting (SPEC C4; thesis §3.3.1, Fig. 3.4).

Stages, all timed on vehicle time:

1. **settle** — straight course at constant depth in the heading-and-depth holding mode (40 s);
2. **train** — the online estimator (SVF + RLS) runs on every sample; after 2 s a doublet of
   0.26 rad is injected open loop on the actuator (+A for half the period, −A for the other half,
   period 4 s) around the current trim; then the actuator is released so the autopilot's heading
   (or depth) loop re-engages; training stops 10.5 s after the excitation, or earlier once the
   estimate has converged (eq. 3.39) *after the excitation has ended* (a convergence detected before
   the doublet only means nothing has been excited yet);
3. **resettle** — the autopilot brings the vehicle back on course. Where it held the vehicle since
   the doublet was released (in the mode it settled in), that recovery already counts towards the
   steadiness rule's window. (Measured, not taken: where the excitation needed another mode
   (ArduPilot's MANUAL), holding the heading the record left the vehicle on instead of turning back
   saved 13 s on ArduRover but raised the a22 error from 1.3 % to 3.8 % median: the next speed's
   settle ended with the turn back not quite at rest);
4. **validate** — a fresh doublet of 0.15 rad, no estimation; the identified model is simulated on
   the recorded actuator input and scored by R² (eq. 3.35–3.37). Accepted at R² ≥ threshold if the
   yaw estimate is a model (a22 < 0, b2 > 0: eq. 3.5–3.9; a fit that passes while unstable or inverted
   is rejected with that reason), otherwise the manoeuvre is repeated from stage 2 (at most
   ``max_attempts`` times).

The same machinery identifies the pitch axis (thesis App. B) with an elevator doublet. The
behaviour is a pure step function of telemetry (SPEC §5): it never touches the link; ``abort``
returns the commands that release what it holds.
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field, replace
from enum import Enum
from typing import Callable, Sequence

from behaviors.base import Behaviour, Footprint, Status
from behaviors.json_form import json_form
from companion.checks import require_choice, require_non_negative, require_positive, require_range
from companion.interface import (
    Command,
    NamedValue,
    OverrideActuator,
    ReleaseActuator,
    SetHeading,
    SetMode,
    StatusText,
    Telemetry,
)
from companion.numerics.bounded_pole import ONLINE, YawModelChoice, choose_yaw_model, fit_yaw_bounded_pole
from companion.numerics.identification import (ConvergenceRule, PitchIdentifier, PitchModel, YawEstimate,
                                               YawIdentifier, YawModel)
from companion.numerics.sampling import SamplingRule, sampling_quality
from companion.numerics.validation import validate_pitch, validate_yaw
from behaviors.steadiness import SteadinessDetector, SteadinessRule

log = logging.getLogger(__name__)

SETTLE, TRAIN, RESETTLE, VALIDATE, DONE = "settle", "train", "resettle", "validate", "done"


@dataclass(frozen=True)
class ManoeuvreConfig:
    """Timings and amplitudes of one identification manoeuvre (defaults: thesis §3.3.1)."""

    axis: str = "yaw"  # "yaw" (rudder, heading) or "pitch" (elevator, pitch)
    settle_s: float = 40.0
    pre_excitation_s: float = 2.0
    doublet_period_s: float = 4.0
    training_amplitude: float = 0.26  # rad
    validation_amplitude: float = 0.15  # rad
    post_excitation_s: float = 10.5
    resettle_s: float = 15.0
    r2_threshold: float = 0.61
    max_attempts: int = 3
    stop_on_convergence: bool = True
    svf_bandwidth: float | None = None  # None: the numerics' default (thesis value, 1 rad/s)
    # Estimator defaults depart from the seeds on evidence (bench/bench_identification.py): the
    # seeds' P0 = 100·I acts as a prior pulling Θ towards 0 on a single 16.5 s doublet (a22, b2 a
    # few % low), and a zero-order hold treats a rate-limited rudder as a staircase (half a sample of
    # input delay: a22, b2 ~4 % high on the simulator). P0 = 1e4 and a first-order hold on both
    # signals remove both biases; ``thesis_estimator()`` gives the seeds' exact choice.
    p0: float = 1e4
    input_hold: str = "foh"
    output_hold: str = "foh"
    live_value_period_s: float = 0.25  # NAMED_VALUE_FLOAT rate of the live estimates
    # None settles and resettles for the fixed times above (the thesis); a rule ends them
    # as soon as the vehicle is steady (behaviors/steadiness.py), the fixed times being the maximum
    steadiness: SteadinessRule | None = None
    # length of the validation record after its doublet (None: post_excitation_s, as training)
    validation_post_s: float | None = None
    # the drift stopping rule (ConvergenceRule.relative_drift, measured, not taken); None: eq. 3.39
    convergence_drift: float | None = None
    # the noise-aware stopping rule (ConvergenceRule.noise_band) and how long after the end of the
    # excitation it may first stop (the response still carries information for ~1/|a22| after it)
    convergence_noise_band: float | None = None
    convergence_delay_s: float = 0.0
    # how much of a record the link may lose before it is not used (companion.numerics.sampling)
    sampling: SamplingRule = SamplingRule()

    def __post_init__(self) -> None:
        require_choice(self, "axis", ("yaw", "pitch"))
        require_positive(self, "settle_s", "doublet_period_s", "post_excitation_s", "resettle_s", "p0",
                         "live_value_period_s")
        require_non_negative(self, "pre_excitation_s", "convergence_delay_s")
        require_range(self, "training_amplitude", 1e-4, 1.0)
        require_range(self, "validation_amplitude", 1e-4, 1.0)
        require_range(self, "r2_threshold", -1.0, 1.0)
        if not (isinstance(self.max_attempts, int) and 1 <= self.max_attempts <= 10):
            raise ValueError(f"ManoeuvreConfig.max_attempts must be an integer in 1..10, not {self.max_attempts!r}")
        require_choice(self, "input_hold", ("foh", "zoh"))
        require_choice(self, "output_hold", ("foh", "zoh"))
        require_range(self, "svf_bandwidth", 1e-3, 100.0, optional=True)
        require_range(self, "validation_post_s", 0.0, 600.0, optional=True)
        require_range(self, "convergence_drift", 1e-6, 1.0, optional=True)
        require_range(self, "convergence_noise_band", 1e-3, 100.0, optional=True)

    @property
    def actuator(self) -> str:
        return "rudder" if self.axis == "yaw" else "elevator"

    @property
    def excitation_end_s(self) -> float:
        return self.pre_excitation_s + self.doublet_period_s

    @property
    def window_s(self) -> float:
        """Length of the training stage without early stop (and of the validation record unless
        ``validation_post_s`` shortens it)."""
        return self.excitation_end_s + self.post_excitation_s

    @property
    def validation_window_s(self) -> float:
        post = self.post_excitation_s if self.validation_post_s is None else self.validation_post_s
        return self.excitation_end_s + post


def thesis_estimator(config: ManoeuvreConfig) -> ManoeuvreConfig:
    """The seeds' estimator exactly: P0 = 100·I and zero-order holds (SPEC C3)."""
    return replace(config, p0=100.0, input_hold="zoh", output_hold="zoh")


def doublet(t_rel: float, start_s: float, period_s: float, amplitude: float) -> float | None:
    """Doublet offset at ``t_rel``: +A in the first half period, −A in the second, None outside."""
    if t_rel < start_s or t_rel >= start_s + period_s:
        return None
    return amplitude if t_rel < start_s + period_s / 2 else -amplitude


class Rejection(Enum):
    """Why an attempt whose fit may have passed was not used: the link lost too much of its records,
    or the estimate is no model (:func:`no_model_reason`)."""

    LINK = "link"
    NOT_A_MODEL = "not a model"


def no_model_reason(model: YawEstimate | PitchModel) -> str | None:
    """Why an attempt holding ``model`` cannot be accepted whatever its R²: a yaw estimate that is no
    model (a22 ≥ 0, b2 ≤ 0 or not finite, eq. 3.5–3.9); None otherwise."""
    if isinstance(model, YawEstimate) and (problem := model.why_not_model) is not None:
        return f"the estimate is not a yaw model: {problem}"
    return None


@dataclass
class IdentificationAttempt:
    """One training + validation of one axis at one thrust (SPEC C4): stored as a run, and as a
    model when accepted. ``training`` and ``validation`` hold the recorded series (for the report).

    A yaw attempt's ``model`` is a :class:`YawModel` whenever its estimate is one (made one here, so
    it is stored under the tag it always had), else the :class:`YawEstimate` it came out as; an
    attempt is ``accepted`` only with a model (ValueError otherwise, :func:`no_model_reason`)."""

    attempt: int
    axis: str
    thrust: float | None
    speed: float  # m/s, mean water speed during training (NaN when not reported)
    model: YawModel | YawEstimate | PitchModel
    r2: float
    accepted: bool
    converged: bool
    converged_s: float | None
    criterion_met_from_s: float | None
    training_s: float
    samples: int
    training: dict = field(default_factory=dict, repr=False)
    validation: dict = field(default_factory=dict, repr=False)
    # how the training and validation records were sampled (SamplingQuality.as_json), and why the
    # attempt was not used although its fit may have passed (a record the link lost too much of)
    sampling: dict = field(default_factory=dict)
    rejected_for: str | None = None
    #: what ``rejected_for`` is about (None: not rejected): the link, or an estimate that is no model
    rejection: Rejection | None = None
    # where the model came from (eq. 3.38p): the online estimate, or the bounded-pole refit and why
    model_source: str = ONLINE
    model_note: str = ""

    def __post_init__(self) -> None:
        if (self.rejected_for is None) != (self.rejection is None):
            raise ValueError(f"{self.axis} attempt {self.attempt}: a rejection needs both its reason and its kind, "
                             f"not {self.rejected_for!r} and {self.rejection!r}")
        if isinstance(self.model, YawEstimate) and self.model.is_model:
            self.model = self.model.model()
        if self.accepted and (reason := no_model_reason(self.model)) is not None:
            raise ValueError(f"{self.axis} attempt {self.attempt} cannot be accepted: {reason}")

    @property
    def spoiled_by_link(self) -> bool:
        """Not used because the link lost too much of its records (``rejected_for`` says how), as
        opposed to a fit that passed with no model (``rejected_for`` is then :func:`no_model_reason`)."""
        return self.rejection is Rejection.LINK

    def summary(self) -> dict:
        """The figures without the series and the covariance (JSON summaries, progress lines)."""
        model = {k: v for k, v in vars(self.model).items() if k != "covariance"}
        return {"attempt": self.attempt, "axis": self.axis, "thrust": self.thrust, "speed": self.speed,
                "model": model, "r2": self.r2, "accepted": self.accepted, "converged": self.converged,
                "converged_s": self.converged_s, "criterion_met_from_s": self.criterion_met_from_s,
                "training_s": self.training_s, "samples": self.samples, "sampling": self.sampling,
                "rejected_for": self.rejected_for, "model_source": self.model_source, "model_note": self.model_note}


#: how a manoeuvre ended (None: not yet): a model accepted, every attempt rejected, stopped from
#: outside, the vehicle not moving, or skipped (its thrust gives a speed already identified)
OUTCOMES = (None, "accepted", "rejected", "aborted", "not moving", "skipped")


@dataclass(frozen=True)
class IdentificationResult:
    """One axis identified at one thrust (module docstring): how it ended (:data:`OUTCOMES`), why it
    was aborted, its configuration, every attempt and the best one (the accepted attempt, else the
    highest R²; None without an attempt). The JSON holds each attempt's summary (no series)."""

    axis: str
    thrust: float | None
    outcome: str | None
    abort_reason: str | None
    config: ManoeuvreConfig
    attempts: tuple[IdentificationAttempt, ...]
    best: IdentificationAttempt | None

    def __post_init__(self) -> None:
        require_choice(self, "axis", ("yaw", "pitch"))
        require_choice(self, "outcome", OUTCOMES)
        if (self.best is None) != (not self.attempts):
            raise ValueError("IdentificationResult.best is one of its attempts, None only without any")

    def to_dict(self) -> dict:
        return json_form({"axis": self.axis, "thrust": self.thrust, "outcome": self.outcome,
                          "abort_reason": self.abort_reason, "config": asdict(self.config),
                          "attempts": [a.summary() for a in self.attempts],
                          "best": self.best.summary() if self.best is not None else None})


@dataclass(frozen=True)
class _PitchChoice:
    """A pitch attempt's model: always the online estimate."""

    model: PitchModel
    source: str = ONLINE
    note: str = ""


@dataclass
class _Record:
    time: list[float] = field(default_factory=list)
    signal: list[float] = field(default_factory=list)  # heading (rad, as reported) or pitch
    actuator: list[float] = field(default_factory=list)

    def add(self, time_s: float, signal: float, actuator: float) -> None:
        self.time.append(time_s)
        self.signal.append(signal)
        self.actuator.append(actuator)


class IdentificationManoeuvre(Behaviour):
    """SPEC C4 at one thrust: settle, train (online), resettle, validate, accept or repeat.

    Ends in SUCCESS with an accepted model, FAILURE when no attempt passed validation."""

    def __init__(self, config: ManoeuvreConfig = ManoeuvreConfig(), *, thrust: float | None = None,
                 status_prefix: str = "", settled_speed: Callable[[float, float], str | None] | None = None) -> None:
        """``settled_speed(thrust, speed)``, asked when the settle ends, says why this thrust need not be
        identified (e.g. it gives the speed another thrust already gave), None to go on: the manoeuvre
        then ends at once (SUCCESS, outcome "skipped", no attempt)."""
        if config.axis not in ("yaw", "pitch"):
            raise ValueError(f"axis must be 'yaw' or 'pitch', not {config.axis!r}")
        super().__init__(f"{config.axis} identification")
        self.footprint = Footprint.of(setpoints=(config.actuator, "mode", "heading"))
        self._course = math.nan
        self.config = config
        self.thrust = thrust
        self._prefix = status_prefix
        self._settled_speed = settled_speed
        self.settled_speed = math.nan  # the water speed when the settle ended
        self.stage = SETTLE
        self._stage_start: float | None = None
        self._settle_s = config.settle_s
        self._trim: float = 0.0
        self.attempt = 0
        self.attempts: list[IdentificationAttempt] = []
        self._identifier: YawIdentifier | PitchIdentifier | None = None
        self._choice: YawModelChoice | _PitchChoice | None = None  # the trained model, once training ends
        self._training = _Record()
        self._validation = _Record()
        self._speeds: list[float] = []
        self._last_live = -math.inf
        self._overriding = False
        self._training_time_s = math.nan
        self._steadiness: SteadinessDetector | None = None
        self._holding_mode = ""
        self._recovery: SteadinessDetector | None = None  # fed while the autopilot recovers from the doublet
        self._recovery_lost = False
        self.stage_times: dict[str, float] = {}  # vehicle seconds spent per stage (the campaign's cost)
        self.outcome: str | None = None  # "accepted", "rejected", "aborted"

    @property
    def abort_reason(self) -> str | None:
        return self.reason if self.status is Status.ABORTED else None

    # ------------------------------------------------------------------ lifecycle
    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        self._stage_start = telemetry.time_s
        self._new_steadiness(telemetry)
        limit = "until steady, at most " if self.config.steadiness is not None else ""
        return [self._status(f"settling {limit}{self.config.settle_s:.0f} s")]

    def _new_steadiness(self, telemetry: Telemetry) -> None:
        rule = self.config.steadiness
        # the course is known once a record started; before, only the rates count
        self._steadiness = SteadinessDetector(rule, self.config.axis, self._course) if rule is not None else None

    def _settled(self, telemetry: Telemetry, t_rel: float, limit_s: float) -> bool:
        """The settle (or resettle) may end: its fixed time is up, or the vehicle is steady."""
        if t_rel >= limit_s:
            return True
        detector = self._steadiness
        if detector is None:
            return False
        detector.add(telemetry.time_s, telemetry.speed_water, telemetry.yaw_rate, telemetry.pitch_rate, telemetry.yaw,
                     telemetry.thrust_ratio)
        return detector.steady(telemetry.time_s)

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        now = telemetry.time_s
        stage_start = self._stage_start
        if stage_start is None:  # initialise starts the first stage
            raise RuntimeError(f"{self.name} updated before it was initialised")
        if now == stage_start and self.stage == SETTLE and not self.attempts:
            return []  # the first snapshot only starts the settle (initialise)
        t_rel = now - stage_start
        if self.stage == SETTLE:
            return self._step_settle(telemetry, t_rel)
        if self.stage == TRAIN:
            return self._step_train(telemetry, t_rel)
        if self.stage == RESETTLE:
            if self._settled(telemetry, t_rel, self.config.resettle_s):
                self._enter(VALIDATE, now)
                return [self._status(f"validating on a fresh {self.config.validation_amplitude:.2f} rad doublet")]
            return []
        if self.stage == VALIDATE:
            return self._step_validate(telemetry, t_rel)
        return []

    def terminate(self, status: Status) -> Sequence[Command]:
        """An abort releases the actuator (every stage already releases it before it ends)."""
        if status is not Status.ABORTED:
            return []
        self.outcome = "aborted"
        self.stage = DONE
        self._overriding = False
        return [ReleaseActuator(self.config.actuator)]

    # ------------------------------------------------------------------ stages
    def _enter(self, stage: str, now: float) -> None:
        if self._stage_start is not None:
            self.stage_times[self.stage] = self.stage_times.get(self.stage, 0.0) + (now - self._stage_start)
        self.stage = stage
        self._stage_start = now
        rule = self.config.steadiness  # set when there is a detector (_new_steadiness)
        if stage in (SETTLE, RESETTLE) and self._steadiness is not None and rule is not None:
            self._steadiness = SteadinessDetector(rule, self.config.axis, self._course)

    def _signal(self, telemetry: Telemetry) -> float:
        return telemetry.yaw if self.config.axis == "yaw" else telemetry.pitch

    def _actuator(self, telemetry: Telemetry) -> float:
        return telemetry.rudder if self.config.axis == "yaw" else telemetry.elevator

    def _step_settle(self, telemetry: Telemetry, t_rel: float) -> list[Command]:
        if not self._settled(telemetry, t_rel, self._settle_s):
            return []
        still = self._not_moving(telemetry)
        if still is not None:
            self.stage = DONE
            self.outcome = "not moving"
            self.finish(Status.FAILURE, still)
            return [StatusText(still[:50], 4)]
        self.settled_speed = telemetry.speed_water
        if self._settled_speed is not None and self.thrust is not None and telemetry.finite("speed_water"):
            skip = self._settled_speed(self.thrust, telemetry.speed_water)
            if skip is not None:
                self._enter(DONE, telemetry.time_s)
                self.outcome = "skipped"
                self.finish(Status.SUCCESS, skip)
                return [self._status(skip[:40], 4)]
        return self._start_training(telemetry)

    def _not_moving(self, telemetry: Telemetry) -> str | None:
        """Why the vehicle is still at rest at the end of its settle (None: it moves, or it has no
        speed sensor to tell): not armed, not in the holding mode, or no throttle out."""
        rule = self.config.steadiness
        floor = rule.min_speed if rule is not None else SteadinessRule().min_speed
        if not telemetry.finite("speed_water") or telemetry.speed_water >= floor:
            return None
        where = f"at thrust {self.thrust:.2f}" if self.thrust is not None else "at the commanded thrust"
        still = f"the vehicle did not move {where} ({telemetry.speed_water:.2f} m/s after the settle)"
        if not telemetry.armed:
            return f"{still}: it is not armed; arm it (the campaign never arms a vehicle) and start again"
        if telemetry.mode and telemetry.mode not in ("hold", "guided"):
            return f"{still}: it is in {telemetry.mode}, not the holding mode the campaign asked for (mode refused?)"
        if telemetry.finite("thrust_ratio") and abs(telemetry.thrust_ratio) < 0.02:
            return (f"{still}: the throttle stayed at zero; check the throttle output, a motor interlock or "
                    "the speed the thrust asks for (WP_SPEED on ArduRover)")
        return f"{still}: check the propulsion and the thrust the campaign asks for"

    def _start_training(self, telemetry: Telemetry) -> list[Command]:
        self.attempt += 1
        # the doublet is injected around the trim the autopilot is holding now
        actuator = self._actuator(telemetry)
        self._trim = actuator if math.isfinite(actuator) else 0.0
        self._course = telemetry.yaw
        self._holding_mode = telemetry.mode  # the mode the vehicle settled in
        self._recovery, self._recovery_lost = None, False
        self._identifier = self._new_identifier()
        self._training = _Record()
        self._speeds = []
        self._enter(TRAIN, telemetry.time_s)
        return [self._status(f"training, attempt {self.attempt}: {self.config.training_amplitude:.2f} rad doublet")]

    def _watch_recovery(self, telemetry: Telemetry, t_rel: float) -> None:
        """After the training doublet, while the autopilot holds the vehicle in the mode it settled
        in (our simulator and PX4 release the actuator back to it; ArduPilot's open-loop excitation
        stays in MANUAL until the record ends), its recovery feeds a steadiness detector the resettle
        then continues."""
        if self.config.steadiness is None or self._overriding or t_rel < self.config.excitation_end_s:
            return
        if not telemetry.mode or telemetry.mode != self._holding_mode:
            self._recovery, self._recovery_lost = None, True
            return
        if self._recovery_lost:
            return
        if self._recovery is None:
            self._recovery = SteadinessDetector(self.config.steadiness, self.config.axis, self._course)
        self._recovery.add(telemetry.time_s, telemetry.speed_water, telemetry.yaw_rate, telemetry.pitch_rate,
                           telemetry.yaw, telemetry.thrust_ratio)

    def _reengage(self) -> list[Command]:
        """The holding mode and the course again once a record ends: on autopilots whose open-loop
        excitation needs another mode (ArduSub's MANUAL) this is what ends it; elsewhere a no-op."""
        heading = [SetHeading(self._course)] if math.isfinite(self._course) else []
        return [SetMode("hold"), *heading]

    def _new_identifier(self):
        # convergence only counts once the whole doublet has been seen (eq. 3.39 + thesis §3.3.1)
        rule = ConvergenceRule(min_time_s=self.config.excitation_end_s + self.config.convergence_delay_s,
                               relative_drift=self.config.convergence_drift,
                               noise_band=self.config.convergence_noise_band)
        kwargs = {"p0": self.config.p0, "rule": rule, "input_hold": self.config.input_hold,
                  "output_hold": self.config.output_hold}
        if self.config.svf_bandwidth is not None:
            kwargs["bandwidth"] = self.config.svf_bandwidth
        return YawIdentifier(**kwargs) if self.config.axis == "yaw" else PitchIdentifier(**kwargs)

    def _attempt_identifier(self) -> YawIdentifier | PitchIdentifier:
        """The identifier of the attempt under way (made when its training starts)."""
        if self._identifier is None:
            raise RuntimeError("no identification attempt under way")
        return self._identifier

    def _excitation(self, t_rel: float, amplitude: float) -> list[Command]:
        offset = doublet(t_rel, self.config.pre_excitation_s, self.config.doublet_period_s, amplitude)
        if offset is not None:
            self._overriding = True
            return [OverrideActuator(self.config.actuator, self._trim + offset)]
        if self._overriding:
            self._overriding = False
            return [ReleaseActuator(self.config.actuator)]
        return []

    def _step_train(self, telemetry: Telemetry, t_rel: float) -> list[Command]:
        commands = self._excitation(t_rel, self.config.training_amplitude)
        self._watch_recovery(telemetry, t_rel)
        signal, actuator = self._signal(telemetry), self._actuator(telemetry)
        if math.isfinite(signal) and math.isfinite(actuator):
            self._attempt_identifier().update(telemetry.time_s, signal, actuator)
            self._training.add(telemetry.time_s, signal, actuator)
        if math.isfinite(telemetry.speed_water):
            self._speeds.append(telemetry.speed_water)
        commands += self._live_values(telemetry.time_s)
        after_excitation = t_rel >= self.config.excitation_end_s
        converged = self.config.stop_on_convergence and after_excitation and self._attempt_identifier().converged
        if converged or t_rel >= self.config.window_s:
            if self._overriding:  # never leave the stage holding the actuator
                self._overriding = False
                commands.append(ReleaseActuator(self.config.actuator))
            self._training_time_s = t_rel
            recovery = self._recovery
            self._enter(RESETTLE, telemetry.time_s)
            if recovery is not None:
                # the autopilot has held the vehicle since the doublet was released: what the
                # resettle waits for may already have been seen (it still needs a full window)
                self._steadiness = recovery
            commands += self._reengage()
            self._choice = self._trained_model()
            commands.append(self._status(f"trained in {t_rel:.1f} s: {self._describe(self._choice.model)}"))
            if self._choice.note:
                commands.append(self._status(self._choice.note[:200]))
        return commands

    def _step_validate(self, telemetry: Telemetry, t_rel: float) -> list[Command]:
        commands = self._excitation(t_rel, self.config.validation_amplitude)
        signal, actuator = self._signal(telemetry), self._actuator(telemetry)
        if math.isfinite(signal) and math.isfinite(actuator):
            self._validation.add(telemetry.time_s, signal, actuator)
        if t_rel < self.config.validation_window_s:
            return commands
        if self._overriding:
            self._overriding = False
            commands.append(ReleaseActuator(self.config.actuator))
        commands += self._reengage()
        commands += self._finish_attempt(telemetry.time_s)
        return commands

    def _trained_model(self) -> YawModelChoice | _PitchChoice:
        """The attempt's model: the online estimate, or for yaw the bounded-pole refit of the training
        record where that says the online one cannot be trusted (eq. 3.38p)."""
        online = self._attempt_identifier().model()
        if not isinstance(online, YawEstimate):
            return _PitchChoice(online)
        try:
            fit = fit_yaw_bounded_pole(self._training.time, self._training.signal, self._training.actuator)
        except ValueError as exc:
            log.warning("no bounded-pole fit of the training record: %s", exc)
            fit = None
        choice = choose_yaw_model(online, fit)
        if choice.note:
            log.info("yaw attempt %d: %s", self.attempt, choice.note)
        return choice

    def _finish_attempt(self, now: float) -> list[Command]:
        choice = self._choice if self._choice is not None else self._trained_model()
        self._choice = None
        model = choice.model
        r2 = self._score(model)
        quality = {name: sampling_quality(record.time) for name, record in
                   (("training", self._training), ("validation", self._validation))}
        spoiled = next((f"{name} record: {verdict}" for name, q in quality.items()
                        if (verdict := q.verdict(self.config.sampling)) is not None), None)
        passed = math.isfinite(r2) and r2 >= self.config.r2_threshold
        # a fit that reproduces the fresh record but is no model (unstable, inverted) is not accepted
        not_model = no_model_reason(model) if passed and spoiled is None else None
        rejected_for = spoiled or not_model
        rejection = Rejection.LINK if spoiled else Rejection.NOT_A_MODEL if not_model else None
        accepted = passed and rejected_for is None
        speed = sum(self._speeds) / len(self._speeds) if self._speeds else math.nan
        self.attempts.append(IdentificationAttempt(
            attempt=self.attempt, axis=self.config.axis, thrust=self.thrust, speed=speed, model=model, r2=r2,
            accepted=accepted, converged=bool(self._attempt_identifier().converged), converged_s=self._converged_s(),
            criterion_met_from_s=self._attempt_identifier().criterion_met_from_s,
            training_s=self._training_time_s, samples=len(self._training.time),
            training=self._series(self._training, history=True),
            validation=self._series(self._validation, model=model),
            sampling={name: q.as_json() for name, q in quality.items()}, rejected_for=rejected_for,
            rejection=rejection, model_source=choice.source, model_note=choice.note))
        self._validation = _Record()
        verdict = "accepted" if accepted else "rejected"
        commands: list[Command] = [self._status(f"validation R2 {r2:.3f}: {verdict}")]
        if spoiled is not None:
            log.warning("%s attempt %d not used: %s", self.config.axis, self.attempt, spoiled)
            commands.append(self._status("record rejected: the link lost samples", 4))
        if not_model is not None:
            log.warning("%s attempt %d not used: %s", self.config.axis, self.attempt, not_model)
            commands.append(self._status(f"rejected, not a model: {self._describe(model)}", 4))  # ASCII
        if accepted:
            self.outcome = "accepted"
            self._enter(DONE, now)
            self.finish(Status.SUCCESS)
        elif self.attempt >= self.config.max_attempts:
            self.outcome = "rejected"
            self._enter(DONE, now)
            reason = self._rejection_reason()
            self.finish(Status.FAILURE, reason)
            commands.append(self._status(reason, 4))
        else:  # repeat from the training stage after a short resettle (bounded by max_attempts)
            self._settle_s = self.config.resettle_s
            self._enter(SETTLE, now)
        return commands

    # ------------------------------------------------------------------ helpers
    def _rejection_reason(self) -> str:
        """Why no attempt gave a model, naming the real cause: when the link spoiled every record,
        the link (what to fix), not the model."""
        spoiled = [a.rejected_for for a in self.attempts if a.spoiled_by_link]
        if spoiled and len(spoiled) == len(self.attempts):
            return (f"the link spoiled all {len(spoiled)} attempts ({spoiled[-1]}): no model could be trusted; "
                    "fix the link (a radio's range or air rate, a serial port's baud rate) and fly again")
        reason = f"no model passed validation after {self.attempt} attempts"
        causes = [f"{len(spoiled)} of them spoiled by the link"] if spoiled else []
        not_models = sum(1 for a in self.attempts if a.rejected_for is not None and not a.spoiled_by_link)
        if not_models:
            causes.append(f"{not_models} of them passing with an estimate that is not a model")
        return reason + (f" ({'; '.join(causes)})" if causes else "")

    def _score(self, model) -> float:
        record = self._validation
        if len(record.time) < 10:
            return math.nan
        validate = validate_yaw if self.config.axis == "yaw" else validate_pitch
        try:
            return float(validate(model, record.time, record.signal, record.actuator))
        except (ValueError, FloatingPointError, ZeroDivisionError) as exc:
            log.warning("validation failed: %s", exc)
            return math.nan

    def _converged_s(self) -> float | None:
        value = getattr(self._identifier, "converged_at_s", None)
        return float(value) if value is not None else None

    def _series(self, record: _Record, *, history: bool = False, model=None) -> dict:
        series: dict = {"time": list(record.time), "signal": list(record.signal), "actuator": list(record.actuator)}
        if history:
            series["history"] = _history_dict(self._attempt_identifier().history_table)
        if model is not None and len(record.time) >= 2:
            series["simulated"] = _simulate(self.config.axis, model, record)
        return series

    def _live_values(self, now: float) -> list[Command]:
        if now - self._last_live < self.config.live_value_period_s:
            return []
        self._last_live = now
        model = _model_dict(self._attempt_identifier().model())
        return [NamedValue(name[:10], value) for name, value in model.items() if isinstance(value, float)]

    def _describe(self, model) -> str:
        values = _model_dict(model)
        return " ".join(f"{name} {value:.3f}" for name, value in values.items() if isinstance(value, float))

    def _status(self, text: str, severity: int = 6) -> StatusText:
        return StatusText(f"{self._prefix}{self.config.axis}: {text}", severity)

    @property
    def best(self) -> IdentificationAttempt | None:
        """The accepted attempt, else the one with the highest R² (None before any attempt)."""
        accepted = [a for a in self.attempts if a.accepted]
        if accepted:
            return accepted[-1]
        return max(self.attempts, key=lambda a: _nan_low(a.r2)) if self.attempts else None

    def result(self) -> IdentificationResult:
        return IdentificationResult(self.config.axis, self.thrust, self.outcome, self.abort_reason, self.config,
                                    tuple(self.attempts), self.best)


def _nan_low(value: float) -> float:
    return value if isinstance(value, float) and math.isfinite(value) else -math.inf


def _model_dict(model) -> dict:
    """Numbers of a YawEstimate/YawModel/PitchModel as a plain dict (covariance as nested lists)."""
    out: dict[str, float | list[list[float]] | None] = {}
    for name, value in vars(model).items():
        if name == "covariance":
            out[name] = None if value is None else [[float(x) for x in row] for row in value]
        elif isinstance(value, (int, float)):
            out[name] = float(value)
    return out


def _history_dict(history) -> dict | None:
    if history is None:
        return None
    if isinstance(history, dict):
        return {key: [float(x) for x in values] for key, values in history.items()}
    return None


def _simulate(axis: str, model, record: _Record) -> list[float]:
    from companion.numerics.validation import simulate_pitch, simulate_yaw  # same numerics as the score

    import numpy as np

    simulate: Callable = simulate_yaw if axis == "yaw" else simulate_pitch
    signal = np.unwrap(np.asarray(record.signal)) if axis == "yaw" else np.asarray(record.signal)
    try:
        return [float(x) for x in simulate(model, record.time, record.actuator, float(signal[0]))]
    except (ValueError, FloatingPointError) as exc:
        log.warning("could not simulate the model for the plot: %s", exc)
        return []
