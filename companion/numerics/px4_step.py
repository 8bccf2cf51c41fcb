"""PX4's own heading controllers, for heading steps predicted on an identified yaw model (eq. A.4, A.5).

Transcribed from upstream PX4-Autopilot (read at commit ``bb59c637cd74e04c000a0b8e35aac184251150d6``,
2026-08-13, of the ``dakejahl/PX4-Autopilot`` mirror):

* **Ackermann rover** (eq. A.4), run at 100 Hz by ``src/modules/rover_ackermann/RoverAckermann.cpp``
  in the order attitude → rate → actuator:

  - ``AckermannAttControl/AckermannAttControl.cpp`` with ``src/lib/rover_control/RoverControl.cpp``
    (``RoverControl::attitudeControl``): the yaw set-point is slewed (``SlewRateYaw``) at
    min(û·tan(RA_MAX_STR_ANG)/RA_WHEEL_BASE, RO_YAW_RATE_LIM), re-initialised to the set-point when the
    slewed one is farther from the heading than the set-point itself; the yaw-rate set-point is a P
    (``PID`` with RO_YAW_P, no integral) on the wrapped error to the slewed set-point, limited to
    ±RO_YAW_RATE_LIM;
  - ``AckermannRateControl/AckermannRateControl.cpp``: the measured yaw rate reads 0 below
    RO_YAW_RATE_TH; the set-point is limited to the feasible rate min(û·tan(RA_MAX_STR_ANG)/L,
    RO_YAW_RATE_LIM), slewed at RO_YAW_ACCEL_LIM (where > 0; re-initialised to the measured rate when
    the slewed set-point is farther from it than the limited one); the steering angle is the bicycle
    feed-forward atan(r_d·L/û)·RO_YAW_RATE_CORR plus a PI (``src/lib/pid/PID.cpp``: RO_YAW_RATE_P/I,
    output and integral each limited to ±1 rad, the integral frozen while the PI's own output is at
    its limit and the error pushes further), normalised by RA_MAX_STR_ANG and clamped to ±1
    (``math::interpolate``);
  - ``AckermannActControl/AckermannActControl.cpp``: the normalised steering slewed at
    RA_STR_RATE_LIM (deg/s of steering angle, where > 0).

  û is PX4's speed estimate, throttle·RO_MAX_THR_SPEED; the step models take it as given (the water
  speed when RO_MAX_THR_SPEED is calibrated, as the design assumes, eq. P.1).
* **UUV** (eq. A.5), ``src/modules/uuv_att_control/uuv_att_control.cpp``
  (``control_attitude_geo``): the geometric attitude error's yaw component for a level vehicle is
  sin(ψ − ψd); the yaw torque is τ = −UUV_YAW_P·sin(ψ − ψd) − UUV_YAW_D·(r − r_d), clamped to
  ±UUV_TORQUE_SAT (``constrain_actuator_commands``). In OFFBOARD with SET_ATTITUDE_TARGET's body
  rates ignored (the companion's set-point) no rate set-point is published, so r_d = 0. The torque is
  an equivalent rudder δ = τ·δfs. There is no integrator.
* **UUV allocation** (eq. A.5a), ``src/lib/control_allocation/control_allocation/
  ControlAllocationSequentialDesaturation.cpp`` (``mixAirmodeDisabled``, MC_AIRMODE 0, the
  HippoCampus' default) with the airframe's four reversible thrusters (CA_R_REV 255, outputs ±1):
  the surge thrust f is mixed first, each thruster at f; the yaw torque τ is added (±τ, the yaw
  column normalised to 1) and reduced by ``desaturateActuators`` until the outputs lie within
  [−1, 1 + 2·MINIMUM_YAW_MARGIN] (0.15: some yaw at full thrust), in two passes (the second at half
  gain); the outputs are then clipped to ±1. The torque that acts is half the difference of the two
  sides: τ itself while f + |τ| ≤ 1, down to 0.5 at f = 0.65 and 0.7 at f = 0.45 for a saturated
  demand, where eq. A.5 alone would act with UUV_TORQUE_SAT (1.0) — the flown steps' step error was
  13–77 % above A.5's prediction.

A controller is a small stateful object (:class:`AckermannYawControl`, :class:`UuvYawControl`):
``start(rudder)`` puts it on course holding ``rudder`` steadily (the heading, relative to the
set-point, at which it does so) and ``update(setpoint, heading, yaw_rate, dt)`` returns the rudder
demand. :func:`fly` flies a step with one on the model of ``companion.numerics.step_response``
(eq. 3.6 with the rudder's limit and slew rate; Euler steps of ``dt``, PX4's loop running at each).
Pure numerics, no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Protocol

import numpy as np

#: FLT_EPSILON: PX4's "configured" test for limits and speeds
EPS = 1.1920929e-07
#: the rate PID's output and integral limits, rad of steering (AckermannRateControl::updateParams)
RATE_PID_LIMIT = 1.0


def wrap_pi(angle: float) -> float:
    """``matrix::wrap_pi``: the angle in [−π, π)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _limit(value: float, bound: float) -> float:
    return value if -bound <= value <= bound else (bound if value > 0.0 else -bound)


