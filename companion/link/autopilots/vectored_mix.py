"""ArduSub's vectored frame: its motor mix un-mixed into the pilot's axes, and the sticks that ask
for them (AP_Motors6DOF ``SUB_FRAME_VECTORED``; the ArduSub strategy and flight logs use it)."""
from __future__ import annotations

import math
from dataclasses import dataclass

#: AP_Motors6DOF SUB_FRAME_VECTORED factors (roll, yaw, throttle, forward) of motors 1..6
VECTORED_FACTORS = (
    (0.0, 1.0, 0.0, -1.0),
    (0.0, -1.0, 0.0, -1.0),
    (0.0, -1.0, 0.0, 1.0),
    (0.0, 1.0, 0.0, 1.0),
    (1.0, 0.0, -1.0, 0.0),
    (-1.0, 0.0, -1.0, 0.0),
)
MOTOR_PWM_CENTRE, MOTOR_PWM_HALF_RANGE = 1500.0, 400.0  # MOT_PWM_MIN/MAX 1100/1900
STICK_CENTRE, STICK_HALF_RANGE = 1500, 400  # RC 3/4/5 trim and range: no climb, no turn, stop


@dataclass(frozen=True)
class VectoredAxes:
    """The vectored frame's demands recovered from its motor outputs (each in ±1).

    ``throttle`` is ArduSub's bidirectional throttle: positive = climb (motors 5/6 have throttle
    factor −1, so a climb drives them below 1500 µs)."""

    yaw: float
    forward: float
    throttle: float = math.nan


def _motor_output(pwm) -> float | None:
    valid = isinstance(pwm, (int, float)) and 800 <= pwm <= 2200
    return (pwm - MOTOR_PWM_CENTRE) / MOTOR_PWM_HALF_RANGE if valid else None


def unmix_vectored(pwm: list[float]) -> VectoredAxes | None:
    """Least-squares un-mix (Σ fᵢ·oᵢ / Σ fᵢ²) of the thruster outputs in µs; None when one of
    motors 1..4 is missing. ``throttle`` is NaN without motors 5 and 6."""
    outputs = [_motor_output(p) for p in list(pwm[:6]) + [None] * (6 - len(pwm[:6]))]
    if any(o is None for o in outputs[:4]):
        return None

    def output(motor: int) -> float:
        value = outputs[motor]
        if value is None:  # axis() is asked only for motors found present above
            raise ValueError(f"motor {motor + 1} has no output")
        return value

    def axis(index: int, motors: range) -> float:
        factors = [VECTORED_FACTORS[m][index] for m in motors]
        return sum(f * output(m) for f, m in zip(factors, motors)) / sum(f * f for f in factors)

    throttle = axis(2, range(4, 6)) if None not in outputs[4:] else math.nan
    return VectoredAxes(yaw=axis(1, range(4)), forward=axis(3, range(4)), throttle=throttle)


def throttle_stick(throttle: float) -> int:
    """RC 3 PWM that gives MANUAL this bidirectional throttle (set_throttle((norm + 1) / 2));
    centre for NaN."""
    value = min(max(throttle, -1.0), 1.0) if math.isfinite(throttle) else 0.0
    return round(STICK_CENTRE + value * STICK_HALF_RANGE)
