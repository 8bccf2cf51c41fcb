"""ArduRover's speed loop, designed from the identified surge model (eq. S.5).

ArduRover (``AR_AttitudeControl::get_throttle_out_speed``, read in ArduPilot's sources) turns a
desired speed into a throttle in [−1, 1]:

    u_d* ← u_d limited to change by ATC_ACCEL_MAX·dt per loop         (acceleration limit)
    e    ← e + α·((u_d* − u) − e)                                       (error filter, ATC_SPEED_FILT 10 Hz)
    I    ← I + ATC_SPEED_I·e·dt,  |I| ≤ ATC_SPEED_IMAX, frozen while the output is limited
    t    = u_d*·CRUISE_THROTTLE/CRUISE_SPEED + ATC_SPEED_P·e + I (+ D)   (eq. S.5)

and, with braking off, no negative throttle while both speeds are positive. The feed-forward
CRUISE_THROTTLE/CRUISE_SPEED is a straight line through the origin: exact at CRUISE_SPEED when
CRUISE_THROTTLE is the throttle that holds it, and everywhere when U_ss ∝ t (eq. S.4 with p = 1).

Design, on the identified surge model (eq. S.4) with its throttle lag, at the cruise speed U0:

* **CRUISE_THROTTLE** = t_ss(U0), the throttle that holds the vehicle's own CRUISE_SPEED by the
  steady law, to the whole percent ArduRover stores (an ``AP_Int8``), and **CRUISE_SPEED** the speed
  that whole-percent throttle holds (the vehicle's, moved by at most the speed of half a percent of
  throttle; the speeds a campaign flew bound how far from them it may lie, see
  :func:`design_speed_gains`): the feed-forward line then passes exactly through the steady law
  there, and, with p ≈ 1, carries most of every speed change (a fractional percent would be
  rounded by the autopilot, and the line would miss the law by up to half a percent of throttle);
* **ATC_SPEED_P and ATC_SPEED_I** are what is left: the pair, on a grid (P 0.01–2 and I from
  I_min to 2, both log-spaced), whose simulated 0.5 m/s step there and back through the loop above
  settles soonest (summed times to stay within 5 %) with at most ``max_overshoot_pct`` (5 %) in
  either direction; of the pairs within ``settle_tie_s`` of the soonest, the one with the strongest
  integrator (the settling time is nearly flat in I, and the weakest tied one was flown and held a
  transient's error for 30 s: ArduRover SITL, 2 of 10 campaigns). I_min = t_ss(U0)/(20·U0) is the slowest integral action kept: it removes a
  feed-forward error of 5 % of the cruise throttle within about 20 s at a 5 % speed error. A weaker
  one was flown and lost: the model's own error, about 1 % of speed at the step's far end, is 4 %
  of a 0.5 m/s step at 2 m/s, and with I = 0.005–0.01 the speed did not come back within 5 % of the
  step in 15 s (P 0.17–0.24, skid boat, six steps); a margin on the lag (the model checked with its
  lag doubled) chose those weak integrators and was dropped.

Why a search and not pole placement: the lag is what limits the loop, and an integrator fast enough
to place the error's poles winds up during the acceleration ramp. Measured on the skid boat's model
(τ = 1.1 s at 1.5 m/s, lag 0.40 s): critically damped poles at twice the boat's speed (P 1.1,
I 0.67) predicted 5 % and flew 10–15 % of overshoot; the defaults (P 0.1, I 0.2) wind up: 28 %
predicted, 26 % flown. The flown steps overshoot 1–2 % more than predicted (the speed estimate's
lag sits in the feedback path, which one lag on the throttle does not model).

**Scored against the speed estimate's drift (eq. S.5r).** In flight the feed-forward misses: the
speed the autopilot regulates is its own estimate, which drifts against the water speed, and the
steady law has its own error. Each pair's settling time is the worst of its steps simulated with
the vehicle needing ε less, as much and ε more throttle than the law says, the integrator starting
without knowing it, where ε = ``SpeedRules.speed_drift`` (0.05 m/s) over the law's slope dU/dt. A
pair that cannot remove that error within the record never settles. Measured on ArduRover SITL's
skid boat: the floor integrator's design (P 0.24–0.34, I 0.02), predicted to settle in 3.6 s, flew
both steps 0.027–0.030 m/s off their demand for the whole 15 s hold, and the original gains were
flown and kept every time (100 s of steps).

The same simulation predicts the vehicle's original gains, so the design and the defaults are
compared before either is flown: when no pair is predicted to settle at least ``min_gain_s``
sooner than the original gains under that worst case, the design keeps the original gains
(``SpeedDesign.keeps_original``) and nothing is written or flown. Pure numerics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.checks import require_interval, require_non_negative, require_positive
from .surge import SurgeModel

#: ArduRover's speed-loop constants (AR_AttitudeControl.cpp): error filter, integrator limit, loop rate
ERROR_FILTER_HZ = 10.0
INTEGRATOR_MAX = 1.0
LOOP_S = 0.02
#: within this fraction of the step the speed counts as settled
SETTLE_BAND = 0.05


@dataclass(frozen=True)
class SpeedRules:
    """The design targets and ArduPilot's documented ranges (module docstring)."""

    step: float = 0.5  # m/s, the verification step
    max_overshoot_pct: float = 5.0  # predicted (module docstring); the flown check allows 10 %
    settle_tie_s: float = 0.1  # summed settling times this close to the fastest count as a tie
    p_range: tuple[float, float] = (0.01, 2.0)
    i_range: tuple[float, float] = (0.0, 2.0)
    #: how far (m/s) the speed the feed-forward holds may miss its demand in flight (eq. S.5r): the
    #: throttle it misses by is this over the steady law's slope dU/dt there. Measured on ArduRover
    #: SITL's skid boat: the speed estimate drifted 0.03 m/s against the water speed within three
    #: minutes, the same measured speed took 59.7 % of throttle in the speed steps where the settles
    #: had taken 60.9 %, and the design's flown steps ended 0.027–0.030 m/s off their demand under
    #: ATC_SPEED_P 0.24–0.34 (2 % of throttle, at dU/dt 2.5 m/s: 0.05 m/s)
    speed_drift: float = 0.05
    #: a design replaces the vehicle's own speed gains only when its worst summed settling time
    #: (eq. S.5r) is shorter than theirs by at least this much (s): else nothing is written or flown
    min_gain_s: float = 1.0

    def __post_init__(self) -> None:
        require_positive(self, "step", "max_overshoot_pct")
        require_non_negative(self, "speed_drift", "min_gain_s")
        require_interval(self, "p_range")
        require_interval(self, "i_range")


