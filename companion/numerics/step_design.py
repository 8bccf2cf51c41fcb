"""Heading gains chosen by optimising their predicted steps (eq. D.1).

A design rule (eq. 3.57, the cascade's bandwidth rule, PX4's eq. P.1–P.6) is one point of a family:
the rule's own parameters — the pair's damping and the integral ratio of the PI; the rate bandwidth,
the angle-P ratio, the integral ratio and the feed-forward scale of a cascade (PX4's Ackermann rover
the same four, its FF scale being RO_YAW_RATE_CORR; PX4's UUV the bandwidth and the angle-P ratio) —
map a yaw model and a speed to the autopilot's gains. Which point of the family is best depends on
what the rule does not see: the rudder's limit and slew rate, the integrator clamp, the turn-rate and
turn-acceleration limits and the output's speed scaling; on a skid-steered boat the mixer that
trades steering for throttle and the speed the turn costs (eq. A.2k, ``StepCase.skid``). Those are all
in the predicted step (``companion.numerics.step_response``, eq. A.1 / A.2 / A.2k / A.4 / A.5), so the
family is searched on it:

    minimise    J(x) = mean over speeds u_i and step sizes s_j of IAE(x; u_i, s_j)      [s]
    subject to  overshoot(x; u_i, s_j) ≤ target,  reversals ≤ max_reversals,  settled in the record

where the gains at u_i are the rule's at the *schedule's* model at u_i (exactly what the schedule
writes there) and the step is flown on that speed's *own* accepted model (what the keep rule predicts,
eq. A.3). Constraints enter as a penalty (``PENALTY_S`` seconds per point of excess overshoot, per
extra reversal, per unsettled step), so the search is one bounded Nelder–Mead
(``scipy.optimize.minimize``) from the rule's default — the cost is flat in places (clamped gains)
and not differentiable at the limits, where a simplex search does better than a gradient one.

The rule's default, the vehicle's original gains and QuickTune's rule (where it exists) are scored the
same way, as candidates, each held to the *acceptable* overshoot (the keep rule's limit less the margin:
what is expected to pass the keep rule when flown) — the optimiser's tighter target is a design
preference, not a reason to replace gains that already pass. :func:`choose` takes the feasible candidate of least cost; **the original
gains are always a candidate, so no design is proposed that is predicted worse than them** — when
nothing beats them, the choice is to keep them, and nothing is written for that loop.

The overshoot target is what a flown step should show less a margin for what the model does not
predict: ``DesignObjective.target_overshoot_pct`` = min(``preferred_overshoot_pct`` (6 %),
``max_overshoot_pct`` (the keep rule's 10 %)) − ``margin_pct``. The margin is the spread of flown minus
predicted overshoot measured per autopilot (the autopilot's profile states it; ``DEFAULT_MARGIN_PCT``
otherwise).

Pure: no I/O; each evaluation is an Euler simulation (``dt`` 20 ms against yaw time constants of
0.3–1 s and rate-loop bandwidths ≤ 10 rad/s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

import numpy as np
from scipy.optimize import minimize

from companion.checks import require_non_negative, require_positive
from .cascade_gains import CascadeRules, design_cascade_gains, output_speed_scale
from .gains import GainBounds, design_heading_gains
from .identification import YawModel
from .px4_gains import design_ackermann_gains, design_uuv_gains
from .skid_step import SkidDrive
from .step_response import RudderPlant, simulate_step, step_metrics

#: the highest rate bandwidth searched on PX4's Ackermann rover, rad/s (``px4_rover_family``)
PX4_ROVER_MAX_BANDWIDTH = 6.0
#: seconds of cost per unit of violated constraint (a point of overshoot, a reversal, an unsettled step)
PENALTY_S = 10.0
#: the margin between the keep rule's overshoot limit and the design's target when the autopilot states
#: none: the largest flown-minus-predicted overshoot measured on ArduRover SITL (2.5–3 points, eq. A.3)
DEFAULT_MARGIN_PCT = 3.5

Gains = dict[str, float]


@dataclass(frozen=True)
class DesignObjective:
    """What the optimised design must meet (module docstring)."""

    step_sizes_rad: tuple[float, ...] = (math.radians(20.0), math.radians(40.0))
    max_overshoot_pct: float = 10.0  # the keep rule's limit on a flown step
    margin_pct: float = DEFAULT_MARGIN_PCT  # flown minus predicted, measured per autopilot
    preferred_overshoot_pct: float = 6.0  # what a flown step should show at most (the quick procedure's goal)
    max_reversals: int = 1
    duration_s: float = 25.0  # a verification step's longest record
    dt: float = 0.02
    #: of the cost, per optimisation: measured on six designs of three speeds (ArduRover's rudder boat
    #: and motorboat, ArduSub, PX4's rover and UUV, our PI), 60 evaluations end within 1 % of the
    #: step error 160 reach (0.533 → 0.538 s at worst), in 40 % of the time: the design's wall time is
    #: vehicle time spent holding course, ten times over on a bench at 10×
    max_evaluations: int = 60
    #: a design replaces the original gains only when its predicted step error is lower by at least
    #: this fraction: a smaller gain is not worth a parameter write and a verification flight
    min_improvement: float = 0.02

    def __post_init__(self) -> None:
        require_non_negative(self, "max_overshoot_pct", "margin_pct", "preferred_overshoot_pct", "min_improvement")
        require_positive(self, "duration_s", "dt")
        if not self.step_sizes_rad or any(not (0.0 < s <= math.pi / 2) for s in self.step_sizes_rad):
            raise ValueError(f"DesignObjective.step_sizes_rad must be in (0, π/2], not {self.step_sizes_rad!r}")
        if not (isinstance(self.max_evaluations, int) and self.max_evaluations >= 10):
            raise ValueError(f"DesignObjective.max_evaluations must be an integer ≥ 10, not {self.max_evaluations!r}")

    @property
    def target_overshoot_pct(self) -> float:
        """What the optimiser designs for: the overshoot a flown step should show (the preferred, never
        above the keep rule's limit) less the margin a flown step shows above its prediction."""
        return max(0.0, min(self.preferred_overshoot_pct, self.max_overshoot_pct) - self.margin_pct)

    @property
    def acceptable_overshoot_pct(self) -> float:
        """What any candidate may be predicted at and still be expected to pass the keep rule."""
        return max(0.0, self.max_overshoot_pct - self.margin_pct)


@dataclass(frozen=True)
class StepCase:
    """One identified speed: the model the step is flown on and the controller's limits there
    (``limits``: the keyword arguments of ``simulate_step`` for this controller, the output's speed
    scaling included); ``skid``: a skid-steered boat's mixer, thrust and speed there (eq. A.2k), None
    for every other vehicle."""

    speed: float
    model: YawModel
    plant: RudderPlant
    controller: str
    limits: Mapping[str, float] = field(default_factory=dict)
    skid: SkidDrive | None = None


@dataclass(frozen=True)
class StepScore:
    """A candidate's predicted steps over every case and size (module docstring's J and constraints)."""

    cost_s: float  # J plus penalties
    iae_s: float  # J alone: the mean normalised IAE
    worst_overshoot_pct: float
    worst_reversals: int
    unsettled: int  # steps not within 5 % by the end of the record
    violation: float  # 0 when every constraint holds

    @property
    def feasible(self) -> bool:
        return self.violation == 0.0

    def to_dict(self) -> dict[str, float]:
        return {"cost_s": self.cost_s, "iae_s": self.iae_s, "worst_overshoot_pct": self.worst_overshoot_pct,
                "worst_reversals": self.worst_reversals, "unsettled": self.unsettled, "feasible": self.feasible}


@dataclass(frozen=True)
class Candidate:
    """One scored gain set per case: ``name`` (optimised, rule, original, quicktune), the rules that
    made it (None for fixed gains) and its gains at each case's speed."""

    name: str
    gains: tuple[Gains, ...]
    score: StepScore
    rules: object | None = None


@dataclass(frozen=True)
class DesignChoice:
    """What :func:`choose` decided, with every candidate's score for the record."""

    chosen: Candidate
    candidates: tuple[Candidate, ...]
    target_overshoot_pct: float
    acceptable_overshoot_pct: float = math.inf

    @property
    def keeps_original(self) -> bool:
        return self.chosen.name == "original"

    def reason(self) -> str:
        best = self.chosen
        others = ", ".join(f"{c.name} {c.score.iae_s:.2f} s{'' if c.score.feasible else ' (infeasible)'}"
                           for c in self.candidates if c is not best)
        return (f"{best.name}: predicted step error {best.score.iae_s:.2f} s, worst overshoot "
                f"{best.score.worst_overshoot_pct:.1f} % (designed for ≤ {self.target_overshoot_pct:.1f} %, "
                f"acceptable ≤ {self.acceptable_overshoot_pct:.1f} %); {others}")

    def to_dict(self) -> dict:
        return {"chosen": self.chosen.name, "target_overshoot_pct": self.target_overshoot_pct,
                "acceptable_overshoot_pct": self.acceptable_overshoot_pct,
                "reason": self.reason(),
                "candidates": {c.name: {**c.score.to_dict(), "gains": [dict(g) for g in c.gains]}
                               for c in self.candidates}}


def score(cases: Sequence[StepCase], gains: Sequence[Gains], objective: DesignObjective,
          target: float | None = None) -> StepScore:
    """Every case's steps of every size with its gains (eq. D.1's J and constraints), the overshoot
    held to ``target`` (default: the design target)."""
    iaes: list[float] = []
    worst_overshoot, worst_reversals, unsettled, violation = 0.0, 0, 0, 0.0
    target = objective.target_overshoot_pct if target is None else target
    for case, case_gains in zip(cases, gains):
        for size in objective.step_sizes_rad:
            try:
                times, heading, _ = simulate_step(case.plant, case.controller, dict(case_gains), size,
                                                  objective.duration_s, dt=objective.dt, skid=case.skid,
                                                  speed_trace=None, rudder_trace=None, **case.limits)
            except ValueError:  # a configuration the autopilot refuses to fly (PX4: no wheel base): never settles
                times, heading = np.array([0.0, objective.duration_s]), np.zeros(2)
            figures = step_metrics(times, heading, 0.0, size, smooth=False)
            overshoot, reversals = figures.overshoot_pct, figures.oscillations
            iae = figures.iae_s if math.isfinite(figures.iae_s) else objective.duration_s
            iaes.append(iae)
            worst_overshoot = max(worst_overshoot, overshoot if math.isfinite(overshoot) else 100.0)
            worst_reversals = max(worst_reversals, reversals)
            violation += max(0.0, overshoot - target) + max(0, reversals - objective.max_reversals)
            if not math.isfinite(figures.settling_time_s):
                unsettled += 1
                violation += 1.0
    mean_iae = float(np.mean(iaes)) if iaes else math.inf
    return StepScore(cost_s=mean_iae + PENALTY_S * violation, iae_s=mean_iae, worst_overshoot_pct=worst_overshoot,
                     worst_reversals=worst_reversals, unsettled=unsettled, violation=violation)


def fixed_candidate(name: str, cases: Sequence[StepCase], gains: Gains, objective: DesignObjective) -> Candidate:
    """The same gains at every speed (the original gains, QuickTune's), judged as every candidate is
    when choosing: against the acceptable overshoot."""
    per_case = tuple(dict(gains) for _ in cases)
    return Candidate(name, per_case, score(cases, per_case, objective, objective.acceptable_overshoot_pct))


def _judged(candidate: Candidate, cases: Sequence[StepCase], objective: DesignObjective) -> Candidate:
    """A designed candidate rescored against the acceptable overshoot, as the fixed ones are."""
    return replace(candidate, score=score(cases, candidate.gains, objective, objective.acceptable_overshoot_pct))


# --------------------------------------------------------------------------- rule families
@dataclass(frozen=True)
class RuleFamily:
    """A design rule as a function of a parameter vector: ``make(x)`` the rules, ``gains(rules,
    model, speed)`` the autopilot's gains; ``x0`` the rule's default and ``bounds`` the searched box
    (in the same coordinates)."""

    make: Callable[[np.ndarray], object]
    gains: Callable[[object, YawModel, float], Gains]
    x0: np.ndarray
    bounds: tuple[tuple[float, float], ...]


def cascade_family(base: CascadeRules) -> RuleFamily:
    """The cascade's rule (eq. A.2's design, ``companion.numerics.cascade_gains``) over x = (ln ωr,
    angle-P ratio, ln N, FF scale); the full scale, ranges and output scaling stay the autopilot's."""
    def make(x: np.ndarray) -> CascadeRules:
        return replace(base, rate_bandwidth=float(math.exp(x[0])), angle_ratio=float(x[1]),
                       integral_ratio=float(math.exp(x[2])), ff_scale=float(x[3]))

    def gains(rules: object, model: YawModel, speed: float) -> Gains:
        return design_cascade_gains(model, rules, speed=speed).params()  # type: ignore[arg-type]

    x0 = np.array([math.log(base.rate_bandwidth), base.angle_ratio, math.log(base.integral_ratio), base.ff_scale])
    bounds = ((math.log(0.5), math.log(12.0)), (0.15, 1.2), (math.log(2.0), math.log(60.0)), (0.3, 1.3))
    return RuleFamily(make, gains, x0, bounds)


def pi_family(base: GainBounds) -> RuleFamily:
    """The PI's rule (eq. 3.57 generalised, ``companion.numerics.gains``) over x = (ζ, ln N)."""
    def make(x: np.ndarray) -> GainBounds:
        return replace(base, damping=float(x[0]), integral_ratio=float(math.exp(x[1])))

    def gains(rules: object, model: YawModel, speed: float) -> Gains:
        designed = design_heading_gains(model, rules, speed=speed)  # type: ignore[arg-type]
        return {"heading_p": designed.kp, "heading_i": designed.ki, "rudder_trim": designed.trim}

    x0 = np.array([base.damping, math.log(base.integral_ratio)])
    bounds = ((0.45, 1.5), (math.log(10.0), math.log(400.0)))
    return RuleFamily(make, gains, x0, bounds)


def px4_rover_family(base: CascadeRules) -> RuleFamily:
    """PX4's Ackermann rover rule (eq. P.1–P.4, ``companion.numerics.px4_gains``) over the cascade's
    x = (ln ωr, RO_YAW_P ratio ρ, ln N, κ = RO_YAW_RATE_CORR); its default point is eq. P.1–P.4."""
    def gains(rules: object, model: YawModel, speed: float) -> Gains:
        return design_ackermann_gains(model, speed, rules).params()  # type: ignore[arg-type]

    family = cascade_family(base)
    # ωr ≤ 6 rad/s: beyond it the predicted step ends in a rudder limit cycle (~0.04 rad peak to peak)
    # through RO_YAW_RATE_TH's dead band, which the IAE does not see
    bounds = ((family.bounds[0][0], math.log(PX4_ROVER_MAX_BANDWIDTH)),) + family.bounds[1:]
    return replace(family, gains=gains, bounds=bounds)


def px4_uuv_family(base: CascadeRules) -> RuleFamily:
    """PX4's UUV rule (eq. P.5–P.6) over x = (ln ωr, ρ): UUV_YAW_D = (ωr + a22)/b, UUV_YAW_P =
    ρ·ωr_a²/b (the loop has no integrator and no feed-forward); its default point is eq. P.5–P.6."""
    def make(x: np.ndarray) -> CascadeRules:
        return replace(base, rate_bandwidth=float(math.exp(x[0])), angle_ratio=float(x[1]))

    def gains(rules: object, model: YawModel, speed: float) -> Gains:
        return design_uuv_gains(model, rules, speed=speed).params()  # type: ignore[arg-type]

    x0 = np.array([math.log(base.rate_bandwidth), base.angle_ratio])
    bounds = ((math.log(0.3), math.log(12.0)), (0.15, 1.2))
    return RuleFamily(make, gains, x0, bounds)


def _rule_candidate(name: str, family: RuleFamily, x: np.ndarray, cases: Sequence[StepCase],
                    design_models: Sequence[YawModel], objective: DesignObjective) -> Candidate | None:
    try:
        rules = family.make(np.asarray(x, dtype=float))
        per_case = tuple(family.gains(rules, model, case.speed) for case, model in zip(cases, design_models))
    except ValueError:
        return None
    return Candidate(name, per_case, score(cases, per_case, objective), rules)


def optimise(family: RuleFamily, cases: Sequence[StepCase], design_models: Sequence[YawModel],
             objective: DesignObjective) -> Candidate | None:
    """The family's point of least cost (eq. D.1), from its default (bounded Nelder–Mead); None when
    no point of the family gives gains for every case."""
    def cost(x: np.ndarray) -> float:
        candidate = _rule_candidate("optimised", family, x, cases, design_models, objective)
        return candidate.score.cost_s if candidate is not None else 1e6

    low, high = np.array([b[0] for b in family.bounds]), np.array([b[1] for b in family.bounds])
    x0 = np.clip(family.x0, low, high)
    result = minimize(cost, x0, method="Nelder-Mead", bounds=family.bounds,
                      options={"maxfev": objective.max_evaluations, "xatol": 1e-2, "fatol": 1e-2,
                               "initial_simplex": _simplex(x0, low, high)})
    return _rule_candidate("optimised", family, np.clip(result.x, low, high), cases, design_models, objective)


def _simplex(x0: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """A starting simplex a fifth of the box wide in each coordinate, inside the box."""
    points = [x0]
    for i in range(len(x0)):
        point = x0.copy()
        width = 0.2 * (high[i] - low[i])
        point[i] = x0[i] + width if x0[i] + width <= high[i] else x0[i] - width
        points.append(point)
    return np.array(points)


def choose(candidates: Sequence[Candidate], objective: DesignObjective) -> DesignChoice:
    """The feasible candidate of least cost; with none feasible, the least violating (a refusal
    downstream names it). The original gains stay unless the best is ``min_improvement`` better (nothing
to write, nothing to fly); other ties go in the given order."""
    if not candidates:
        raise ValueError("no candidate design to choose from")
    def key(c: Candidate) -> tuple[float, float, int]:
        return (c.score.violation, c.score.cost_s if c.score.feasible else math.inf, 0 if c.name == "original" else 1)
    ranked = sorted(candidates, key=key)
    best = ranked[0]
    original = next((c for c in candidates if c.name == "original"), None)
    if original is not None and original.score.feasible and best is not original \
            and not best.score.iae_s < (1.0 - objective.min_improvement) * original.score.iae_s:
        best = original
    return DesignChoice(best, tuple(candidates), objective.target_overshoot_pct, objective.acceptable_overshoot_pct)


def design_by_prediction(family: RuleFamily, cases: Sequence[StepCase], design_models: Sequence[YawModel],
                         objective: DesignObjective, *, original: Gains | None = None,
                         others: Mapping[str, Gains] | None = None) -> DesignChoice:
    """eq. D.1 end to end: the rule's default, its optimum (designed for the target overshoot), the
    original gains and any ``others`` (e.g. QuickTune's) scored on the same predicted steps against
    the acceptable overshoot (the keep rule's limit less the margin), and the choice among them.

    ``cases``: one per identified speed (its own model and the controller's limits there);
    ``design_models``: the models the rule designs from at the same speeds (the schedule's)."""
    if len(cases) != len(design_models) or not cases:
        raise ValueError("one design model per case, and at least one case")
    candidates: list[Candidate] = []
    default = _rule_candidate("rule", family, family.x0, cases, design_models, objective)
    if default is not None:
        candidates.append(_judged(default, cases, objective))
    best = optimise(family, cases, design_models, objective)
    if best is not None:
        candidates.append(_judged(best, cases, objective))
    if original:
        candidates.append(fixed_candidate("original", cases, original, objective))
    for name, gains in (others or {}).items():
        if gains:
            candidates.append(fixed_candidate(name, cases, gains, objective))
    return choose(candidates, objective)


def cascade_case(model: YawModel, speed: float, *, rudder_max: float, rudder_rate: float, full_scale: float,
                 rate_max: float, rate_accel_max: float, output_scale_base: float | None,
                 rate_imax: float = 1.0, input_tc: float = 0.0, yaw_slew_max: float = math.inf) -> StepCase:
    """A case under ArduPilot's cascade (eq. A.2) at ``speed``; with ``input_tc`` > 0 ArduSub's
    shaped angle loop (eq. A.2s)."""
    plant = RudderPlant(model.a22, model.b2, model.delta0, rudder_max, rudder_rate)
    limits = {"full_scale": full_scale, "rate_max": rate_max, "rate_accel_max": rate_accel_max,
              "output_scale": output_speed_scale(output_scale_base, speed), "rate_imax": rate_imax,
              "input_tc": input_tc, "yaw_slew_max": yaw_slew_max}
    return StepCase(speed, model, plant, "cascade", limits)


def px4_rover_case(model: YawModel, speed: float, *, steering_max: float, rudder_rate: float = math.inf,
                   steering_rate: float = math.inf, rate_max: float = math.inf, rate_accel_max: float = math.inf,
                   rate_threshold: float = 0.0, speed_estimate: float | None = None) -> StepCase:
    """A case under PX4's Ackermann rover (eq. A.4) at ``speed``: ``steering_max`` RA_MAX_STR_ANG (the
    rudder's limit and PX4's steering full scale), ``rudder_rate`` the servo's own rate, the rest PX4's
    limits in rad/s (RA_STR_RATE_LIM, RO_YAW_RATE_LIM, RO_YAW_RATE_TH) and rad/s² (RO_YAW_ACCEL_LIM;
    inf where not configured); ``speed_estimate`` PX4's û (default ``speed``: RO_MAX_THR_SPEED
    calibrated)."""
    plant = RudderPlant(model.a22, model.b2, model.delta0, steering_max, rudder_rate)
    limits = {"full_scale": steering_max, "speed": speed if speed_estimate is None else speed_estimate,
              "rate_max": rate_max, "rate_accel_max": rate_accel_max, "steering_rate": steering_rate,
              "rate_threshold": rate_threshold}
    return StepCase(speed, model, plant, "px4_rover", limits)


def px4_uuv_case(model: YawModel, speed: float, *, full_scale: float, torque_max: float = 1.0,
                 rudder_rate: float = math.inf, forward_thrust: float = math.nan) -> StepCase:
    """A case under PX4's UUV yaw control (eq. A.5) at ``speed``: ``full_scale`` the equivalent rudder
    of full yaw torque, ``torque_max`` UUV_TORQUE_SAT; ``forward_thrust`` the surge thrust there, whose
    allocation leaves the yaw less room (eq. A.5a; NaN: unknown, not modelled)."""
    plant = RudderPlant(model.a22, model.b2, model.delta0, full_scale, rudder_rate)
    return StepCase(speed, model, plant, "px4_uuv", {"full_scale": full_scale, "torque_max": torque_max,
                                                      "forward_thrust": forward_thrust})


def pi_case(model: YawModel, speed: float, *, rudder_max: float, rudder_rate: float, imax: float) -> StepCase:
    """A case under our simulator's PI (eq. A.1) at ``speed``."""
    plant = RudderPlant(model.a22, model.b2, model.delta0, rudder_max, rudder_rate)
    return StepCase(speed, model, plant, "pi", {"imax": imax})
