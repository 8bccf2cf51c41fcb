"""Which heading steps a short campaign flies, what it predicts instead, and when its gains stay
(SPEC C5: "every design is checked by heading steps through the autopilot before it is kept").

The thesis compared three gain sets by flying each at every speed (Fig. 3.16): 15 steps, four fifths
of a campaign's time at sea. A product only needs to know that the gains it writes are good:

* **flown**: the designed gains' step at the lowest and the highest identified speed. The schedule
  between them is an interpolation of one design rule through models that each passed validation
  (R² ≥ 0.9 on a fresh record), and those two speeds bracket the dynamics (the slowest and the
  fastest yaw response). The lowest is flown right after its own model was accepted, with that
  model's own design (the vehicle is there and steady: no extra settle); the highest at the end,
  with the fitted schedule. A step is ``behaviors.verification.VerificationStep``: one step that
  ends when it has decided.
* **predicted**: every other step — the schedule at each identified speed, and the original gains
  everywhere — flown on the accepted model under the autopilot's own heading controller
  (``companion.numerics.step_response``, eq. A.1 / A.2 / A.4 / A.5), on a skid-steered boat through
  its mixer, thrust and speed (eq. A.2k, :func:`skid_plant`): there the identified model alone
  predicted ArduRover's quick steps 26–47 % faster than flown.

:class:`KeepRule` decides. The gains are written only when (1) every flown step decided, overshot at
most ``max_overshoot_pct`` and reversed at most ``max_oscillations`` times; (2) the model predicted
each flown step (overshoot within ``overshoot_tolerance_pct`` points, step error within
``iae_tolerance`` of it) — otherwise the predictions cannot stand in for flights and the original
gains are flown at that speed too, and compared as flown; (3) at every identified speed the
schedule's predicted step passes (1) and its error is below the original gains' (predicted, or
flown where (2) failed); and (4) a speed flown with its own model's design is covered by the
schedule: the two predicted steps agree within the same tolerances, else the schedule is flown
there too. Measured on the simulator (in-process, 3 seeds × 5 speeds): predicted overshoot within
0.5 points of the flown one for the original gains and 0.1–2 points below it for the designed
ones (the flown step's noise), predicted step error 3–6 % above the flown one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Iterable, Mapping, Sequence, Union

import numpy as np

from behaviors.json_form import json_form
from behaviors.verification import VerificationResult
from companion.checks import require_non_negative, require_positive
from companion.link.autopilots import registered_profiles
from companion.numerics.skid_step import SkidMixer, SkidPlant, SpeedHold
from companion.numerics.speed_law import choose_speed_law
from companion.numerics.rate_loop import ARDUROVER_RATE_LOOP, RateLoopForm
from companion.numerics.step_design import StepCase, cascade_case, pi_case, px4_rover_case, px4_uuv_case
from companion.numerics.step_figures import PredictedStep, StepFigures
from companion.numerics.step_response import predict_step
from companion.numerics.surge import SurgeModel, steady_law

#: the autopilot's heading controller each schedule kind is the gains of (eq. A.1, A.2, A.4, A.5), as
#: each registered autopilot's module declares it (``AutopilotProfile.heading_controller``)
CONTROLLERS = {profile.heading_schedule: profile.heading_controller for profile in registered_profiles()}
#: read with the original gains (never written: a restore finds them unchanged), for the predictions;
#: a profile declares those its autopilot has (PX4's rover: RA_MAX_STR_ANG, RA_STR_RATE_LIM,
#: RO_YAW_RATE_LIM, RO_YAW_ACCEL_LIM, RO_YAW_RATE_TH; its UUV: UUV_TORQUE_SAT)
LIMIT_PARAMETERS = ("rudder_max", "rudder_rate", "heading_imax", "turn_rate_max", "heading_rate_imax",
                    "turn_accel_max", "steering_scale_speed", "steering_max", "steering_rate_max",
                    "yaw_rate_threshold", "torque_max", "input_tc", "yaw_slew_max", "rate_ff_enabled")


@dataclass(frozen=True)
class HeadingLimits:
    """What bounds a heading step besides the gains: the rudder's limit and slew rate (rad, rad/s),
    the PI's integrator clamp (rad), the cascade's full scale (rad per unit output), turn-rate
    limit (rad/s), turn-acceleration limit (rad/s²), the speed above which its output is scaled
    down (m/s, eq. A.2; None: never) and its rate integrator's clamp (fraction of the output); PX4's
    steering slew (RA_STR_RATE_LIM, rad/s), yaw-rate measurement threshold (RO_YAW_RATE_TH, rad/s)
    and UUV torque limit (UUV_TORQUE_SAT, fraction of full torque), eq. A.4 / A.5; a skid-steered
    boat's mixer, thrust and speed, eq. A.2k."""

    rudder_max: float
    rudder_rate: float = math.inf
    imax: float = 0.15
    full_scale: float = 0.5236
    rate_max: float = math.inf
    rate_accel_max: float = math.inf
    output_scale_base: float | None = None
    rate_imax: float = 1.0  # the cascade's rate integrator clamp, a fraction of the output
    steering_rate: float = math.inf  # PX4 rover: RA_STR_RATE_LIM (inf: not configured)
    rate_threshold: float = 0.0  # PX4 rover: RO_YAW_RATE_TH
    torque_max: float = 1.0  # PX4 UUV: UUV_TORQUE_SAT
    input_tc: float = 0.0  # ArduSub: ATC_INPUT_TC where ATC_RATE_FF_ENAB shapes the set-point (eq. A.2s); 0: none
    yaw_slew_max: float = math.inf  # ArduSub: ATC_SLEW_YAW, rad/s
    #: a skid-steered boat's mixer, thrust and speed (eq. A.2k; the campaign's :func:`skid_plant`), None otherwise
    skid: SkidPlant | None = None
    #: PX4 UUV: the surge thrust (0–1) flown at each speed, (speed, thrust) pairs, which the yaw
    #: torque is allocated beside (eq. A.5a); empty: not known
    forward_thrust: tuple[tuple[float, float], ...] = ()
    #: the rate loop's form (eq. A.2r), for the turn-rate verification's replay (learning during missions)
    rate_loop: RateLoopForm = ARDUROVER_RATE_LOOP

    def __post_init__(self) -> None:
        if self.skid is not None and not isinstance(self.skid, SkidPlant):
            raise ValueError(f"HeadingLimits.skid must be a SkidPlant or None, not {self.skid!r}")
        for speed, thrust in self.forward_thrust:
            if not (math.isfinite(speed) and math.isfinite(thrust) and 0.0 <= thrust <= 1.0):
                raise ValueError(f"HeadingLimits.forward_thrust: a (speed, thrust 0..1) pair, not {(speed, thrust)!r}")
        if not isinstance(self.rate_loop, RateLoopForm):
            raise ValueError(f"HeadingLimits.rate_loop must be a RateLoopForm, not {self.rate_loop!r}")

    def thrust_at(self, speed: float) -> float:
        """The surge thrust at ``speed``, linear between the pairs flown and held beyond them (NaN:
        none known, or no speed)."""
        if not self.forward_thrust or not math.isfinite(speed):
            return math.nan
        pairs = sorted(self.forward_thrust)
        return float(np.interp(speed, [u for u, _ in pairs], [t for _, t in pairs]))

    @classmethod
    def from_vehicle(cls, values: dict[str, float], *, full_scale: float, rudder_rate: float | None,
                     output_scale_base: float | None = None,
                     rate_loop: RateLoopForm = ARDUROVER_RATE_LOOP) -> "HeadingLimits":
        """From the parameters read with the original gains (:data:`LIMIT_PARAMETERS`; ArduPilot's
        and PX4's turn limits and PX4's steering slew in degrees) and the profile's rudder full scale
        and servo rate; what the vehicle does not say takes the profile's. ``output_scale_base``: the
        design's (CascadeRules), which knows whether this frame's output is scaled at all."""
        rate = values.get("rudder_rate", rudder_rate if rudder_rate else math.inf)
        turn = values.get("turn_rate_max", 0.0)
        accel = values.get("turn_accel_max", 0.0)
        steering_rate = values.get("steering_rate_max", 0.0)
        threshold = values.get("yaw_rate_threshold", 0.0)
        torque = values.get("torque_max", 1.0)
        shaped = "input_tc" in values and values.get("rate_ff_enabled", 1.0) > 0.0
        tc = values.get("input_tc", 0.0) if shaped else 0.0
        slew = values.get("yaw_slew_max", 0.0)
        return cls(rudder_max=values.get("rudder_max", values.get("steering_max", full_scale)),
                   rudder_rate=rate if rate and rate > 0 else math.inf,
                   imax=values.get("heading_imax", 0.15), full_scale=full_scale,
                   rate_max=math.radians(turn) if turn and turn > 0 else math.inf,
                   rate_accel_max=math.radians(accel) if accel and accel > 0 else math.inf,
                   output_scale_base=output_scale_base,
                   rate_imax=imax if (imax := values.get("heading_rate_imax", 1.0)) and imax > 0 else 1.0,
                   steering_rate=math.radians(steering_rate) if steering_rate and steering_rate > 0 else math.inf,
                   rate_threshold=math.radians(threshold) if threshold and threshold > 0 else 0.0,
                   torque_max=min(max(torque, 0.0), 1.0) if math.isfinite(torque) else 1.0,
                   input_tc=tc if math.isfinite(tc) and tc > 0 else 0.0,
                   yaw_slew_max=math.radians(slew) if math.isfinite(slew) and slew > 0 else math.inf,
                   rate_loop=rate_loop)


