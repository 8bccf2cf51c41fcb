"""How a boat's servo outputs steer and drive it, read from the autopilot's own parameters (SPEC C1, §4).

ArduPilot says what each output drives with ``SERVOn_FUNCTION`` (``SRV_Channel::Aux_servo_function_t``):

* a **steering servo**: 26 GroundSteering (ArduRover's steering output) or 21 Rudder, with a
  throttle 70;
* a **skid-steered pair** (twin thrusters): 73 ThrottleLeft and 74 ThrottleRight. ArduRover mixes the
  steering demand s and the throttle t (both ±1) into the two motors in
  ``AP_MotorsUGV::output_skid_steering``: s and t are first limited (MOT_THST_ASYM sets the reverse
  limit ``lower = −1/asym``; on saturation MOT_STR_THR_MIX ≥ 0.5 gives the steering priority and
  lowers the throttle, below 0.5 the reverse), then ``left = t + s``, ``right = t − s``, a negative
  motor is multiplied by the asymmetry, and each motor goes through ``get_scaled_throttle``
  (MOT_THR_MIN and the thrust curve MOT_THST_EXPO) to its PWM.

:meth:`Actuation.demands` turns the outputs back into (s, t): each PWM to its normalised output
with the output's SERVOn_MIN/TRIM/MAX/REVERSED (``SRV_Channel::pwm_from_angle``), the thrust curve and
MOT_THR_MIN undone, the asymmetry undone, then **s = (L − R)/2, t = (L + R)/2** (eq. S.1). Every
step is exact, so what comes back is the steering and throttle the mixer *applied*, after any
saturation it resolved: the identifier sees the yaw input the boat really got. Saturation itself
changes the throttle while steering (the speed then drifts within a record), so the campaign keeps
clear of it (the ArduRover strategy holds |s| + |t| within the mixer's room, and says so).

The neutral "rudder" of a skid boat is its steering demand times the profile's full scale (an
**equivalent rudder**, rad); its "thrust" is the throttle t. A steering-servo boat reads the same way
(the servo's normalised output × full scale), so the rest of the product never asks which kind it is.

A vehicle whose outputs cannot be understood is refused (:class:`companion.link.errors.ProfileError`)
with what to set. Pure: parameters in, numbers out (also used by the log readers).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

from companion.checks import require_non_negative, require_range
from companion.link.errors import ProfileError

#: SERVOn_FUNCTION numbers (ArduPilot ``SRV_Channel::Aux_servo_function_t``)
FUNCTION_RUDDER = 21
FUNCTION_GROUND_STEERING = 26
FUNCTION_THROTTLE = 70
FUNCTION_THROTTLE_LEFT = 73
FUNCTION_THROTTLE_RIGHT = 74
STEERING_FUNCTIONS = (FUNCTION_GROUND_STEERING, FUNCTION_RUDDER)
#: ArduRover's servo outputs (SERVO1..16)
OUTPUTS = tuple(range(1, 17))
#: the mixer parameters read with the outputs, and ArduPilot's defaults
MIXER_DEFAULTS = {"MOT_THST_ASYM": 1.0, "MOT_STR_THR_MIX": 0.5, "MOT_THR_MIN": 0.0, "MOT_THST_EXPO": 0.0}
#: a PWM outside this range is "no data" (0 = output disabled)
PWM_VALID = (800.0, 2200.0)


def function_names(outputs: Sequence[int] = OUTPUTS) -> tuple[str, ...]:
    return tuple(f"SERVO{n}_FUNCTION" for n in outputs)


def scale_names(output: int) -> tuple[str, ...]:
    return tuple(f"SERVO{output}_{field}" for field in ("MIN", "TRIM", "MAX", "REVERSED"))


@dataclass(frozen=True)
class OutputScale:
    """One servo output's PWM range (SERVOn_MIN/TRIM/MAX/REVERSED)."""

    output: int
    minimum: float = 1000.0
    trim: float = 1500.0
    maximum: float = 2000.0
    reversed: bool = False

    def __post_init__(self) -> None:
        require_range(self, "output", 1, 32)
        if not (self.minimum < self.trim < self.maximum):
            raise ProfileError(f"SERVO{self.output}: MIN {self.minimum:g} < TRIM {self.trim:g} < MAX {self.maximum:g} "
                               "does not hold; set the output's PWM range")

    @classmethod
    def from_params(cls, output: int, params: Mapping[str, float]) -> "OutputScale":
        low, trim, high, rev = (params.get(name) for name in scale_names(output))
        return cls(output, 1000.0 if low is None else float(low), 1500.0 if trim is None else float(trim),
                   2000.0 if high is None else float(high), bool(rev))

    def normalised(self, pwm: float) -> float:
        """The output's ±1 value of a PWM (``SRV_Channel::pwm_from_angle`` inverted); NaN for no data."""
        if not (isinstance(pwm, (int, float)) and math.isfinite(pwm) and PWM_VALID[0] <= pwm <= PWM_VALID[1]):
            return math.nan
        if pwm >= self.trim:
            value = (pwm - self.trim) / (self.maximum - self.trim)
        else:
            value = (pwm - self.trim) / (self.trim - self.minimum)
        return -value if self.reversed else value


