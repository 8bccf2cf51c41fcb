"""The pre-mission self-identification campaign (SPEC C4, C5; thesis §3.3, §3.5).

One behaviour that runs, in order:

1. the heading-and-depth holding mode at the campaign depth, on the current course;
2. for each thrust setting: the yaw identification manoeuvre (and the pitch one, if asked);
3. the heading gain design from the accepted yaw models: the laws a22(u) ≈ const and
   b2(u) = k·u² + c fitted over them, PI gains per speed (``companion.numerics.gains``);
4. optional heading-step checks at every thrust with the original gains, one constant gain tuned at
   the lowest thrust, and the speed-scheduled gains (thesis Fig. 3.16);
5. the scheduled gains for the current speed written to the autopilot.

It is a pure step function of telemetry like every behaviour; the application (``companion.procedures.app``)
runs it over the link with a restore point, and drains :attr:`events` after every step into the
store, so nothing already measured is lost if the process dies.
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field, replace
from typing import Sequence

from behaviors.heading_steps import HeadingStepTest, StepTestConfig, reengage_hold
from behaviors.identification import IdentificationManoeuvre, ManoeuvreConfig, thesis_estimator
from behaviors.sequence import Instant, SequenceBehavior
from companion.interface import (
    Behavior,
    Command,
    SetDepth,
    SetHeading,
    SetMode,
    SetParameters,
    SetThrust,
    StatusText,
    Telemetry,
)
from companion.numerics.gains import GainBounds, HeadingGains, design_heading_gains
from companion.numerics.identification import YawModel
from companion.numerics.schedule import YawSchedule, fit_yaw_schedule

log = logging.getLogger(__name__)

DEFAULT_THRUSTS = (0.60, 0.70, 0.80, 0.90, 1.00)


@dataclass(frozen=True)
class CampaignConfig:
    """Everything that shapes a campaign; stored with it."""

    thrusts: tuple[float, ...] = DEFAULT_THRUSTS
    depth: float = 2.0  # m (thesis §3.3.1: straight runs at 2 m)
    axes: tuple[str, ...] = ("yaw", "pitch")
    yaw: ManoeuvreConfig = ManoeuvreConfig()
    pitch: ManoeuvreConfig = ManoeuvreConfig(axis="pitch", settle_s=15.0, training_amplitude=0.10,
                                             validation_amplitude=0.06)
    bounds: GainBounds = GainBounds()
    write_gains: bool = True
    step_labels: tuple[str, ...] = ("original", "constant", "scheduled")  # () skips the step checks
    step_test: StepTestConfig = StepTestConfig()

    def to_dict(self) -> dict:
        return asdict(self)

    def with_thesis_estimator(self) -> "CampaignConfig":
        """The seeds' exact estimator on both axes (P0 = 100·I, zero-order holds)."""
        return replace(self, yaw=thesis_estimator(self.yaw), pitch=thesis_estimator(self.pitch))


def gains_to_params(gains: HeadingGains) -> dict[str, float]:
    """Neutral parameter names (see ``companion.link.profiles``) of a heading gain set."""
    return {"heading_p": float(gains.kp), "heading_i": float(gains.ki), "rudder_trim": float(gains.trim)}


@dataclass
class DesignOutcome:
    schedule: YawSchedule | None
    per_thrust: list[dict] = field(default_factory=list)
    error: str | None = None


def constant_schedule(speed: float, model: YawModel) -> YawSchedule:
    """A campaign at a single speed cannot fit b2(u): keep that model's gains at every speed
    (no extrapolation of an unknown law) — the honest fallback, logged by the caller."""
    if not (model.a22 < 0 and model.b2 > 0):
        raise ValueError("the model needs a22 < 0 and b2 > 0")
    return YawSchedule(a22=model.a22, b2_slope=0.0, b2_intercept=model.b2, delta0=model.delta0,
                       speed_range=(speed, speed), b2_min_identified=model.b2, speeds=[speed])


