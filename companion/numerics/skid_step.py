"""A skid-steered boat's heading step: the mixer, the thrust it leaves and the speed it loses (eq. A.2k).

A twin-thruster boat turns with differential thrust, so the yaw model identified at one speed
(ṙ = a22·r + b2·(δ − δ0), eq. 3.6, from small doublets around the throttle t0 that holds the speed
u0) does not hold through a quick heading step:

* **the mixer** (ArduRover's ``AP_MotorsUGV::output_skid_steering``, :meth:`SkidMixer.mix`) keeps
  t + |s| ≤ 1: a steering demand beyond the room 1 − t0 is scaled down and the throttle lowered
  (MOT_STR_THR_MIX 0.5, the default: s' = s/σ, t' = 1 − |s'|, σ = t + |s|), and the steering and
  throttle limits it reports freeze the rate and speed integrators;
* **the yaw moment** is the two motors' thrust difference, F(t' + s') − F(t' − s') with
  F(d) = sign(d)·|d|^q: with q = 2 (a propeller's thrust ∝ demand²) it is 4·t'·s', proportional to
  the *throttle* as much as to the steering, so the throttle the mixer takes away takes the yaw
  authority with it;
* **the speed** answers the motors' total thrust F(t' + s') + F(t' − s') through the surge model
  (eq. S.4, with its throttle lag), and ArduRover's speed loop (eq. S.5, GUIDED: the verification
  steps are flown at a speed demand) pushes the throttle back; the hull's damping a22 and the
  steering authority b2 follow the speed (the fitted a22 slope and the speed law, eq. S.3).

With u the speed, t_ss(u) = t0·(u/u0)^(1/p) the throttle that holds it (eq. S.4's steady law,
q = 2p: thrust ∝ U_ss² ∝ t^(2p)), s0 = δ0/δfs the trim and L, R = t' ± s' the motors:

    M(t, s; u) = (F(t + s) − F(t − s)) / (2·F′(t_ss(u)))                 (the steering, per unit of b2·δfs)
    ṙ = a22(u)·r + b2(u)·δfs·(M(t', s'; u) − M(t', s0; u))
    u̇ = γ·(u0²·(F(Lx) + F(Rx)) / (F(t0 + s0) + F(t0 − s0)) − u·|u|),   Lx, Rx: L, R lagged by τl
    a22(u) = a22(u0) + (∂a22/∂u)·(u − u0),   b2(u) = b2(u0)·(k·uⁿ + c)/(k·u0ⁿ + c)       (A.2k)

At the step's start (t' = t0, s' = s0, u = u0) M is exactly s − s0 for small steering, so the
identified model is unchanged there; a rudder boat never takes this path. F is symmetric in the
mixer's space: MOT_THST_ASYM is taken to compensate the motors' weaker astern thrust.

What slows a quick step is the throttle the mixer takes, not the speed: with q = 2 and b2 ∝ u the
moment per unit of t'·s' does not change with the speed (b2(u)/F′(t_ss(u)) is constant), and the
speed lost in the turn acts through a22(u) and the law's intercept only. Measured on ArduRover SITL
(our skid boat, 3 runs × 4 flown ±40° steps): the recorded steering with the throttle the mixer left
reproduces the flown heading within 1.4–1.8° RMS, with the identified model alone 12–18°; the speed
dip (2.00 → 1.72 m/s flown, 1.76 predicted) moved the predicted step error by 3 % (docs/method.md,
eq. A.2k). Pure numerics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from companion.checks import require_finite, require_non_negative, require_positive, require_range


@dataclass(frozen=True)
class MixerOutput:
    """What the mixer applied: steering and throttle (±1), and whether it limited either."""

    steering: float
    throttle: float
    steering_limited: bool
    throttle_limited: bool


def _lerp(low_out: float, high_out: float, value: float, low_in: float, high_in: float) -> float:
    """ArduPilot's ``linear_interpolate`` (clamped)."""
    if value <= low_in:
        return low_out
    if value >= high_in:
        return high_out
    return low_out + (value - low_in) / (high_in - low_in) * (high_out - low_out)