@dataclass(frozen=True)
class Actuation:
    """What drives the boat (module docstring): ``kind`` "steering" (a steering servo and a throttle)
    or "skid" (a left/right pair), the outputs' scales and the mixer's parameters."""

    kind: str
    steering: OutputScale | None = None
    throttle: OutputScale | None = None
    left: OutputScale | None = None
    right: OutputScale | None = None
    thrust_asymmetry: float = 1.0  # MOT_THST_ASYM
    steering_throttle_mix: float = 0.5  # MOT_STR_THR_MIX
    throttle_min_pct: float = 0.0  # MOT_THR_MIN
    thrust_expo: float = 0.0  # MOT_THST_EXPO
    steering_function: int = FUNCTION_GROUND_STEERING

    def __post_init__(self) -> None:
        if self.kind == "steering":
            if self.steering is None:
                raise ValueError("Actuation 'steering' needs a steering output")
        elif self.kind == "skid":
            if self.left is None or self.right is None:
                raise ValueError("Actuation 'skid' needs a left and a right output")
        else:
            raise ValueError(f"Actuation.kind must be 'steering' or 'skid', not {self.kind!r}")
        require_range(self, "thrust_asymmetry", 1.0, 10.0)
        require_range(self, "steering_throttle_mix", 0.0, 1.0)
        require_range(self, "throttle_min_pct", 0.0, 99.0)
        require_range(self, "thrust_expo", -1.0, 1.0)
        require_non_negative(self, "steering_function")

    @property
    def skid(self) -> bool:
        return self.kind == "skid"

    @property
    def lower_throttle(self) -> float:
        """The mixer's reverse limit −1/MOT_THST_ASYM."""
        return -1.0 / self.thrust_asymmetry

    def unscaled_throttle(self, value: float) -> float:
        """A throttle-type output (±1) before ``get_scaled_throttle``: the thrust curve
        y → (1 − e)·y + e·y² and MOT_THR_MIN undone (both exact inverses)."""
        if not math.isfinite(value) or value == 0.0:
            return value
        sign, q = (1.0 if value > 0 else -1.0), min(abs(value), 1.0)
        e = self.thrust_expo
        p = q if e == 0.0 else (1.0 - e) * q + e * q * q
        low = self.throttle_min_pct / 100.0
        if low > 0.0:
            p = max(0.0, (p - low) / (1.0 - low))
        return sign * p

    def demands(self, pwm: Sequence[float]) -> tuple[float, float]:
        """(steering s, throttle t), each ±1, from SERVO_OUTPUT_RAW / RCOU PWM (outputs 1..n, index 0 =
        output 1); NaN where an output is missing or disabled (eq. S.1 for a pair)."""
        def at(scale: OutputScale) -> float:
            return scale.normalised(pwm[scale.output - 1]) if scale.output <= len(pwm) else math.nan

        if not self.skid:
            throttle = self.unscaled_throttle(at(self.throttle)) if self.throttle is not None else math.nan
            return at(self._scale(self.steering, "steering")), throttle
        left = self.unscaled_throttle(at(self._scale(self.left, "left")))
        right = self.unscaled_throttle(at(self._scale(self.right, "right")))
        if left < 0.0:
            left /= self.thrust_asymmetry
        if right < 0.0:
            right /= self.thrust_asymmetry
        return 0.5 * (left - right), 0.5 * (left + right)

    def steering_room(self, throttle: float) -> float:
        """The largest |s| the skid mixer applies at throttle t without touching the throttle
        (t + |s| ≤ 1 and t − |s| ≥ −1/asym); 1 for a steering servo (its throttle is separate)."""
        if not self.skid or not math.isfinite(throttle):
            return 1.0
        return max(0.0, min(1.0 - throttle, throttle - self.lower_throttle))

    def outputs(self) -> dict[str, int]:
        """Neutral role → output number (for messages and reports)."""
        roles = (("steering", self.steering), ("throttle", self.throttle), ("left", self.left), ("right", self.right))
        return {role: scale.output for role, scale in roles if scale is not None}

    def _scale(self, scale: OutputScale | None, role: str) -> OutputScale:
        """``scale``, an output this kind has (``__post_init__`` checked it is there)."""
        if scale is None:
            raise ValueError(f"Actuation {self.kind!r} has no {role} output")
        return scale

    def describe(self) -> str:
        if self.skid:
            left, right = self._scale(self.left, "left"), self._scale(self.right, "right")
            return (f"skid steering: SERVO{left.output} ThrottleLeft, SERVO{right.output} ThrottleRight "
                    f"(MOT_THST_ASYM {self.thrust_asymmetry:g}, MOT_STR_THR_MIX {self.steering_throttle_mix:g}); "
                    "steering and throttle un-mixed from the two outputs")
        name = "Rudder" if self.steering_function == FUNCTION_RUDDER else "GroundSteering"
        throttle = f", SERVO{self.throttle.output} Throttle" if self.throttle is not None else ", no throttle output"
        steering = self._scale(self.steering, "steering")
        return f"SERVO{steering.output} {name} (min/trim/max {steering.minimum:.0f}/" \
               f"{steering.trim:.0f}/{steering.maximum:.0f}){throttle}"

    def scale_params(self) -> tuple[str, ...]:
        """The SERVOn_MIN/TRIM/MAX/REVERSED names of the outputs in use."""
        return tuple(name for output in self.outputs().values() for name in scale_names(output))


