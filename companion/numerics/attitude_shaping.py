"""ArduSub's yaw angle loop with its input shaping (eq. A.2s), transcribed from AC_AttitudeControl.

ArduPilot master, ``libraries/AC_AttitudeControl/AC_AttitudeControl.cpp`` and
``libraries/AP_Math/control.cpp`` (read at the blitzy-public-samples/ardupilot-blitzy snapshot,
4.7.0-dev): ALT_HOLD with a SET_ATTITUDE_TARGET heading calls ``input_euler_angle_roll_pitch_yaw``
with ``slew_yaw``; with ``ATC_RATE_FF_ENAB`` 1 (ArduSub's default) the heading does not reach the
angle P at once:

* the *target* heading ψ_t moves toward the set-point at the target rate ω_t, shaped by
  ``input_shaping_angle``: ω_d = sqrt_controller(ψ_sp − ψ_t, 1/ATC_INPUT_TC, α, dt), then ω_t moves
  toward ω_d by at most α·dt (α = ATC_ACCEL_Y_MAX), and is held within the yaw slew
  (min(ATC_SLEW_YAW, ATC_RATE_Y_MAX));
* the angle loop (``attitude_controller_run_quat``) asks the rate loop for
  r_d = sat(sqrt_controller(ψ_t − ψ, ATC_ANG_YAW_P, α_c, dt), ATC_RATE_Y_MAX) + ω_t, with
  α_c = clamp(α/2, 10°/s², 120°/s²): the target rate is a feed-forward into the rate loop;
* the heading error is limited to what saturates the rate loop at rest
  (``thrust_heading_rotation_angles``: min(inv_sqrt_controller(1/ATC_RAT_YAW_P, ANG_P, α_c), 45°)):
  beyond it the target is pulled back toward the vehicle.

Hand-written: these few lines are ArduPilot's own arithmetic; no library carries them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from companion.checks import require_non_negative, require_positive

#: AC_ATTITUDE_ACCEL_Y_CONTROLLER_MIN/MAX_RADSS: the angle loop's acceleration limit bounds, rad/s²
YAW_CONTROLLER_ACCEL_MIN = math.radians(10.0)
YAW_CONTROLLER_ACCEL_MAX = math.radians(120.0)
#: AC_ATTITUDE_YAW_MAX_ERROR_ANGLE_RAD: the largest heading error the angle loop acts on
YAW_MAX_ERROR = math.radians(45.0)


def sqrt_controller(error: float, p: float, second_order_limit: float, dt: float) -> float:
    """AP_Math ``sqrt_controller``: linear P near zero, the square root of constant deceleration
    beyond ``second_order_limit``/p², never overshooting the error within one ``dt``."""
    if not second_order_limit > 0.0 or not math.isfinite(second_order_limit):
        correction = error * p
    elif p == 0.0:
        correction = math.copysign(math.sqrt(2.0 * second_order_limit * abs(error)), error) if error else 0.0
    else:
        linear = second_order_limit / (p * p)
        if error > linear:
            correction = math.sqrt(2.0 * second_order_limit * (error - linear / 2.0))
        elif error < -linear:
            correction = -math.sqrt(2.0 * second_order_limit * (-error - linear / 2.0))
        else:
            correction = error * p
    if dt > 0.0:
        bound = abs(error) / dt
        correction = min(max(correction, -bound), bound)
    return correction


def inv_sqrt_controller(output: float, p: float, second_order_limit: float) -> float:
    """AP_Math ``inv_sqrt_controller``: the error at which :func:`sqrt_controller` gives ``output``."""
    limited = second_order_limit > 0.0 and math.isfinite(second_order_limit)
    if limited and p == 0.0:
        return output * output / (2.0 * second_order_limit)
    if not limited:
        return output / p if p != 0.0 else 0.0
    linear_velocity = second_order_limit / p
    if abs(output) < linear_velocity:
        return output / p
    linear_distance = second_order_limit / (p * p)
    stopping = linear_distance / 2.0 + output * output / (2.0 * second_order_limit)
    return math.copysign(stopping, output)


@dataclass
class ShapedYawTarget:
    """The yaw target and the angle loop of eq. A.2s (module docstring): :meth:`rate_demand` gives the
    rate loop's demand for one ``dt``. Angles in rad, rates in rad/s, ``accel_max`` rad/s² (inf:
    ATC_ACCEL_Y_MAX 0, no limit), ``slew_max`` the yaw slew (rad/s)."""

    input_tc: float
    angle_p: float
    rate_p: float
    rate_max: float = math.inf
    accel_max: float = math.inf
    slew_max: float = math.inf
    target: float = 0.0
    target_rate: float = 0.0
    _controller_accel: float = field(init=False, default=math.inf)
    _error_max: float = field(init=False, default=YAW_MAX_ERROR)

    def __post_init__(self) -> None:
        require_positive(self, "input_tc")
        require_non_negative(self, "angle_p", "rate_p")
        for name in ("rate_max", "accel_max", "slew_max"):  # inf: no limit
            if not getattr(self, name) > 0.0:
                raise ValueError(f"ShapedYawTarget.{name} must be > 0 (inf: no limit), not {getattr(self, name)!r}")
        if math.isfinite(self.accel_max):
            self._controller_accel = min(max(self.accel_max / 2.0, YAW_CONTROLLER_ACCEL_MIN), YAW_CONTROLLER_ACCEL_MAX)
        if self.rate_p > 0.0:
            self._error_max = min(abs(inv_sqrt_controller(1.0 / self.rate_p, self.angle_p, self._controller_accel)),
                                  YAW_MAX_ERROR)

    def rate_demand(self, setpoint: float, heading: float, dt: float) -> float:
        """One loop: the target moved toward ``setpoint`` (shaped), then the rate loop's demand."""
        desired = sqrt_controller(setpoint - self.target, 1.0 / max(self.input_tc, 0.01), self.accel_max, dt)
        if math.isfinite(self.accel_max):
            step = self.accel_max * dt
            desired = min(max(desired, self.target_rate - step), self.target_rate + step)
        slew = min(self.slew_max, self.rate_max)
        self.target_rate = min(max(desired, -slew), slew)
        self.target += self.target_rate * dt
        error = self.target - heading
        if self.angle_p > 0.0 and abs(error) > self._error_max:
            error = math.copysign(self._error_max, error)
            self.target = heading + error
        correction = sqrt_controller(error, self.angle_p, self._controller_accel, dt)
        correction = min(max(correction, -self.rate_max), self.rate_max)
        return correction + self.target_rate