@dataclass(frozen=True)
class SkidMixer:
    """ArduRover's skid-steering mixer: MOT_THST_ASYM (≥ 1) and MOT_STR_THR_MIX (0–1)."""

    thrust_asymmetry: float = 1.0
    steering_throttle_mix: float = 0.5

    def __post_init__(self) -> None:
        require_range(self, "thrust_asymmetry", 1.0, 10.0)
        require_range(self, "steering_throttle_mix", 0.0, 1.0)

    def mix(self, steering: float, throttle: float) -> MixerOutput:
        """The steering and throttle ``AP_MotorsUGV::output_skid_steering`` applies for a demand of
        ``steering`` and ``throttle`` (both ±1), with the limit flags it raises for the controllers."""
        return MixerOutput(*_mix(steering, throttle, self.thrust_asymmetry, self.steering_throttle_mix))


def _mix(steering: float, throttle: float, asymmetry: float, priority: float) -> tuple[float, float, bool, bool]:
    """:meth:`SkidMixer.mix` as a tuple (steering, throttle, steering limited, throttle limited)."""
    lower = -1.0 / asymmetry
    best = (1.0 + lower) * 0.5
    room = (max(throttle, 0.0) - lower) if throttle < best else (1.0 - best)
    s = min(max(steering, -room), room)
    t = min(max(throttle, lower), 1.0)
    steer_limited = abs(s) < abs(steering) or abs(steering) > 1.0  # set_limits_from_input: beyond ±1
    throttle_limited = t != throttle
    saturation = max(t + abs(s), (t - abs(s)) / lower)
    if saturation > 1.0:
        s_before, t_before = s, t
        fair = 1.0 / saturation
        if priority >= 0.5:  # the steering first: scaled by lerp(1/σ → 1), the throttle takes what is left
            s *= _lerp(fair, 1.0, priority, 0.5, 1.0)
            t = 1.0 - abs(s) if t >= best else abs(s) + lower
        else:  # the throttle first
            t *= _lerp(fair, 1.0, 0.5 - priority, 0.0, 0.5)
            sign = 1.0 if s > 0.0 else -1.0
            s = (1.0 - t) * sign if t >= best else (t - lower) * sign
        steer_limited = steer_limited or abs(s) < abs(s_before)
        throttle_limited = throttle_limited or abs(t) < abs(t_before)
    return s, t, steer_limited, throttle_limited


@dataclass(frozen=True)
class SpeedHold:
    """ArduRover's speed loop during a heading step (eq. S.5 at a constant demand, the speed's own):
    t = t0 + ATC_SPEED_P·(u0 − u) + ΔI, İ = ATC_SPEED_I·(u0 − u), |I| ≤ ATC_SPEED_IMAX, I frozen
    while the mixer limits the throttle (unless it unwinds). The feed-forward cancels out."""

    p: float
    i: float
    imax: float = 1.0

    def __post_init__(self) -> None:
        require_non_negative(self, "p", "i")
        require_positive(self, "imax")


def _check_shared(record: "SkidDrive | SkidPlant") -> None:
    """The fields a skid boat's drive at one speed and its plant over all speeds share."""
    require_non_negative(record, "gamma", "lag", "b2_exponent")
    require_finite(record, "a22_slope", "b2_intercept_ratio")
    name = type(record).__name__
    if not isinstance(record.mixer, SkidMixer):
        raise ValueError(f"{name}.mixer must be a SkidMixer, not {record.mixer!r}")
    if record.speed_loop is not None and not isinstance(record.speed_loop, SpeedHold):
        raise ValueError(f"{name}.speed_loop must be a SpeedHold or None, not {record.speed_loop!r}")