def _outputs_with(functions: Mapping[int, float], wanted: int) -> list[int]:
    return sorted(n for n, f in functions.items() if isinstance(f, (int, float)) and math.isfinite(f)
                  and int(round(f)) == wanted)


def actuation_from_functions(functions: Mapping[int, float], params: Mapping[str, float] | None = None,
                             where: str = "the vehicle", *, require_throttle: bool = True) -> Actuation:
    """The boat's actuation from its output functions (output number → SERVOn_FUNCTION) and, where
    known, the outputs' scales and the mixer's parameters (``params`` by ArduPilot name; defaults
    otherwise). ProfileError with what to set when the outputs cannot be understood; a steering
    servo without a throttle output passes only without ``require_throttle`` (a log, where only
    the steering is needed)."""
    params = dict(params or {})
    mixer = {name: float(params.get(name, default)) for name, default in MIXER_DEFAULTS.items()}
    left, right = _outputs_with(functions, FUNCTION_THROTTLE_LEFT), _outputs_with(functions, FUNCTION_THROTTLE_RIGHT)
    steering = {f: _outputs_with(functions, f) for f in STEERING_FUNCTIONS}
    throttle = _outputs_with(functions, FUNCTION_THROTTLE)
    found = ", ".join(f"SERVO{n}_FUNCTION {int(round(f))}" for n, f in sorted(functions.items())
                      if isinstance(f, (int, float)) and math.isfinite(f) and int(round(f)) != 0) or "no output function"
    thrust_asymmetry = max(1.0, mixer["MOT_THST_ASYM"])
    steering_throttle_mix = min(1.0, max(0.0, mixer["MOT_STR_THR_MIX"]))
    throttle_min_pct = min(99.0, max(0.0, mixer["MOT_THR_MIN"]))
    thrust_expo = mixer["MOT_THST_EXPO"] if -1.0 <= mixer["MOT_THST_EXPO"] <= 1.0 else 0.0
    if left or right:
        if not (left and right):
            missing = "74 ThrottleRight" if left else "73 ThrottleLeft"
            raise ProfileError(f"{where} has one skid-steering motor but not the other ({found}): set "
                               f"SERVOn_FUNCTION {missing} on the other motor's output")
        if steering[FUNCTION_GROUND_STEERING] or steering[FUNCTION_RUDDER] or throttle:
            raise ProfileError(f"{where} has a skid-steering pair and a steering servo or throttle too ({found}): "
                               "the companion cannot tell which one steers; keep either 73/74 or 26 (or 21) with 70")
        return Actuation("skid", left=OutputScale.from_params(left[0], params),
                         right=OutputScale.from_params(right[0], params), thrust_asymmetry=thrust_asymmetry,
                         steering_throttle_mix=steering_throttle_mix, throttle_min_pct=throttle_min_pct,
                         thrust_expo=thrust_expo)
    function = next((f for f in STEERING_FUNCTIONS if steering[f]), None)
    if function is None:
        raise ProfileError(f"{where} has no steering output ({found}): set SERVOn_FUNCTION 26 (GroundSteering) on "
                           "the steering servo's output, or 73/74 (ThrottleLeft/Right) on a twin-thruster boat's motors")
    if not throttle and require_throttle:
        raise ProfileError(f"{where} has a steering output but no throttle ({found}): set SERVOn_FUNCTION 70 "
                           "(Throttle) on the motor's output")
    return Actuation("steering", steering=OutputScale.from_params(steering[function][0], params),
                     throttle=OutputScale.from_params(throttle[0], params) if throttle else None,
                     steering_function=function, thrust_asymmetry=thrust_asymmetry,
                     steering_throttle_mix=steering_throttle_mix, throttle_min_pct=throttle_min_pct,
                     thrust_expo=thrust_expo)


def actuation_from_params(params: Mapping[str, float], where: str = "the vehicle") -> Actuation:
    """:func:`actuation_from_functions` from a parameter table (a log's PARAM_VALUE / PARM rows; a
    throttle output is not required there)."""
    functions = {n: params[f"SERVO{n}_FUNCTION"] for n in range(1, 33) if f"SERVO{n}_FUNCTION" in params}
    if not functions:
        raise ProfileError(f"{where} carries no SERVOn_FUNCTION parameter: the companion cannot tell which output "
                           "steers (a log recorded with its parameters, or --profile sim for our simulator's logs)")
    return actuation_from_functions(functions, params, where, require_throttle=False)