def limits_case(controller: str, model, speed: float | None, limits: HeadingLimits) -> StepCase:
    """One predicted-step case under ``controller`` (:data:`CONTROLLERS`' values: eq. A.1, A.2, A.4,
    A.5) on the yaw ``model`` at ``speed`` with the vehicle's ``limits`` (PX4's rover: ``rudder_max``
    is RA_MAX_STR_ANG as read); a skid-steered boat's (``limits.skid``) at a known speed through its
    mixer, thrust and speed (eq. A.2k). ValueError for PX4's rover without a speed (its feed-forward
    divides by it)."""
    at = math.nan if speed is None else speed  # unknown: no output speed scaling (eq. A.2)
    case = _case(controller, model, speed, at, limits)
    if limits.skid is not None and case.controller in ("pi", "cascade") and math.isfinite(at) and at > 0.0:
        case = replace(case, skid=limits.skid.at(at))
    return case


def _case(controller: str, model, speed: float | None, at: float, limits: HeadingLimits) -> StepCase:
    if controller == "cascade":
        return cascade_case(model, at, rudder_max=limits.rudder_max, rudder_rate=limits.rudder_rate,
                            full_scale=limits.full_scale, rate_max=limits.rate_max,
                            rate_accel_max=limits.rate_accel_max, output_scale_base=limits.output_scale_base,
                            rate_imax=limits.rate_imax, input_tc=limits.input_tc, yaw_slew_max=limits.yaw_slew_max)
    if controller == "px4_rover":
        if speed is None or not (math.isfinite(speed) and speed > 0.0):
            raise ValueError(f"PX4's rover step needs a speed > 0, not {speed!r}")
        return px4_rover_case(model, speed, steering_max=limits.rudder_max, rudder_rate=limits.rudder_rate,
                              steering_rate=limits.steering_rate, rate_max=limits.rate_max,
                              rate_accel_max=limits.rate_accel_max, rate_threshold=limits.rate_threshold)
    if controller == "px4_uuv":
        return px4_uuv_case(model, at, full_scale=limits.full_scale, torque_max=limits.torque_max,
                            rudder_rate=limits.rudder_rate, forward_thrust=limits.thrust_at(at))
    return pi_case(model, at, rudder_max=limits.rudder_max, rudder_rate=limits.rudder_rate, imax=limits.imax)