@dataclass(frozen=True)
class SkidDrive:
    """Eq. A.2k at one speed (module docstring): the mixer, the trim throttle ``throttle`` (t0) that
    holds ``speed`` (u0, m/s), the motors' thrust exponent q, the surge model's γ (1/m; 0: the speed
    is held) and lag (s), how a22 and b2 follow the speed (``a22_slope`` 1/s per m/s; b2 ∝ k·uⁿ + c:
    ``b2_exponent`` n and ``b2_intercept_ratio`` c/k) and the speed loop (None: the throttle demand
    stays at t0)."""

    mixer: SkidMixer
    speed: float
    throttle: float
    thrust_exponent: float = 2.0
    gamma: float = 0.0
    lag: float = 0.0
    a22_slope: float = 0.0
    b2_exponent: float = 1.0
    b2_intercept_ratio: float = 0.0
    speed_loop: SpeedHold | None = None

    def __post_init__(self) -> None:
        require_positive(self, "speed", "thrust_exponent")
        require_range(self, "throttle", 0.01, 1.0)
        _check_shared(self)

    # ------------------------------------------------------------------ eq. A.2k's pieces
    def thrust(self, demand: float) -> float:
        """F(d) = sign(d)·|d|^q: one motor's thrust, relative."""
        if self.thrust_exponent == 2.0:
            return demand * abs(demand)
        return math.copysign(abs(demand) ** self.thrust_exponent, demand)

    def steady_throttle(self, speed: float) -> float:
        """t_ss(u) = t0·(u/u0)^(1/p), p = q/2 (eq. S.4's steady law through this speed's trim)."""
        return self.throttle * (max(speed, 1e-3) / self.speed) ** (2.0 / self.thrust_exponent)

    def moment(self, throttle: float, steering: float, speed: float) -> float:
        """M(t, s; u): the motors' yaw moment in units of steering at the steady throttle of ``speed``."""
        q = self.thrust_exponent
        slope = 2.0 * q * self.steady_throttle(speed) ** (q - 1.0)
        return (self.thrust(throttle + steering) - self.thrust(throttle - steering)) / slope

    def b2_ratio(self, speed: float) -> float:
        """b2(u)/b2(u0) by the speed law (never below a tenth: the law is fitted over the flown speeds)."""
        law = max(speed, 0.0) ** self.b2_exponent + self.b2_intercept_ratio
        base = self.speed ** self.b2_exponent + self.b2_intercept_ratio
        return max(law / base, 0.1) if base > 0.0 else 1.0


@dataclass(frozen=True)
class SkidPlant:
    """What a campaign knows of a skid-steered boat for eq. A.2k at any of its speeds: the mixer, the
    steady law U_ss = k·t^p of eq. S.4 (``throttle_gain`` k, m/s at throttle 1, and
    ``throttle_exponent`` p: the trim throttle at each speed, and q = 2p), the surge model's γ and
    lag (γ 0: unknown, the speed is held), a22's slope with the speed and b2's speed law (eq. S.3), and
    the speed loop the steps are flown with (None: unknown, the throttle demand is held)."""

    mixer: SkidMixer
    throttle_gain: float
    throttle_exponent: float = 1.0
    gamma: float = 0.0
    lag: float = 0.0
    a22_slope: float = 0.0
    b2_exponent: float = 1.0
    b2_intercept_ratio: float = 0.0
    speed_loop: SpeedHold | None = None

    def __post_init__(self) -> None:
        require_positive(self, "throttle_gain")
        require_range(self, "throttle_exponent", 0.2, 3.0)
        _check_shared(self)

    def throttle_at(self, speed: float) -> float:
        """The throttle that holds ``speed`` (eq. S.4's steady law), within the mixer's 0.01–1."""
        return min(max((max(speed, 0.0) / self.throttle_gain) ** (1.0 / self.throttle_exponent), 0.01), 1.0)

    def at(self, speed: float) -> SkidDrive:
        """Eq. A.2k at ``speed`` (m/s > 0)."""
        return SkidDrive(self.mixer, speed, self.throttle_at(speed), 2.0 * self.throttle_exponent, self.gamma,
                         self.lag, self.a22_slope, self.b2_exponent, self.b2_intercept_ratio, self.speed_loop)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "SkidPlant":
        """From ``dataclasses.asdict`` of one (a stored campaign summary's limits)."""
        values = dict(data)
        values["mixer"] = SkidMixer(**values["mixer"])
        loop = values.get("speed_loop")
        values["speed_loop"] = SpeedHold(**loop) if loop is not None else None
        return cls(**values)


def _thrust(demand: float, exponent: float) -> float:
    """F(d) = sign(d)·|d|^q (:meth:`SkidDrive.thrust`)."""
    if exponent == 2.0:
        return demand * abs(demand)
    return math.copysign(abs(demand) ** exponent, demand)


