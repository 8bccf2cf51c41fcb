"""ArduRover's skid-steering mix, reproduced for the simulator's own autopilot (no ArduPilot code).

A skid-steered (twin-thruster) boat has no rudder: the steering demand s ∈ [−1, 1] (positive = turn
to starboard, clockwise) and the throttle t ∈ [−1, 1] become two motor demands. The rules below are
those of ArduPilot's ``libraries/AR_Motors/AP_MotorsUGV.cpp``, read in ``output_skid_steering``,
``output_throttle`` and ``SRV_Channel::pwm_from_angle``, and of ``Rover/mode.cpp``
(``Mode::get_pilot_desired_steering_and_throttle``) for a pilot's sticks:

1. ``lower = −1/MOT_THST_ASYM`` (asymmetry ≥ 1), ``best = (1 + lower)/2`` (the throttle that leaves
   the most steering room). Steering is limited to ``max(t, 0) − lower`` when t < best, else to
   ``1 − best``; throttle to [lower, 1].
2. Saturation ``σ = max(t + |s|, (t − |s|)/lower)``. If σ > 1, with ``MOT_STR_THR_MIX`` ≥ 0.5
   (default 0.5: steering first) the steering is scaled by ``lerp(1/σ → 1, mix 0.5 → 1)`` and the
   throttle becomes ``1 − |s|`` (t ≥ best) or ``|s| + lower`` (t < best); with mix < 0.5 the
   throttle is scaled by ``lerp(1/σ → 1, 0.5 − mix: 0 → 0.5)`` and the steering takes what is left.
3. ``left = t + s``, ``right = t − s``; a negative motor output is multiplied by the asymmetry.
4. Output: ±1 → scaled ±1000 on a channel of angle range 1000 → PWM
   ``trim + int(scaled·(max − trim)/1000)`` (C++ ``uint16_t`` truncation), i.e. 1500 µs = stop,
   2000 full ahead, 1000 full astern with SERVOn_MIN/MAX/TRIM 1000/2000/1500.

Pilot sticks (MANUAL) first shrink both demands in proportion when |s| + |t| > 1.

Sign: positive steering raises the LEFT motor, whose thrust at y = −y_arm turns the boat clockwise
(``sim.physics.propulsion3dof``), as a positive rudder does.
"""
from __future__ import annotations

#: SERVOn_FUNCTION numbers (ArduPilot ``SRV_Channel::Aux_servo_function_t``)
FUNCTION_GROUND_STEERING = 26
FUNCTION_THROTTLE = 70
FUNCTION_THROTTLE_LEFT = 73
FUNCTION_THROTTLE_RIGHT = 74

#: ArduPilot's defaults of MOT_THST_ASYM and MOT_STR_THR_MIX
DEFAULT_THRUST_ASYMMETRY = 1.0
DEFAULT_STEERING_THROTTLE_MIX = 0.5

PWM_TRIM = 1500
PWM_HALF_RANGE = 500


def _lerp(low_out: float, high_out: float, value: float, low_in: float, high_in: float) -> float:
    """ArduPilot's ``linear_interpolate``: ``value`` from [low_in, high_in] mapped to [low_out, high_out], clamped."""
    if value <= low_in:
        return low_out
    if value >= high_in:
        return high_out
    return low_out + (value - low_in) / (high_in - low_in) * (high_out - low_out)


def skid_mix(
    steering: float,
    throttle: float,
    thrust_asymmetry: float = DEFAULT_THRUST_ASYMMETRY,
    steering_throttle_mix: float = DEFAULT_STEERING_THROTTLE_MIX,
) -> tuple[float, float]:
    """(left, right) motor demands in [−1, 1] for steering and throttle in [−1, 1] (rules 1–3 above)."""
    asymmetry = max(thrust_asymmetry, 1.0)
    lower = -1.0 / asymmetry
    best = (1.0 + lower) * 0.5
    steering_range = (max(throttle, 0.0) - lower) if throttle < best else (1.0 - best)
    s = max(-steering_range, min(steering_range, steering))
    t = max(lower, min(1.0, throttle))
    saturation = max(t + abs(s), (t - abs(s)) / lower)
    if saturation > 1.0:
        mix = max(0.0, min(1.0, steering_throttle_mix))
        fair = 1.0 / saturation
        if mix >= 0.5:  # steering first
            s *= _lerp(fair, 1.0, mix, 0.5, 1.0)
            t = 1.0 - abs(s) if t >= best else abs(s) + lower
        else:  # throttle first
            t *= _lerp(fair, 1.0, 0.5 - mix, 0.0, 0.5)
            sign = 1.0 if s > 0.0 else -1.0
            s = (1.0 - t) * sign if t >= best else (t - lower) * sign
    left = t + s
    right = t - s
    if left < 0.0:
        left *= asymmetry
    if right < 0.0:
        right *= asymmetry
    return left, right


def pilot_skid_limit(steering: float, throttle: float) -> tuple[float, float]:
    """A pilot's steering and throttle (±1) shrunk in proportion when |s| + |t| > 1 (Rover MANUAL)."""
    s = max(-1.0, min(1.0, steering))
    t = max(-1.0, min(1.0, throttle))
    saturation = abs(s) + abs(t)
    if saturation > 1.0:
        return steering / saturation, throttle / saturation
    return steering, throttle


def skid_unmix(left: float, right: float, thrust_asymmetry: float = DEFAULT_THRUST_ASYMMETRY) -> tuple[float, float]:
    """(steering, throttle) back from two motor demands: exact for any output of :func:`skid_mix`
    (which keeps t + s and t − s within range)."""
    asymmetry = max(thrust_asymmetry, 1.0)
    if left < 0.0:
        left /= asymmetry
    if right < 0.0:
        right /= asymmetry
    return 0.5 * (left - right), 0.5 * (left + right)


def pwm_from_motor(demand: float) -> int:
    """PWM (µs) of a ThrottleLeft/Right output for a demand in [−1, 1] (rule 4: truncated, 1500 = stop)."""
    d = max(-1.0, min(1.0, demand))
    step = int(abs(d) * PWM_HALF_RANGE)
    return PWM_TRIM + step if d >= 0.0 else PWM_TRIM - step


def motor_from_pwm(pwm: float) -> float:
    """Motor demand in [−1, 1] from PWM (1500 = stop, 2000 full ahead, 1000 full astern)."""
    return max(-1.0, min(1.0, (pwm - PWM_TRIM) / PWM_HALF_RANGE))