@dataclass
class SpeedLoopGains:
    """ArduRover's speed-loop parameters, in the product's units (throttle as a fraction)."""

    cruise_speed: float  # m/s
    cruise_throttle: float  # 0..1 (CRUISE_THROTTLE is percent)
    p: float
    i: float

    def params(self) -> dict[str, float]:
        """Neutral names (``companion.link.autopilots.ardurover``)."""
        return {"cruise_speed": self.cruise_speed, "cruise_thrust": self.cruise_throttle, "speed_p": self.p,
                "speed_i": self.i}

    @classmethod
    def from_params(cls, params: dict) -> "SpeedLoopGains":
        return cls(float(params["cruise_speed"]), float(params["cruise_thrust"]), float(params["speed_p"]),
                   float(params["speed_i"]))


@dataclass
class SpeedDesign:
    """A speed-loop design: the gains, what they rest on, and the predicted steps (original and design)."""

    surge: SurgeModel
    gains: SpeedLoopGains
    design_speed: float
    time_constant_s: float  # open loop, at the design speed
    throttle_gain: float  # K = dU/dt at the design speed
    step: tuple[float, float]  # the verification step's speeds (from, to)
    # "design"/"original" (the step), "design_back"/"original_back" (the step back) → step metrics
    predicted: dict = field(default_factory=dict)
    clamped: tuple[str, ...] = ()
    #: "design"/"original" → the summed settling time of the step there and back, the worst over the
    #: feed-forward errors of eq. S.5r (inf: one never settles within the record)
    worst_settling_s: dict = field(default_factory=dict)
    #: no design is predicted better than the vehicle's own gains (eq. S.5r): those stay, unflown
    keeps_original: bool = False
    #: the feed-forward error (throttle) the worst case was taken over (eq. S.5r, ``SpeedRules.speed_drift``)
    feed_forward_error: float = 0.0

    def reason(self) -> str:
        """Why the design stands, or why the vehicle's own gains do (eq. S.5r), in words."""
        design, original = self.worst_settling_s.get("design"), self.worst_settling_s.get("original")
        def said(value: float | None) -> str:
            return "never" if value is None or not math.isfinite(value) else f"{value:.1f} s"
        if self.keeps_original:
            return (f"no speed design is predicted better than the vehicle's own gains: settled in {said(design)} "
                    f"against {said(original)} with the feed-forward off by up to "
                    f"{100 * self.feed_forward_error:.0f} % of throttle")
        return f"predicted to settle in {said(design)} against the vehicle's own gains' {said(original)}"