class SkidState:
    """The integration state of eq. A.2k through one predicted step (used by ``simulate_step``, so
    written for speed: the drive's constants are unpacked once)."""

    def __init__(self, drive: SkidDrive, trim_steering: float) -> None:
        self.drive = drive
        self.trim = trim_steering
        self.speed = drive.speed
        self.integral = 0.0  # the speed loop's integrator change since the step began
        self.left, self.right = drive.throttle + trim_steering, drive.throttle - trim_steering  # lagged motors
        self.thrust0 = drive.thrust(self.left) + drive.thrust(self.right)
        self.throttle = drive.throttle  # the mixer's latest
        self.steering_limited = False
        self.throttle_limited = False
        self._mixer = (drive.mixer.thrust_asymmetry, drive.mixer.steering_throttle_mix)
        q = drive.thrust_exponent
        self._q = q
        self._slope0 = 2.0 * q * drive.throttle ** (q - 1.0)  # 2F′(t0)
        self._slope_power = 2.0 * (q - 1.0) / q
        self._law0 = drive.speed ** drive.b2_exponent + drive.b2_intercept_ratio
        self._follow: tuple[float, float] = (math.nan, 1.0)  # (dt, the lag's factor over it)

    def mix(self, steering: float, dt: float) -> float:
        """The steering the mixer applies for ``steering`` (±1) at the speed loop's throttle; the
        limit flags it raises act on the controllers' next update, as on the autopilot."""
        loop = self.drive.speed_loop
        if loop is None:
            throttle = self.drive.throttle
        else:  # the speed loop (SpeedHold), its integrator frozen while the mixer limits the throttle
            error = self.drive.speed - self.speed
            if not self.throttle_limited or error * self.integral < 0.0:
                self.integral = min(max(self.integral + loop.i * error * dt, -loop.imax), loop.imax)
            throttle = self.drive.throttle + loop.p * error + self.integral
        asymmetry, priority = self._mixer
        if asymmetry == 1.0 and 0.0 <= throttle <= 1.0 and -1.0 <= steering <= 1.0 \
                and throttle + abs(steering) <= 1.0:  # inside the room: as asked (the common case)
            self.throttle, self.steering_limited, self.throttle_limited = throttle, False, False
            return steering
        applied, self.throttle, self.steering_limited, self.throttle_limited = _mix(
            steering, throttle, asymmetry, priority)
        return applied

    def accelerate(self, a22: float, b2: float, full_scale: float, r: float, steering: float, dt: float) -> float:
        """ṙ of eq. A.2k with ``steering`` (±1) applied at the mixer's latest throttle (``a22``, ``b2``:
        the model at the step's speed, ``full_scale`` δfs); then the speed over ``dt`` (eq. S.4 driven
        by both motors' thrust, each lagged)."""
        drive, t, u, q, trim = self.drive, self.throttle, self.speed, self._q, self.trim
        u0 = drive.speed
        # M(t, s) − M(t, s0), in units of 2F′(t_ss(u))
        a, b, c, d = t + steering, t - steering, t + trim, t - trim
        if q == 2.0:
            moment = a * abs(a) - b * abs(b) - c * abs(c) + d * abs(d)
        elif q > 1.0:  # sign(x)·|x|^q = x·|x|^(q − 1), inline (the hot loop of the design's search)
            e = q - 1.0
            moment = a * abs(a) ** e - b * abs(b) ** e - c * abs(c) ** e + d * abs(d) ** e
        else:
            moment = _thrust(a, q) - _thrust(b, q) - _thrust(c, q) + _thrust(d, q)
        if u == u0:
            accel = a22 * r + b2 * full_scale * moment / self._slope0
        else:
            # 2F′(t_ss(u)) = 2F′(t0)·(u/u0)^(2(q − 1)/q), and b2's speed law
            slope = self._slope0 * (max(u, 1e-3) / u0) ** self._slope_power
            n = drive.b2_exponent
            law = (u if n == 1.0 else max(u, 0.0) ** n) + drive.b2_intercept_ratio
            ratio = max(law / self._law0, 0.1) if self._law0 > 0.0 else 1.0
            accel = (a22 + drive.a22_slope * (u - u0)) * r + b2 * ratio * full_scale * moment / slope
        lag_dt, follow = self._follow
        if lag_dt != dt:
            follow = 1.0 if drive.lag <= 0.0 else 1.0 - math.exp(-dt / drive.lag)
            self._follow = (dt, follow)
        self.left += (t + steering - self.left) * follow
        self.right += (t - steering - self.right) * follow
        if drive.gamma > 0.0 and self.thrust0 > 0.0:
            left, right = self.left, self.right
            both = left * abs(left) ** (q - 1.0) + right * abs(right) ** (q - 1.0) if q > 1.0 else \
                _thrust(left, q) + _thrust(right, q)
            push = u0 * u0 * both / self.thrust0
            self.speed = u + drive.gamma * (push - u * abs(u)) * dt
        return accel
