"""Heading steps: their figures of merit, and their prediction from an identified yaw model.

:func:`step_metrics` scores a flown (or predicted) step: overshoot, rise time, settling time, the
integrated absolute error normalised by the step (IAE, seconds) and the reversals of the error, a
``companion.numerics.step_figures.StepFigures`` (a prediction: a ``PredictedStep``).
:func:`predict_step` flies the step on the identified model instead of the vehicle (eq. 3.6 with the
rudder's limit and slew rate), under the autopilot's own heading controller:

* the heading PI of our simulator (eq. A.1): δ = trim + Kp·e + I, İ = Ki·e with
  |I| ≤ imax and conditional integration while the rudder is saturated;
* ArduPilot's cascade (eq. A.2): desired turn rate r_d = ANG_P·e (limited in size, in slew and by
  the distance left to stop), steering s = FF·r_d + P·(r_d − r) + I∫(r_d − r) (|I| ≤ IMAX),
  δ = δfs·sat(k·s) with k the output's speed scaling (``companion.numerics.cascade_gains.output_speed_scale``);
* PX4's Ackermann rover (eq. A.4) and UUV (eq. A.5) controllers, transcribed from PX4's source in
  ``companion.numerics.px4_step`` (controller names ``"px4_rover"``, ``"px4_uuv"``).

Before the step the vehicle is on course with the rudder at its trim δ0, the integrator holding what
the trim feed-forward does not. Pure: Euler integration at ``dt`` (10 ms against yaw time constants
of ~1 s), no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import trapezoid
from scipy.signal import savgol_filter

from .attitude_shaping import ShapedYawTarget
from .px4_step import PX4_CONTROLLERS, fly, px4_controller
from .rate_loop import ARDUROVER_RATE_LOOP, RateLoopForm
from .skid_step import SkidDrive, SkidState
from .step_figures import PredictedStep, StepFigures

#: a reversal of the error counts only beyond this fraction of the step (noise stays inside)
OSCILLATION_BAND = 0.03
#: settled: the error stays within this fraction of the step to the end of the record
SETTLE_BAND = 0.05


def smooth_heading(times: np.ndarray, heading: np.ndarray, window_s: float = 1.0) -> np.ndarray:
    """Savitzky–Golay smoothing (quadratic, ``window_s`` long) of a measured heading.

    The maximum of a noisy signal is biased upwards by a few noise σ (σ 0.3° of compass noise reads
    as 3–5 % of extra overshoot on a 20° step); a quadratic local fit over 1 s removes the noise
    and keeps the response peak, which is several seconds wide."""
    if len(times) < 7:
        return heading
    dt = float(np.median(np.diff(times)))
    window = int(round(window_s / dt)) | 1  # odd
    window = min(window, len(heading) - (1 - len(heading) % 2))
    return savgol_filter(heading, window, 2) if window >= 5 else heading


def step_metrics(times: ArrayLike, heading: ArrayLike, start: float, target: float,
                 smooth: bool = True) -> StepFigures:
    """One heading step (headings unwrapped; smoothed by :func:`smooth_heading` unless ``smooth`` is
    False, for a noise-free prediction): overshoot (% of the step), 90 % rise time, settling time
    (within 5 % to the end, NaN if never), the integrated absolute error normalised by the step
    (``iae_s``, seconds: one figure of merit to compare gain sets) and the number of reversals of the
    error beyond ±3 % of the step after the target was first crossed (``oscillations``; a well-damped
    step has at most one), as a :class:`~companion.numerics.step_figures.StepFigures`."""
    t = np.asarray(times, dtype=float)
    psi = np.asarray(heading, dtype=float)
    psi = smooth_heading(t, psi) if smooth else psi
    size = target - start
    if len(t) < 2 or abs(size) < 1e-9:
        return StepFigures.unmeasured()
    progress = (psi - start) / size  # 0 at the start, 1 on target
    overshoot = max(0.0, float(np.max(progress)) - 1.0) * 100.0
    reached = np.nonzero(progress >= 0.9)[0]
    rise = float(t[reached[0]] - t[0]) if len(reached) else math.nan
    error = progress - 1.0
    outside = np.nonzero(np.abs(error) > SETTLE_BAND)[0]
    if len(outside) == 0:
        settling = 0.0
    elif outside[-1] == len(t) - 1:
        settling = math.nan
    else:
        settling = float(t[outside[-1] + 1] - t[0])
    iae = float(trapezoid(np.abs(error), t))
    crossed = np.nonzero(error >= 0.0)[0]
    reversals, sign = 0, 0
    for value in (error[crossed[0]:] if len(crossed) else []):
        if abs(value) <= OSCILLATION_BAND:
            continue
        current = 1 if value > 0 else -1
        if sign and current != sign:
            reversals += 1
        sign = current
    return StepFigures(overshoot_pct=overshoot, rise_time_s=rise, settling_time_s=settling, iae_s=iae,
                       oscillations=reversals)


@dataclass(frozen=True)
class RudderPlant:
    """The identified yaw model with the rudder that drives it: ṙ = a22·r + b2·(δ − δ0) (eq. 3.6),
    |δ| ≤ ``rudder_max`` moved at most at ``rudder_rate`` (rad/s; inf: at once)."""

    a22: float
    b2: float
    delta0: float
    rudder_max: float
    rudder_rate: float = math.inf


def _slew(current: float, demand: float, limit: float, max_step: float) -> float:
    target = min(max(demand, -limit), limit)
    return current + min(max(target - current, -max_step), max_step)


def simulate_step(plant: RudderPlant, controller: str, gains: dict[str, float], step: float, duration_s: float,
                  *, full_scale: float = 0.5236, rate_max: float = math.inf, imax: float = 0.15,
                  rate_accel_max: float = math.inf, output_scale: float = 1.0, rate_imax: float = 1.0,
                  speed: float = math.nan, steering_rate: float = math.inf, rate_threshold: float = 0.0,
                  torque_max: float = 1.0, forward_thrust: float = math.nan, input_tc: float = 0.0,
                  yaw_slew_max: float = math.inf,
                  skid: SkidDrive | None = None, speed_trace: list[float] | None = None,
                  rudder_trace: list[float] | None = None, dt: float = 0.01) -> tuple[np.ndarray, np.ndarray, float]:
    """Heading over time after a step of ``step`` rad from 0 (module docstring); also the largest
    rudder deflection reached. ``controller``: ``"pi"`` (gains ``heading_p``, ``heading_i``,
    ``rudder_trim``) or ``"cascade"`` (``heading_angle_p``, ``heading_rate_p``, ``heading_rate_i``,
    ``heading_rate_ff``; ``heading_rate_imax`` as a fraction of the output, else ``rate_imax``: the
    vehicle's), with the
    desired turn rate limited to ``rate_max`` (rad/s), its change to ``rate_accel_max`` (rad/s²,
    which also caps it at √(2·|e|·accel) so the turn can stop on target, as ArduPilot's
    ``get_turn_rate_from_heading``), and the output scaled by ``output_scale`` (k of eq. A.2);
    with ``input_tc`` > 0 the angle loop is ArduSub's, its set-point shaped (eq. A.2s,
    ``companion.numerics.attitude_shaping``: ATC_INPUT_TC, the yaw slew ``yaw_slew_max``).
    ``"px4_rover"`` / ``"px4_uuv"`` (eq. A.4 / A.5, ``companion.numerics.px4_step.px4_controller``)
    take ``full_scale``, ``rate_max``, ``rate_accel_max``, ``speed`` (PX4's speed estimate),
    ``steering_rate``, ``rate_threshold`` and ``torque_max``; the UUV's ``forward_thrust`` (its surge
    thrust, 0–1; NaN: not known) allocates the yaw torque beside it (eq. A.5a).

    ``skid`` (a skid-steered boat only, ``"pi"`` or ``"cascade"``): the controller's output is a
    steering demand δ/``full_scale`` that the skid mixer scales with the throttle of the speed loop,
    and the yaw moment and the speed follow the throttle it leaves (eq. A.2k,
    ``companion.numerics.skid_step``); the largest deflection returned is then the one the
    controller asked for, before the mixer, and the predicted speed at each time is appended to
    ``speed_trace`` when one is given. The rudder at each time (after the mixer on a skid boat) is
    appended to ``rudder_trace`` when one is given."""
    if skid is not None and controller not in ("pi", "cascade"):
        raise ValueError(f"a skid-steered step (eq. A.2k) is predicted under pi or cascade, not {controller!r}")
    if controller in PX4_CONTROLLERS:
        loop = px4_controller(controller, gains, full_scale=full_scale, speed=speed, rate_max=rate_max,
                              rate_accel_max=rate_accel_max, steering_rate=steering_rate,
                              rate_threshold=rate_threshold, torque_max=torque_max, forward_thrust=forward_thrust)
        trace = fly(plant, loop, step, duration_s, dt)
        if rudder_trace is not None:
            rudder_trace.extend(float(v) for v in trace.rudder)
        return trace.times, trace.heading, trace.rudder_peak
    steps = int(round(duration_s / dt))
    times = np.arange(steps + 1) * dt
    heading = np.zeros(steps + 1)
    psi, r, delta = 0.0, 0.0, plant.delta0
    max_step = plant.rudder_rate * dt if math.isfinite(plant.rudder_rate) else math.inf
    if controller == "pi":
        kp, ki, trim = gains.get("heading_p", 0.0), gains.get("heading_i", 0.0), gains.get("rudder_trim", 0.0)
        integral = min(max(plant.delta0 - trim, -imax), imax)
    elif controller == "cascade":
        angle_p = gains.get("heading_angle_p", 0.0)
        rate_p, rate_i = gains.get("heading_rate_p", 0.0), gains.get("heading_rate_i", 0.0)
        rate_ff, rate_imax = gains.get("heading_rate_ff", 0.0), gains.get("heading_rate_imax", rate_imax)
        integral = min(max(plant.delta0 / (full_scale * output_scale), -rate_imax), rate_imax)
        accel_step = rate_accel_max * dt
        previous_demand = 0.0
        shaper = ShapedYawTarget(input_tc, angle_p, rate_p, rate_max, rate_accel_max, yaw_slew_max) \
            if input_tc > 0.0 else None
    else:
        raise ValueError(f"unknown heading controller {controller!r} (pi, cascade, {', '.join(PX4_CONTROLLERS)})")
    peak = abs(delta)
    drive = SkidState(skid, plant.delta0 / full_scale) if skid is not None else None
    previous_delta = delta
    if drive is not None and speed_trace is not None:
        speed_trace.append(drive.speed)
    if rudder_trace is not None:
        rudder_trace.append(delta)
    for k in range(1, steps + 1):
        error = step - psi
        if controller == "pi":  # our simulator's PI knows its own saturation only, not the mixer's
            unsaturated = trim + kp * error + integral
            saturated = min(max(unsaturated, -plant.rudder_max), plant.rudder_max)
            if saturated == unsaturated or (ki * error) * unsaturated <= 0.0:
                integral = min(max(integral + ki * error * dt, -imax), imax)
            demand = min(max(trim + kp * error + integral, -plant.rudder_max), plant.rudder_max)
        else:
            rate_demand = min(max(angle_p * error, -rate_max), rate_max)
            if shaper is not None:
                rate_demand = shaper.rate_demand(step, psi, dt)
            elif math.isfinite(rate_accel_max):
                stop_limit = math.sqrt(2.0 * abs(error) * rate_accel_max)
                rate_demand = min(max(rate_demand, -stop_limit), stop_limit)
                rate_demand = min(max(rate_demand, previous_demand - accel_step), previous_demand + accel_step)
                previous_demand = rate_demand
            rate_error = rate_demand - r
            # the speed scaling comes before the output's limit (AP_MotorsUGV::output_regular), and
            # the integrator stops growing while the scaled output is at it
            output = output_scale * (rate_ff * rate_demand + rate_p * rate_error + integral)
            # ArduRover's rate integrator also stops while the skid mixer limits the steering (eq. A.2k)
            limited = drive is not None and drive.steering_limited
            if (abs(output) < 1.0 and not limited) or (rate_i * rate_error) * output <= 0.0:
                integral = min(max(integral + rate_i * rate_error * dt, -rate_imax), rate_imax)
            output = output_scale * (rate_ff * rate_demand + rate_p * rate_error + integral)
            demand = min(max(output, -1.0), 1.0) * full_scale
        if drive is None:
            delta = _slew(delta, demand, plant.rudder_max, max_step)
            peak = max(peak, abs(delta))
            r += (plant.a22 * r + plant.b2 * (delta - plant.delta0)) * dt
        else:  # eq. A.2k: the mixer, the throttle it leaves and the speed
            peak = max(peak, abs(demand))
            delta = drive.mix(demand / full_scale, dt) * full_scale
            if math.isfinite(max_step) or abs(delta) > plant.rudder_max:  # a slewed or narrower rudder
                delta = _slew(previous_delta, delta, plant.rudder_max, max_step)
            previous_delta = delta
            r += drive.accelerate(plant.a22, plant.b2, full_scale, r, delta / full_scale, dt) * dt
            if speed_trace is not None:
                speed_trace.append(drive.speed)
        psi += r * dt
        heading[k] = psi
        if rudder_trace is not None:
            rudder_trace.append(delta)
    return times, heading, peak


def simulate_rate_tracking(plant: RudderPlant, gains: dict[str, float], times: ArrayLike,
                           desired: ArrayLike, yaw_rate0: float, *, rudder0: float = math.nan,
                           full_scale: float = 0.5236, output_scale: float = 1.0, rate_imax: float = 1.0,
                           rate_loop: RateLoopForm = ARDUROVER_RATE_LOOP, dt: float = 0.01,
                           **_limits: float) -> np.ndarray:
    """The turn rate (rad/s, at ``times``) of eq. A.2's rate loop alone on the model, in the form
    ``rate_loop`` (eq. A.2r: ArduSub's without FF and without the integrator's freeze), asked for the
    recorded ``desired`` turn rate (held between samples): what the rate loop with ``gains`` makes
    of the turns a navigation asked for (the angle loop's limits, ``_limits``, do not act here). A
    record may begin in the middle of a turn, so it starts where the vehicle was: at ``yaw_rate0``
    with the rudder ``rudder0`` it had (unknown: the rudder that holds that turn steadily,
    b2·(δ − δ0) = −a22·r0) and the integrator that, with these gains, gives that rudder. The rate
    PID's D term is not modelled (0: ArduSub's yaw default; learning neither reads nor writes it)."""
    t = np.asarray(times, dtype=float)
    wanted = np.asarray(desired, dtype=float)
    rate_p, rate_i = gains.get("heading_rate_p", 0.0), gains.get("heading_rate_i", 0.0)
    rate_ff, rate_imax = gains.get("heading_rate_ff", 0.0), gains.get("heading_rate_imax", rate_imax)
    if not rate_loop.feed_forward:
        rate_ff = 0.0
    r = yaw_rate0
    delta = rudder0 if math.isfinite(rudder0) else plant.delta0 - plant.a22 * r / plant.b2
    delta = min(max(delta, -plant.rudder_max), plant.rudder_max)
    asked = wanted[0] if wanted.size and math.isfinite(wanted[0]) else 0.0
    integral = delta / (full_scale * output_scale) - rate_ff * asked - rate_p * (asked - r)
    integral = min(max(integral, -rate_imax), rate_imax)
    max_step = plant.rudder_rate * dt if math.isfinite(plant.rudder_rate) else math.inf
    out = np.empty(t.size)
    if t.size == 0:
        return out
    out[0] = r
    for k in range(1, t.size):
        demand_rate = wanted[k - 1] if math.isfinite(wanted[k - 1]) else 0.0
        steps = max(1, int(round((t[k] - t[k - 1]) / dt)))
        h = (t[k] - t[k - 1]) / steps
        for _ in range(steps):
            rate_error = demand_rate - r
            output = output_scale * (rate_ff * demand_rate + rate_p * rate_error + integral)
            if not rate_loop.freeze_at_limit or abs(output) < 1.0 or (rate_i * rate_error) * output <= 0.0:
                integral = min(max(integral + rate_i * rate_error * h, -rate_imax), rate_imax)
            output = output_scale * (rate_ff * demand_rate + rate_p * rate_error + integral)
            delta = _slew(delta, min(max(output, -1.0), 1.0) * full_scale, plant.rudder_max,
                          max_step * h / dt if math.isfinite(max_step) else math.inf)
            r += (plant.a22 * r + plant.b2 * (delta - plant.delta0)) * h
        out[k] = r
    return out


def predict_step(plant: RudderPlant, controller: str, gains: dict[str, float], step: float,
                 duration_s: float = 30.0, **limits) -> PredictedStep:
    """The figures of merit (:func:`step_metrics`) of a step flown on the model, and whether the
    rudder saturated (``rudder_peak`` against its limit; PX4's UUV: its torque limit's, eq. A.5) and
    for how long it sat at its limit (``saturated_s``, what a flown step is allowed too); a
    skid-steered boat's (``skid``, eq. A.2k) also the speed it loses (``speed_dip_pct``, % of its
    speed at the step's start, at the lowest). A :class:`~companion.numerics.step_figures.PredictedStep`."""
    speeds: list[float] = []
    rudder: list[float] = []
    times, heading, peak = simulate_step(plant, controller, gains, step, duration_s, speed_trace=speeds,
                                         rudder_trace=rudder, **limits)
    figures = step_metrics(times, heading, 0.0, step, smooth=False)
    speed_dip = float(100.0 * (1.0 - min(speeds) / speeds[0])) if speeds else None
    limit = plant.rudder_max
    if controller == "px4_uuv":
        limit = min(limit, limits.get("torque_max", 1.0) * limits.get("full_scale", limit))
    # the time at the rudder's limit, by the verification's own test (|δ| ≥ 98 % of the limit)
    at_limit = np.abs(np.asarray(rudder)) >= 0.98 * plant.rudder_max
    saturated_s = float(np.count_nonzero(at_limit[1:]) * (times[1] - times[0])) if times.size > 1 else 0.0
    return PredictedStep(figures, rudder_peak=float(peak), saturated=bool(peak >= 0.999 * limit),
                         saturated_s=saturated_s, speed_dip_pct=speed_dip)