class YawPlant(Protocol):
    """What :func:`fly` needs of the plant (``companion.numerics.step_response.RudderPlant``)."""

    @property
    def a22(self) -> float: ...

    @property
    def b2(self) -> float: ...

    @property
    def delta0(self) -> float: ...

    @property
    def rudder_max(self) -> float: ...

    @property
    def rudder_rate(self) -> float: ...


class HeadingController(Protocol):
    """What :func:`fly` needs of a heading controller."""

    def start(self, rudder: float) -> float:
        """On course, holding ``rudder`` steadily: returns the heading relative to the set-point."""

    def update(self, setpoint: float, heading: float, yaw_rate: float, dt: float) -> float:
        """One loop: the rudder demand (rad)."""


def _positive(owner: object, *names: str) -> None:
    for name in names:
        value = getattr(owner, name)
        if not (isinstance(value, (int, float)) and value > 0.0 and not math.isnan(value)):
            raise ValueError(f"{type(owner).__name__}.{name} must be > 0, not {value!r}")


def _non_negative(owner: object, *names: str) -> None:
    for name in names:
        value = getattr(owner, name)
        if not (isinstance(value, (int, float)) and value >= 0.0 and math.isfinite(value)):
            raise ValueError(f"{type(owner).__name__}.{name} must be finite and ≥ 0, not {value!r}")