def design_from_attempts(accepted: Sequence[dict], bounds: GainBounds) -> DesignOutcome:
    """Fit the schedule over the accepted yaw attempts and design gains at each of their speeds."""
    usable = [a for a in accepted if a["axis"] == "yaw" and math.isfinite(a.get("speed") or math.nan)]
    if not usable:
        return DesignOutcome(None, error="no accepted yaw model")
    models = [YawModel(a["model"]["a22"], a["model"]["b2"], a["model"]["delta0"]) for a in usable]
    speeds = [a["speed"] for a in usable]
    try:
        if len({round(u, 3) for u in speeds}) == 1:
            schedule = constant_schedule(speeds[-1], models[-1])
        else:
            schedule = fit_yaw_schedule(speeds, models)
    except ValueError as exc:
        return DesignOutcome(None, error=f"schedule fit failed: {exc}")
    per_thrust = []
    for attempt, model in zip(usable, models):
        own = design_heading_gains(model, bounds, speed=attempt["speed"])
        scheduled = schedule.gains_at(attempt["speed"], bounds)
        per_thrust.append({"thrust": attempt["thrust"], "speed": attempt["speed"], "kp": own.kp, "ki": own.ki,
                           "trim": own.trim, "scheduled": gains_to_params(scheduled)})
    return DesignOutcome(schedule, per_thrust)