def step_metrics(times: np.ndarray, speed: np.ndarray, start: float, target: float) -> dict:
    """Overshoot (% of the step) and time to settle within 5 % of it, to the end of the record."""
    size = target - start
    progress = (np.asarray(speed) - start) / size
    overshoot = max(0.0, float(np.max(progress)) - 1.0) * 100.0
    outside = np.nonzero(np.abs(progress - 1.0) > SETTLE_BAND)[0]
    if len(outside) == 0:
        settle = 0.0
    elif outside[-1] == len(times) - 1:
        settle = math.nan
    else:
        settle = float(times[outside[-1] + 1] - times[0])
    return {"overshoot_pct": overshoot, "settling_time_s": settle}


def simulate_speed_step(model: SurgeModel, gains: SpeedLoopGains, start: float, target: float,
                        accel_max: float = 1.0, duration_s: float = 15.0) -> tuple[np.ndarray, np.ndarray]:
    """(times, speed) of eq. S.5 on the surge model, from steady at ``start`` to a demand of ``target``."""
    times, speed = simulate_speed_steps(model, gains.cruise_speed, gains.cruise_throttle, np.array([gains.p]),
                                        np.array([gains.i]), start, target, accel_max, duration_s)
    return times, speed[:, 0]


def simulate_speed_steps(model: SurgeModel, cruise_speed: float, cruise_throttle: float, p: np.ndarray,
                         i: np.ndarray, start: float, target: float, accel_max: float = 1.0,
                         duration_s: float = 15.0, feed_forward_error: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`simulate_speed_step` for many (P, I) pairs at once (arrays of one shape, flattened):
    times and speed[k, pair]. With ``feed_forward_error`` ε the vehicle needs ε more throttle than
    the surge model says at every speed, and the integrator starts without knowing it (eq. S.5r)."""
    p, i = np.ravel(p).astype(float), np.ravel(i).astype(float)
    n = int(round(duration_s / LOOP_S)) + 1
    times = np.arange(n) * LOOP_S
    speed = np.empty((n, p.size))
    slope = cruise_throttle / cruise_speed if cruise_speed > 0.0 and cruise_throttle > 0.0 else 0.0
    u = np.full(p.size, float(start))
    demand = float(start)
    error = np.zeros(p.size)
    # steady at ``start``: the integrator holds what the feed-forward misses there
    integrator = np.full(p.size, min(max(model.throttle_for(start) - start * slope, -INTEGRATOR_MAX), INTEGRATOR_MAX))
    alpha = LOOP_S / (LOOP_S + 1.0 / (2.0 * math.pi * ERROR_FILTER_HZ))
    thrust = np.full(p.size, model.throttle_for(start))
    follow = 1.0 if model.lag <= 0.0 else 1.0 - math.exp(-LOOP_S / model.lag)
    limit = accel_max * LOOP_S if accel_max > 0.0 else math.inf
    for k in range(n):
        speed[k] = u
        demand += max(-limit, min(limit, target - demand))
        error += alpha * ((demand - u) - error)
        unlimited = demand * slope + p * error + integrator
        throttle = np.clip(unlimited, 0.0, 1.0)
        free = throttle == unlimited  # ArduPilot freezes the integrator while the output is limited
        integrator = np.where(free, np.clip(integrator + i * error * LOOP_S, -INTEGRATOR_MAX, INTEGRATOR_MAX),
                              integrator)
        thrust += (throttle - thrust) * follow  # the thrust behind its lag, then Heun (SurgeModel.simulate)
        effective = thrust - feed_forward_error
        first = _acceleration(model, u, effective)
        u = u + 0.5 * LOOP_S * (first + _acceleration(model, u + LOOP_S * first, effective))
    return times, speed


def _acceleration(model: SurgeModel, u: np.ndarray, thrust: np.ndarray) -> np.ndarray:
    steady = model.gain * np.maximum(thrust, 0.0) ** model.exponent
    return model.gamma * (steady * steady - u * np.abs(u))


def predict_step(model: SurgeModel, gains: SpeedLoopGains, start: float, target: float, accel_max: float) -> dict:
    times, speed = simulate_speed_step(model, gains, start, target, accel_max)
    return step_metrics(times, speed, start, target)


def design_speed_gains(model: SurgeModel, cruise_speed: float, speed_range: tuple[float, float],
                       rules: SpeedRules = SpeedRules(), accel_max: float = 1.0,
                       original: SpeedLoopGains | None = None, speed_max: float = math.inf) -> SpeedDesign:
    """The rule of the module docstring. ``cruise_speed`` is the vehicle's CRUISE_SPEED, kept when it
    lies within ``speed_range`` (the campaign's steady speeds) widened by 20 %, else replaced by the
    middle of that range (the steady law is not extrapolated further); ValueError for a model
    that cannot be designed on (γ or the steady law not positive). ``speed_max``: the most speed the
    autopilot can be asked for (ArduRover: WP_SPEED at thrust level 1); the speed steps stay below it
    (measured on SITL's motorboat with CRUISE_SPEED = WP_SPEED = 5: the design's cruise speed came out
    at 5.01 m/s, a step that could not be asked for)."""
    if not (model.gamma > 0.0 and model.gain > 0.0 and model.exponent > 0.0):
        raise ValueError(f"the surge model cannot be designed on ({model.describe()})")
    low, high = speed_range
    clamped: list[str] = []
    speed = cruise_speed
    if not (math.isfinite(speed) and 0.8 * low <= speed <= 1.2 * high):
        speed = 0.5 * (low + high)
        clamped.append("cruise_speed")
    throttle = round(100.0 * model.throttle_for(speed)) / 100.0  # CRUISE_THROTTLE is a whole percent
    if not 0.0 < throttle <= 1.0:
        raise ValueError(f"the surge model needs throttle {model.throttle_for(speed):.3f} for {speed:.2f} m/s, "
                         "outside 0.005..1")
    speed = model.steady_speed(throttle)  # the speed that percent holds: the feed-forward exact there
    tau = model.time_constant(speed)
    gain = model.throttle_gain(speed)
    start = min(speed, speed_max)
    up = start + rules.step
    step = (start, up) if up <= min(1.1 * high, speed_max) else (start, start - rules.step)
    i_min = max(rules.i_range[0], throttle / (20.0 * speed))
    mesh_p, mesh_i = np.meshgrid(np.geomspace(rules.p_range[0], rules.p_range[1], 16),
                                 np.geomspace(max(i_min, 1e-4), rules.i_range[1], 10))
    grid_p, grid_i = mesh_p.ravel(), mesh_i.ravel()
    scores = []
    for begin, end in (step, (step[1], step[0])):
        times, speeds = simulate_speed_steps(model, speed, throttle, grid_p, grid_i, begin, end, accel_max)
        scores.append([step_metrics(times, speeds[:, j], begin, end) for j in range(grid_p.size)])
    error = rules.speed_drift / gain if gain > 0.0 else 0.0  # eq. S.5r: the throttle the drift is worth
    worst = _worst_settling(model, speed, throttle, grid_p, grid_i, step, accel_max, error)
    feasible = [(worst[j], j) for j, (there, back) in enumerate(zip(*scores))
                if max(there["overshoot_pct"], back["overshoot_pct"]) <= rules.max_overshoot_pct]
    if not feasible:
        raise ValueError(f"no speed-loop gains keep a {rules.step:g} m/s step within {rules.max_overshoot_pct:g} % "
                         f"of overshoot on the surge model ({model.describe()})")
    fastest = min(score for score, _ in feasible)
    # among the pairs that settle as soon (within the tie), the strongest integrator: the settling
    # time is nearly flat in I, and a weak one chosen by a hundredth of a second could not unwind what a
    # transient left in it (flown: I 0.02 held the speed 0.26 m/s short for 30 s; I 0.26 did not)
    if math.isfinite(fastest):
        score, j = max(((score, j) for score, j in feasible if score <= fastest + rules.settle_tie_s),
                       key=lambda item: (grid_i[item[1]], -item[0]))
    else:  # none settles under every error: the soonest on the model's own (its worst stays inf)
        _, j = min(((_settled(scores[0][j]) + _settled(scores[1][j]), j) for _, j in feasible),
                   key=lambda item: (item[0], -grid_i[item[1]]))
        score = math.inf
    gains = SpeedLoopGains(cruise_speed=speed, cruise_throttle=throttle, p=float(grid_p[j]), i=float(grid_i[j]))
    design = SpeedDesign(surge=model, gains=gains, design_speed=speed, time_constant_s=tau, throttle_gain=gain,
                         step=step, predicted={"design": scores[0][j], "design_back": scores[1][j]},
                         clamped=tuple(clamped), worst_settling_s={"design": float(score)},
                         feed_forward_error=error)
    if original is not None:
        design.predicted["original"] = predict_step(model, original, *step, accel_max)
        design.predicted["original_back"] = predict_step(model, original, step[1], step[0], accel_max)
        theirs = float(_worst_settling(model, original.cruise_speed, original.cruise_throttle,
                                       np.array([original.p]), np.array([original.i]), step, accel_max,
                                       error, original.cruise_speed > 0.0)[0])
        design.worst_settling_s["original"] = theirs
        # eq. S.5r: the vehicle's own gains stay unless the design is predicted to settle sooner by
        # min_gain_s under every feed-forward error (both never settling: nothing to gain either)
        design.keeps_original = not (score < theirs - rules.min_gain_s or (math.isinf(theirs) and math.isfinite(score)))
    return design


def _worst_settling(model: SurgeModel, cruise_speed: float, cruise_throttle: float, p: np.ndarray, i: np.ndarray,
                    step: tuple[float, float], accel_max: float, error: float, valid: bool = True) -> np.ndarray:
    """Per (P, I) pair, the summed settling time of the step there and back, the worst over the
    feed-forward missing by −ε, 0 and +ε of throttle (eq. S.5r; inf: one never settles)."""
    worst = np.zeros(p.size)
    if not valid:
        return np.full(p.size, math.inf)
    for offset in ((0.0, error, -error) if error > 0.0 else (0.0,)):
        total = np.zeros(p.size)
        for begin, end in (step, (step[1], step[0])):
            times, speeds = simulate_speed_steps(model, cruise_speed, cruise_throttle, p, i, begin, end, accel_max,
                                                 feed_forward_error=offset)
            total += [_settled(step_metrics(times, speeds[:, j], begin, end)) for j in range(p.size)]
        worst = np.maximum(worst, total)
    return worst


def _settled(metrics: dict) -> float:
    value = metrics["settling_time_s"]
    return value if math.isfinite(value) else math.inf


def _clamp(name: str, value: float, limits: tuple[float, float], clamped: list[str]) -> float:
    low, high = limits
    if value < low or value > high:
        clamped.append(name)
    return min(max(value, low), high)


def simulate_speed_tracking(model: SurgeModel, gains: SpeedLoopGains, times: np.ndarray, desired: np.ndarray,
                            speed0: float, throttle0: float) -> np.ndarray:
    """The speed ArduRover's loop (eq. S.5) with ``gains`` achieves on the surge model (eq. S.4) when
    asked for the speeds ``desired`` at ``times`` (a flown record's PID_TUNING target: the demand
    after ArduRover's acceleration limit, so none is applied again), at the record's sample times:
    the replay of eq. L.4. It starts where the record did: at ``speed0``, with the thrust at the
    throttle the record began with (``throttle0``) and the integrator holding what the feed-forward
    and P did not give of it (the loop continues from its own output, as the turn-rate replay of
    eq. A.2r continues from the rudder). The demand is interpolated linearly between samples and
    the loop runs at ArduRover's 50 Hz."""
    times = np.asarray(times, dtype=float)
    desired = np.asarray(desired, dtype=float)
    if times.size == 0:
        return np.empty(0)
    slope = gains.cruise_throttle / gains.cruise_speed if gains.cruise_speed > 0.0 and gains.cruise_throttle > 0.0 else 0.0
    n = int(math.ceil((times[-1] - times[0]) / LOOP_S)) + 1
    grid = times[0] + np.arange(n) * LOOP_S
    demand = np.interp(grid, times, desired)
    alpha = LOOP_S / (LOOP_S + 1.0 / (2.0 * math.pi * ERROR_FILTER_HZ))
    u = float(speed0)
    error = float(demand[0]) - u
    throttle = throttle0 if math.isfinite(throttle0) else model.throttle_for(max(u, 0.0))
    integrator = min(max(throttle - demand[0] * slope - gains.p * error, -INTEGRATOR_MAX), INTEGRATOR_MAX)
    thrust = throttle
    follow = 1.0 if model.lag <= 0.0 else 1.0 - math.exp(-LOOP_S / model.lag)
    speed = np.empty(n)
    for k in range(n):
        speed[k] = u
        error += alpha * ((demand[k] - u) - error)
        unlimited = demand[k] * slope + gains.p * error + integrator
        out = min(max(unlimited, 0.0), 1.0)
        if out == unlimited:  # ArduPilot freezes the integrator while the output is limited
            integrator = min(max(integrator + gains.i * error * LOOP_S, -INTEGRATOR_MAX), INTEGRATOR_MAX)
        thrust += (out - thrust) * follow
        steady = model.gain * max(thrust, 0.0) ** model.exponent
        first = model.gamma * (steady * steady - u * abs(u))
        u1 = u + LOOP_S * first
        u = u + 0.5 * LOOP_S * (first + model.gamma * (steady * steady - u1 * abs(u1)))
    return np.interp(times, grid, speed)