@dataclass
class AckermannYawControl:
    """PX4's Ackermann rover heading and yaw-rate control (eq. A.4; module docstring). Gains and
    limits in PX4's units except angles in rad: ``rate_max`` (RO_YAW_RATE_LIM), ``accel_max``
    (RO_YAW_ACCEL_LIM; inf: not configured), ``steering_rate`` (RA_STR_RATE_LIM; inf: not
    configured) and ``rate_threshold`` (RO_YAW_RATE_TH) in rad/s or rad/s²."""

    yaw_p: float  # RO_YAW_P, rad/s per rad
    rate_p: float  # RO_YAW_RATE_P, rad of steering per rad/s
    rate_i: float  # RO_YAW_RATE_I, rad of steering per rad
    wheel_base: float  # RA_WHEEL_BASE, m
    speed_estimate: float  # û = throttle·RO_MAX_THR_SPEED, m/s
    steering_max: float  # RA_MAX_STR_ANG, rad
    rate_correction: float = 1.0  # RO_YAW_RATE_CORR
    rate_max: float = math.inf
    accel_max: float = math.inf
    steering_rate: float = math.inf
    rate_threshold: float = 0.0
    adjusted_yaw: float = field(default=0.0, init=False)  # the slewed yaw set-point
    adjusted_rate: float = field(default=0.0, init=False)  # the limited and slewed yaw-rate set-point
    integral: float = field(default=0.0, init=False)  # the rate PID's integral, rad of steering
    servo: float = field(default=0.0, init=False)  # the normalised steering after its slew

    def __post_init__(self) -> None:
        _non_negative(self, "yaw_p", "rate_p", "rate_i", "rate_threshold")
        # PX4's own sanity checks refuse to run without these (runSanityChecks)
        _positive(self, "wheel_base", "speed_estimate", "steering_max", "rate_correction", "rate_max",
                  "accel_max", "steering_rate")
        if not self.steering_max < math.pi / 2:
            raise ValueError(f"AckermannYawControl.steering_max must be below π/2, not {self.steering_max!r}")

    @classmethod
    def from_gains(cls, gains: Mapping[str, float], *, speed_estimate: float, steering_max: float,
                   rate_max: float = math.inf, accel_max: float = math.inf, steering_rate: float = math.inf,
                   rate_threshold: float = 0.0) -> "AckermannYawControl":
        """From the neutral names of ``companion.link.autopilots.px4_rover`` (``heading_angle_p``,
        ``heading_rate_p``, ``heading_rate_i``, ``heading_ff_length``, ``heading_ff_correction``)."""
        return cls(yaw_p=gains.get("heading_angle_p", 0.0), rate_p=gains.get("heading_rate_p", 0.0),
                   rate_i=gains.get("heading_rate_i", 0.0), wheel_base=gains.get("heading_ff_length", 0.0),
                   rate_correction=gains.get("heading_ff_correction", 1.0), speed_estimate=speed_estimate,
                   steering_max=steering_max, rate_max=rate_max, accel_max=accel_max,
                   steering_rate=steering_rate, rate_threshold=rate_threshold)

    @property
    def feasible_rate(self) -> float:
        """û·tan(RA_MAX_STR_ANG)/RA_WHEEL_BASE: the turn rate PX4 believes full steering makes."""
        return abs(self.speed_estimate) * math.tan(self.steering_max) / self.wheel_base

    def start(self, rudder: float) -> float:
        """On course with the set-point, the rate loop's integral holding ``rudder`` (as far as its
        ±1 rad clamp allows) and the steering there."""
        self.adjusted_yaw, self.adjusted_rate = 0.0, 0.0
        self.integral = _limit(rudder, RATE_PID_LIMIT)
        self.servo = _limit(self.integral / self.steering_max, 1.0)
        return 0.0

    def update(self, setpoint: float, heading: float, yaw_rate: float, dt: float) -> float:
        feasible = self.feasible_rate
        # attitude: RoverControl::attitudeControl with AckermannAttControl's slew and limits
        slew = min(feasible, self.rate_max)
        if slew > EPS:
            self.adjusted_yaw = wrap_pi(self.adjusted_yaw + _limit(wrap_pi(setpoint - self.adjusted_yaw), slew * dt))
            if abs(wrap_pi(self.adjusted_yaw - heading)) > abs(wrap_pi(setpoint - heading)):
                self.adjusted_yaw = setpoint
        else:
            self.adjusted_yaw = setpoint
        rate_setpoint = _limit(self.yaw_p * wrap_pi(self.adjusted_yaw - heading), self.rate_max)
        # rate: AckermannRateControl::updateRateControl
        measured = yaw_rate if abs(yaw_rate) > self.rate_threshold else 0.0
        constrained = _limit(rate_setpoint, min(feasible, self.rate_max))
        if math.isfinite(self.accel_max):
            if abs(self.adjusted_rate - measured) > abs(constrained - measured):
                self.adjusted_rate = measured
            self.adjusted_rate += _limit(constrained - self.adjusted_rate, self.accel_max * dt)
        else:
            self.adjusted_rate = constrained
        steering = math.atan(self.adjusted_rate * self.wheel_base / self.speed_estimate) * self.rate_correction
        error = self.adjusted_rate - measured
        output = self.rate_p * error + self.integral
        limited = _limit(output, RATE_PID_LIMIT)
        excess = output - limited
        pushing = (excess > EPS and error > 0.0) or (excess < -EPS and error < 0.0)
        self.integral = _limit(self.integral + self.rate_i * (0.0 if pushing else error) * dt, RATE_PID_LIMIT)
        normalised = _limit((steering + limited) / self.steering_max, 1.0)
        # actuator: AckermannActControl's servo slew (its re-initialisation is to its own last output)
        if math.isfinite(self.steering_rate):
            self.servo += _limit(normalised - self.servo, self.steering_rate / self.steering_max * dt)
        else:
            self.servo = normalised
        return self.servo * self.steering_max