class IdentificationCampaign:
    """The campaign as one behaviour (see module docstring)."""

    def __init__(self, config: CampaignConfig = CampaignConfig(), original_gains: dict[str, float] | None = None) -> None:
        self.config = config
        self.original_gains = dict(original_gains or {})
        self.events: list[dict] = []  # drained by the application: {"type": "run"|"steps"|"gains", ...}
        self.accepted: list[dict] = []
        self.manoeuvres: list[dict] = []
        self.design: DesignOutcome | None = None
        self.step_results: list[dict] = []
        self.final_gains: dict[str, float] | None = None
        self._sequence: SequenceBehavior | None = None
        self._course = math.nan
        self.status: str = "pending"
        self.reason: str | None = None
        self._total = 0

    # ------------------------------------------------------------------ construction
    def _build(self, course: float) -> SequenceBehavior:
        cfg = self.config
        items: list = [Instant(SetMode("hold"), SetDepth(cfg.depth), SetHeading(course), SetThrust(cfg.thrusts[0]),
                               StatusText(f"identification campaign: {len(cfg.thrusts)} thrusts, axes {','.join(cfg.axes)}"),
                               name="prepare")]
        for index, thrust in enumerate(cfg.thrusts):
            prefix = f"[{index + 1}/{len(cfg.thrusts)} T{thrust * 100:.0f}] "
            items.append(Instant(SetThrust(thrust), SetHeading(course), name=f"thrust {thrust:.2f}"))
            for axis in cfg.axes:
                manoeuvre_config = cfg.yaw if axis == "yaw" else cfg.pitch
                items.append(IdentificationManoeuvre(replace(manoeuvre_config, axis=axis), thrust=thrust,
                                                     status_prefix=prefix))
        items.append(self._design_step)
        for thrust in cfg.thrusts:
            for label in cfg.step_labels:
                items.append(self._step_test_factory(thrust, label))
        items.append(self._final_gains_step)
        # progress counts the manoeuvres and the step checks (the design and the final write are instants)
        self._total = len(cfg.thrusts) * (len(cfg.axes) + len(cfg.step_labels))
        return SequenceBehavior(items, on_complete=self._on_complete)

    def _design_step(self) -> Behavior:
        self.design = design_from_attempts(self.accepted, self.config.bounds)
        if self.design.error:
            log.warning("gain design: %s", self.design.error)
            return Instant(StatusText(f"gain design skipped: {self.design.error}", 4), name="design")
        self.events.append({"type": "design", "design": self.design_summary()})
        s = self.design.schedule
        return Instant(StatusText(f"schedule: a22 {s.a22:.3f}, b2 = {s.b2_slope:.3f} u^2 + {s.b2_intercept:.3f}"),
                       name="design")

    def _gains_for(self, label: str, thrust: float) -> dict[str, float] | None:
        """Gains of one heading-step check: the originals, one constant set, or the scheduled set."""
        if self.design is None or self.design.schedule is None:
            return None
        if label == "original":
            return self.original_gains or None
        speeds = {row["thrust"]: row["speed"] for row in self.design.per_thrust}
        if label == "constant":  # one gain tuned at the lowest identified thrust, used everywhere
            lowest = min(self.design.per_thrust, key=lambda row: row["thrust"])
            return dict(lowest["scheduled"])
        speed = speeds.get(thrust)
        if speed is None:  # this thrust has no accepted model: extrapolate on the nearest speed
            nearest = min(self.design.per_thrust, key=lambda row: abs(row["thrust"] - thrust))
            speed = nearest["speed"]
        return gains_to_params(self.design.schedule.gains_at(speed, self.config.bounds))

    def _step_test_factory(self, thrust: float, label: str):
        def build() -> Behavior | None:
            gains = self._gains_for(label, thrust)
            if gains is None:
                return None
            return HeadingStepTest(thrust, gains, self.config.step_test, label=label)
        return build

    def _final_gains_step(self) -> Behavior | None:
        """Write the scheduled gains for the speed measured now (the scheduler keeps them matched later)."""
        if not self.config.write_gains or self.design is None or self.design.schedule is None:
            return None
        return Instant(name="write gains", make=self._write_scheduled_gains)

    def _write_scheduled_gains(self, telemetry: Telemetry) -> list[Command]:
        schedule = self.design.schedule
        speed = telemetry.speed_water if telemetry.finite("speed_water") else schedule.speed_range[0]
        gains = gains_to_params(schedule.gains_at(speed, self.config.bounds))
        self.final_gains = gains
        self.events.append({"type": "gains", "speed": speed, "before": self.original_gains, "after": gains})
        thrust = telemetry.thrust_ratio if telemetry.finite("thrust_ratio") else self.config.thrusts[-1]
        return [SetParameters(gains), *reengage_hold(thrust, telemetry.yaw),
                StatusText(f"heading gains written for {speed:.2f} m/s: kp {gains['heading_p']:.3f}"
                           f" ki {gains['heading_i']:.3f} trim {gains['rudder_trim']:.3f}")]

    # ------------------------------------------------------------------ events
    def _on_complete(self, behavior: Behavior) -> None:
        if isinstance(behavior, IdentificationManoeuvre):
            result = behavior.result()
            self.manoeuvres.append(result)
            for attempt in result["attempts"]:
                self.events.append({"type": "run", "attempt": attempt})
                if attempt["accepted"]:
                    self.accepted.append(attempt)
        elif isinstance(behavior, HeadingStepTest):
            result = behavior.result()
            self.step_results.append(result)
            self.events.append({"type": "steps", "result": result})

    def progress(self) -> float:
        """Fraction of the campaign's manoeuvres and checks completed (0..1), for COMMAND_ACK."""
        if self.status == "completed":
            return 1.0
        if self._sequence is None or not self._total:
            return 0.0
        done = sum(1 for b in self._sequence.completed if isinstance(b, (IdentificationManoeuvre, HeadingStepTest)))
        return min(1.0, done / self._total)

    def design_summary(self) -> dict | None:
        if self.design is None or self.design.schedule is None:
            return None
        s = self.design.schedule
        return {"a22": s.a22, "b2_slope": s.b2_slope, "b2_intercept": s.b2_intercept, "delta0": s.delta0,
                "per_thrust": self.design.per_thrust}

    # ------------------------------------------------------------------ behaviour protocol
    @property
    def done(self) -> bool:
        return self.status in ("completed", "aborted")

    def step(self, telemetry: Telemetry) -> Sequence[Command]:
        if self.done:
            return []
        if self._sequence is None:
            if not telemetry.finite("yaw"):
                return []
            self._course = telemetry.yaw
            self._sequence = self._build(self._course)
            self.status = "running"
        commands = list(self._sequence.step(telemetry))
        if self._sequence.done:
            self.status = "completed"
            commands.append(StatusText(f"campaign complete: {len(self.accepted)} models accepted"))
        return commands

    def abort(self, reason: str) -> Sequence[Command]:
        self.status, self.reason = "aborted", reason
        return list(self._sequence.abort(reason)) if self._sequence is not None else []

    def result(self) -> dict:
        return {
            "status": self.status,
            "reason": self.reason,
            "config": self.config.to_dict(),
            "manoeuvres": [{k: v for k, v in m.items() if k != "attempts"} for m in self.manoeuvres],
            "accepted": [{k: v for k, v in a.items() if k not in ("training", "validation")} for a in self.accepted],
            "design": self.design_summary(),
            "steps": [{k: v for k, v in r.items() if k != "series"} for r in self.step_results],
            "final_gains": self.final_gains,
        }