def predicted_step(controller: str, model, gains: dict[str, float], limits: HeadingLimits, step: float,
                   duration_s: float, speed: float | None = None) -> PredictedStep:
    """One heading step of ``step`` rad flown on the yaw ``model`` (a22, b2, δ0) with ``gains`` at
    ``speed`` (m/s: the output's speed scaling), scored over ``duration_s`` (a flown step's own
    length when compared with it: the step error integrates to the end of the record)."""
    case = limits_case(controller, model, speed, limits)
    return predict_step(case.plant, case.controller, gains, abs(step), duration_s, skid=case.skid, **case.limits)


def skid_plant(mixer: SkidMixer, levels: Sequence[tuple[float, float]], surge: SurgeModel | None,
               speeds: Sequence[float], a22: Sequence[float], b2: Sequence[float], law: str | None,
               speed_gains: Mapping[str, float]) -> SkidPlant | None:
    """What eq. A.2k needs of a skid-steered boat, from what its campaign measured: the ``mixer``
    (MOT_THST_ASYM, MOT_STR_THR_MIX read from the vehicle), the surge model (eq. S.4; without one,
    the steady law of the settles' ``levels`` (throttle, speed) and the speed held), a22's slope
    with the speed and b2's speed law (eq. S.3, ``law`` the actuation's prior) over the accepted yaw
    models at ``speeds``, and ArduRover's speed loop as found (``speed_p``, ``speed_i``; the steps are
    flown at a speed demand, eq. S.5). None when no throttle is known at any speed."""
    if surge is not None:
        gain, exponent, gamma, lag = surge.gain, surge.exponent, surge.gamma, surge.lag
    else:
        try:
            gain, exponent = steady_law(levels)
        except ValueError:
            return None
        gamma = lag = 0.0
    if not (math.isfinite(gain) and gain > 0.0 and 0.2 <= exponent <= 3.0):
        return None
    u, a, b = (np.asarray(v, dtype=float) for v in (speeds, a22, b2))
    slope, b2_exponent, ratio = 0.0, 1.0, 0.0
    if np.unique(u).size >= 2:
        slope = float(np.polyfit(u, a, 1)[0])
        if np.all(b > 0.0) and np.all(u > 0.0):
            choice = choose_speed_law(u.tolist(), b.tolist(), prior=law)
            if choice.slope > 0.0:
                b2_exponent, ratio = choice.exponent_of_law, choice.intercept / choice.slope
            else:  # b2 not growing with the speed over the flown ones: held
                b2_exponent, ratio = 0.0, 0.0
    loop = None
    if all(name in speed_gains and math.isfinite(speed_gains[name]) for name in ("speed_p", "speed_i")):
        imax = speed_gains.get("speed_imax", 1.0)
        loop = SpeedHold(max(speed_gains["speed_p"], 0.0), max(speed_gains["speed_i"], 0.0),
                         imax if math.isfinite(imax) and imax > 0.0 else 1.0)
    return SkidPlant(mixer, gain, exponent, max(gamma, 0.0), max(lag, 0.0), slope, b2_exponent, ratio, loop)