@dataclass
class UuvAllocation:
    """PX4's allocation of a UUV's yaw torque beside its surge thrust ``forward`` (eq. A.5a, module
    docstring): thrusters within [``output_min``, ``output_max``], the yaw's margin above the top."""

    forward: float
    output_min: float = -1.0  # CA_R_REV: reversible thrusters
    output_max: float = 1.0
    yaw_margin: float = 0.15  # ControlAllocationSequentialDesaturation::MINIMUM_YAW_MARGIN

    def __post_init__(self) -> None:
        if not (math.isfinite(self.forward) and self.output_min <= self.forward <= self.output_max):
            raise ValueError(f"UuvAllocation.forward must be a thrust within [{self.output_min:g}, "
                             f"{self.output_max:g}], not {self.forward!r}")
        _non_negative(self, "yaw_margin")

    def torque(self, demand: float) -> float:
        """The yaw torque the thrusters make for ``demand`` (±1, after UUV_TORQUE_SAT)."""
        size = abs(demand)
        high, low = self.forward + size, self.forward - size  # the two sides of the yaw column
        top = self.output_max + (self.output_max - self.output_min) * self.yaw_margin
        for share in (1.0, 0.5):  # desaturateActuators: a full pass, then half the gain left
            gains = [top - high] if high > top else []
            if low < self.output_min:
                gains.append(low - self.output_min)  # the yaw vector is −1 on this side
            gain = share * (min(gains + [0.0]) + max(gains + [0.0]))
            high, low = high + gain, low - gain
        high = min(max(high, self.output_min), self.output_max)
        low = min(max(low, self.output_min), self.output_max)
        return math.copysign(0.5 * (high - low), demand)


@dataclass(frozen=True)
class UuvYawControl:
    """PX4's UUV yaw control (eq. A.5; module docstring): ``yaw_p``, ``yaw_d`` (UUV_YAW_P/D, torque
    per rad and per rad/s), ``torque_max`` (UUV_TORQUE_SAT, 0–1) and ``full_scale`` (rad of
    equivalent rudder at torque 1); with ``allocation`` the torque the thrusters make beside the
    surge thrust (eq. A.5a)."""

    yaw_p: float
    yaw_d: float
    full_scale: float
    torque_max: float = 1.0
    allocation: UuvAllocation | None = None

    def __post_init__(self) -> None:
        _non_negative(self, "yaw_p", "yaw_d", "torque_max")
        _positive(self, "full_scale")
        if self.torque_max > 1.0:
            raise ValueError(f"UuvYawControl.torque_max is UUV_TORQUE_SAT, 0–1, not {self.torque_max!r}")

    @classmethod
    def from_gains(cls, gains: Mapping[str, float], *, full_scale: float, torque_max: float = 1.0,
                   forward_thrust: float = math.nan) -> "UuvYawControl":
        """From the neutral names of ``companion.link.autopilots.px4_uuv`` (``heading_angle_p``,
        ``heading_rate_d``); a finite ``forward_thrust`` (the surge thrust, 0–1) allocates the torque
        beside it (eq. A.5a)."""
        allocation = UuvAllocation(forward_thrust) if math.isfinite(forward_thrust) else None
        return cls(yaw_p=gains.get("heading_angle_p", 0.0), yaw_d=gains.get("heading_rate_d", 0.0),
                   full_scale=full_scale, torque_max=torque_max, allocation=allocation)

    def start(self, rudder: float) -> float:
        """No integrator: a steady ``rudder`` needs the heading error −UUV_YAW_P·sin(ψ − ψd) = δ/δfs;
        0 where the loop cannot hold it (no gain, or beyond the torque limit)."""
        torque = rudder / self.full_scale
        if self.yaw_p <= 0.0 or abs(torque) > min(self.torque_max, self.yaw_p):
            return 0.0
        return -math.asin(torque / self.yaw_p)

    def update(self, setpoint: float, heading: float, yaw_rate: float, dt: float) -> float:
        torque = _limit(-self.yaw_p * math.sin(heading - setpoint) - self.yaw_d * yaw_rate, self.torque_max)
        if self.allocation is not None:
            torque = self.allocation.torque(torque)
        return torque * self.full_scale


@dataclass(frozen=True)
class StepTrace:
    """A flown (predicted) step: time, heading, yaw rate and rudder at each loop."""

    times: np.ndarray
    heading: np.ndarray
    yaw_rate: np.ndarray
    rudder: np.ndarray

    @property
    def rudder_peak(self) -> float:
        return float(np.max(np.abs(self.rudder))) if self.rudder.size else 0.0


def fly(plant: YawPlant, controller: HeadingController, step: float, duration_s: float,
        dt: float = 0.01) -> StepTrace:
    """A heading step of ``step`` rad from the set-point 0, flown with ``controller`` on ``plant``
    (ṙ = a22·r + b2·(δ − δ0), the rudder within ±rudder_max moved at most at rudder_rate), which
    starts on course at the heading where the controller holds δ0 (eq. A.4, A.5)."""
    if not (dt > 0.0 and duration_s > 0.0):
        raise ValueError(f"fly needs dt > 0 and duration_s > 0, not {dt!r}, {duration_s!r}")
    count = int(round(duration_s / dt))
    times = np.arange(count + 1) * dt
    heading, rates, rudders = np.empty(count + 1), np.empty(count + 1), np.empty(count + 1)
    delta = _limit(plant.delta0, plant.rudder_max)
    psi, r = controller.start(delta), 0.0
    max_step = plant.rudder_rate * dt if math.isfinite(plant.rudder_rate) else math.inf
    heading[0], rates[0], rudders[0] = psi, r, delta
    a22, b2, delta0 = plant.a22, plant.b2, plant.delta0
    for k in range(1, count + 1):
        demand = _limit(controller.update(step, psi, r, dt), plant.rudder_max)
        delta += _limit(demand - delta, max_step)
        r += (a22 * r + b2 * (delta - delta0)) * dt
        psi += r * dt
        heading[k], rates[k], rudders[k] = psi, r, delta
    return StepTrace(times, heading, rates, rudders)


def px4_controller(name: str, gains: Mapping[str, float], *, full_scale: float, speed: float = math.nan,
                   rate_max: float = math.inf, rate_accel_max: float = math.inf, steering_rate: float = math.inf,
                   rate_threshold: float = 0.0, torque_max: float = 1.0,
                   forward_thrust: float = math.nan) -> HeadingController:
    """The controller ``name`` ("px4_rover", eq. A.4, or "px4_uuv", eq. A.5) with ``gains`` (neutral
    names) and the vehicle's limits; ``full_scale`` is RA_MAX_STR_ANG on the rover, the equivalent
    rudder of full torque on the UUV, and ``speed`` the rover's speed estimate û."""
    if name == "px4_rover":
        return AckermannYawControl.from_gains(gains, speed_estimate=speed, steering_max=full_scale,
                                              rate_max=rate_max, accel_max=rate_accel_max,
                                              steering_rate=steering_rate, rate_threshold=rate_threshold)
    if name == "px4_uuv":
        return UuvYawControl.from_gains(gains, full_scale=full_scale, torque_max=torque_max,
                                        forward_thrust=forward_thrust)
    raise ValueError(f"unknown PX4 heading controller {name!r} (px4_rover, px4_uuv)")


#: the heading controllers of this module, by the name ``step_response.simulate_step`` takes
PX4_CONTROLLERS = ("px4_rover", "px4_uuv")