@dataclass(frozen=True)
class FlownStep(VerificationResult):
    """A verification step as the campaign recorded it: the step's result and the model's predicted
    step for the same gains (:func:`predicted_step`; None without an accepted model at its thrust)."""

    predicted: PredictedStep | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.predicted is not None and not isinstance(self.predicted, PredictedStep):
            raise ValueError(f"FlownStep.predicted must be a PredictedStep or None, not {self.predicted!r}")

    @classmethod
    def of(cls, result: VerificationResult, predicted: PredictedStep | None) -> "FlownStep":
        return cls(**vars(result), predicted=predicted)

    def to_dict(self) -> dict:
        return {**super().to_dict(),
                "predicted": None if self.predicted is None else json_form(self.predicted.to_dict())}


#: the labels of a predicted step at an identified speed: the schedule's gains or the vehicle's own
PREDICTED_LABELS = ("scheduled", "original")


@dataclass(frozen=True)
class PredictedAtSpeed:
    """A predicted step at one identified speed (:func:`predicted_step`): its ``thrust``, ``speed``
    (m/s; None: not known), ``label`` (:data:`PREDICTED_LABELS`) and the ``step`` itself. Its JSON is
    ``thrust``, ``speed``, ``label`` then the step's keys (``PredictedStep.to_dict``)."""

    thrust: float
    speed: float | None
    label: str
    step: PredictedStep

    def __post_init__(self) -> None:
        if not (isinstance(self.thrust, (int, float)) and math.isfinite(self.thrust)):
            raise ValueError(f"PredictedAtSpeed.thrust must be a finite number, not {self.thrust!r}")
        if self.label not in PREDICTED_LABELS:
            raise ValueError(f"PredictedAtSpeed.label must be one of {', '.join(PREDICTED_LABELS)}, not {self.label!r}")
        if not isinstance(self.step, PredictedStep):
            raise ValueError(f"PredictedAtSpeed.step must be a PredictedStep, not {self.step!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"thrust": self.thrust, "speed": self.speed, "label": self.label, **self.step.to_dict()}


#: a step the keep rule judges: flown (its result), or predicted (:func:`predicted_step`, alone or at a speed)
Step = Union[VerificationResult, PredictedStep, PredictedAtSpeed]


def step_figures(step: Step) -> tuple[float, float, int]:
    """A step's overshoot (%), step error (``iae_s``) and heading reversals, flown or predicted."""
    if isinstance(step, VerificationResult):
        return step.max_overshoot_pct, step.iae_s, step.oscillations
    figures: StepFigures = (step.step if isinstance(step, PredictedAtSpeed) else step).figures
    return figures.overshoot_pct, figures.iae_s, figures.oscillations


@dataclass(frozen=True)
class KeepRule:
    """When verified gains stay on the vehicle (eq. A.3; module docstring)."""

    max_overshoot_pct: float = 10.0
    max_oscillations: int = 1
    overshoot_tolerance_pct: float = 3.0  # points between a flown step's overshoot and its prediction
    iae_tolerance: float = 0.2  # relative difference between a flown step's error and its prediction
    better_than_original: bool = True

    def __post_init__(self) -> None:
        require_non_negative(self, "max_overshoot_pct")
        require_positive(self, "overshoot_tolerance_pct", "iae_tolerance")
        if not (isinstance(self.max_oscillations, int) and self.max_oscillations >= 0):
            raise ValueError(f"KeepRule.max_oscillations must be an integer ≥ 0, not {self.max_oscillations!r}")

    # ------------------------------------------------------------------ pieces
    def step_fails(self, step: Step) -> str | None:
        """Why one step (flown or predicted) does not pass, None when it does."""
        overshoot, _, oscillations = step_figures(step)
        if not (isinstance(overshoot, (int, float)) and math.isfinite(overshoot)):
            return "no overshoot measured"
        if overshoot > self.max_overshoot_pct:
            return f"overshoot {overshoot:.1f} % > {self.max_overshoot_pct:g} %"
        if oscillations > self.max_oscillations:
            return f"the heading oscillates ({oscillations} reversals)"
        return None

    def agree(self, flown: Step, predicted: Step) -> str | None:
        """None when ``predicted`` matches ``flown`` within the tolerances, else how it does not."""
        flown_overshoot, flown_iae, _ = step_figures(flown)
        predicted_overshoot, predicted_iae, _ = step_figures(predicted)
        overshoot_gap = abs(flown_overshoot - predicted_overshoot)
        iae_gap = abs(flown_iae / predicted_iae - 1.0) if predicted_iae > 0 else math.inf
        if not overshoot_gap <= self.overshoot_tolerance_pct:
            return (f"overshoot {flown_overshoot:.1f} % where {predicted_overshoot:.1f} % was predicted "
                    f"(tolerance {self.overshoot_tolerance_pct:g} points)")
        if not iae_gap <= self.iae_tolerance:
            return (f"step error {flown_iae:.2f} s where {predicted_iae:.2f} s was predicted "
                    f"(tolerance {self.iae_tolerance:.0%})")
        return None

    # ------------------------------------------------------------------ the verdict
    def verdict(self, flown: Sequence[FlownStep], predicted: Iterable[PredictedAtSpeed]) -> str | None:
        """None when the designed gains may stay, else why not (one sentence).

        ``flown``: the flown steps (``label`` "scheduled" or "own", or "original" where a prediction
        failed), each with its ``predicted`` step (the model's, with the same gains); ``predicted``:
        per identified thrust, the schedule's and the original gains' predicted steps
        (:class:`PredictedAtSpeed`: ``label`` "scheduled" / "original")."""
        designed = [s for s in flown if s.label in ("scheduled", "own")]
        if not designed:
            return "no verification step was flown"
        untrusted: set[float] = set()
        for step in designed:
            where = f"thrust {step.thrust:.2f}"
            if not step.decided:
                return f"{where}: {step.why_undecided or 'the step could not decide'}"
            failure = self.step_fails(step)
            if failure:
                return f"{where}: {failure}"
            if step.predicted is not None and self.agree(step, step.predicted) is not None:
                untrusted.add(step.thrust)
        flown_original = {s.thrust: s for s in flown if s.label == "original"}
        for thrust in sorted(untrusted):
            step = next(s for s in designed if s.thrust == thrust)
            original = flown_original.get(thrust)
            if original is None:
                how = self.agree(step, step.predicted) if step.predicted is not None else None
                return (f"thrust {thrust:.2f}: the model did not predict the flown step "
                        f"({how}) and the original gains were not flown there")
            if self.better_than_original and not step.iae_s < original.iae_s:
                return (f"thrust {thrust:.2f}: not better than the original gains as flown "
                        f"(step error {step.iae_s:.2f} s vs {original.iae_s:.2f} s)")
        by_thrust: dict[float, dict[str, PredictedAtSpeed]] = {}
        for prediction in predicted:
            by_thrust.setdefault(prediction.thrust, {})[prediction.label] = prediction
        # where the schedule itself was flown, its flight (checked above) decides, not its prediction
        flown_schedule = {s.thrust for s in designed if s.label == "scheduled"}
        for thrust, steps in sorted(by_thrust.items()):
            scheduled = steps.get("scheduled")
            if scheduled is None or thrust in flown_schedule:
                continue
            failure = self.step_fails(scheduled)
            if failure:
                return f"thrust {thrust:.2f} (predicted): {failure}"
            predicted_original = steps.get("original")
            if (self.better_than_original and predicted_original is not None and thrust not in untrusted
                    and not scheduled.step.figures.iae_s < predicted_original.step.figures.iae_s):
                return (f"thrust {thrust:.2f} (predicted): not better than the original gains "
                        f"(step error {scheduled.step.figures.iae_s:.2f} s vs "
                        f"{predicted_original.step.figures.iae_s:.2f} s)")
        return None

    def originals_stand(self, flown: Sequence[FlownStep], predicted: Iterable[PredictedAtSpeed]) -> bool:
        """The verdict refuses the design only because it is not better than the original gains, and
        the original gains pass the step checks themselves (flown where they were flown, else
        predicted): the vehicle's own gains are as good as anything designed, and they stay."""
        flown, predicted = list(flown), list(predicted)
        if self.verdict(flown, predicted) is None:
            return False
        if replace(self, better_than_original=False).verdict(flown, predicted) is not None:
            return False
        flown_original = [s for s in flown if s.label == "original"]
        if any(not s.decided or self.step_fails(s) for s in flown_original):
            return False
        flown_at = {s.thrust for s in flown_original}
        return not any(self.step_fails(s) for s in predicted if s.label == "original" and s.thrust not in flown_at)

    def covers(self, own: PredictedStep, scheduled: PredictedStep) -> bool:
        """The schedule's predicted step at a speed flown with that speed's own design agrees with
        the own design's prediction (so the flight stands for the schedule there)."""
        return self.agree(own, scheduled) is None
