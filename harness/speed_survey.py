"""A survey's speed changes behind ArduRover's speed loop, simulated for the tests of learning the
speed loop during missions (eq. L.4): what a boat in AUTO does to its speed on a lawnmower, without
MAVLink and in lockstep by construction.

The boat is eq. S.4's surge (thrust against quadratic drag behind a throttle lag) with a random
along-track force (an Ornstein–Uhlenbeck process, the sea) and noise on the measured speed; the
autopilot is ArduRover's speed loop as ``AR_AttitudeControl::get_throttle_out_speed`` runs it (eq.
S.5: the demand acceleration-limited, the error filtered at 10 Hz, FF + P + I, the integrator frozen
while the output is limited, no negative throttle), at 50 Hz, the physics at 200 Hz. The survey: AUTO
from rest at ``start_s`` to WP_SPEED; each lane ends with a slow-down to ``corner_speed`` on the
straight, then a corner at ``corner_rate_deg_s`` for ``corner_s``, then the next lane. Telemetry at
25 Hz carries what the link gives on ArduRover: the throttle output, the speed, the yaw rate, the
mode, and PID_TUNING's speed target (after the acceleration limit) and measured speed.
:class:`SpeedSurveyPort` puts it behind a vehicle port with ArduRover's profile, for a
``LearningSession`` in lockstep.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from companion.interface import SetParameters, StatusText, Telemetry
from companion.link.autopilots.ardurover import PROFILE as ARDUROVER
from companion.link.parameters import ForeignChange
from companion.numerics.speed_gains import ERROR_FILTER_HZ, INTEGRATOR_MAX, SpeedLoopGains
from harness.port_stub import PortStub, StubParameters

PHYSICS_S = 0.005
LOOP_S = 0.02
TELEMETRY_S = 0.04


@dataclass(frozen=True)
class SurgeTruth:
    """The simulated boat's surge (eq. S.4's form) and its sea."""

    gain: float = 2.5  # m/s at full throttle
    exponent: float = 1.0
    gamma: float = 0.35  # 1/m
    lag_s: float = 0.3
    force_sigma: float = 0.01  # along-track disturbance (m/s² RMS), OU with
    force_tau_s: float = 3.0
    speed_noise: float = 0.01  # m/s RMS on the measured speed


@dataclass(frozen=True)
class SurveyShape:
    wp_speed: float = 2.0
    accel_max: float = 1.0  # ATC_ACCEL_MAX, m/s²
    start_s: float = 5.0
    lane_s: float = 45.0  # at the lane's speed, before its slow-down
    slow_s: float = 4.0  # the slow-down before a corner, on the straight
    corner_speed: float = 1.2
    corner_s: float = 9.0
    corner_rate_deg_s: float = 20.0


@dataclass
class SpeedSurvey:
    """The boat and its speed loop flying :class:`SurveyShape`; :meth:`next_telemetry` advances one
    snapshot; :meth:`set_gains` writes speed-loop gains (neutral names), as a PARAM_SET would."""

    gains: SpeedLoopGains
    truth: SurgeTruth = SurgeTruth()
    shape: SurveyShape = SurveyShape()
    seed: int = 1
    mode: str = "auto"
    time_s: float = 0.0
    _u: float = 0.0
    _thrust: float = 0.0
    _force: float = 0.0
    _demand: float = 0.0
    _error: float = 0.0
    _integrator: float = 0.0
    _throttle: float = 0.0
    _measured: float = 0.0
    _yaw: float = 0.0
    _rng: np.random.Generator = field(init=False)
    written: list[tuple[float, dict[str, float]]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)

    def set_gains(self, values: dict[str, float]) -> None:
        merged = {**self.gains.params(), **values}
        self.gains = SpeedLoopGains.from_params(merged)
        self.written.append((self.time_s, dict(values)))

    def phase(self, t: float) -> tuple[float, bool]:
        """(the demand before the acceleration limit, turning) at vehicle time ``t``."""
        s = self.shape
        if t < s.start_s:
            return 0.0, False
        period = s.lane_s + s.slow_s + s.corner_s
        into = (t - s.start_s) % period
        if into < s.lane_s:
            return s.wp_speed, False
        if into < s.lane_s + s.slow_s:
            return s.corner_speed, False
        return s.corner_speed, True

    def _loop(self, target: float) -> None:
        """One 50 Hz pass of ArduRover's speed loop (eq. S.5)."""
        g, s = self.gains, self.shape
        step = s.accel_max * LOOP_S
        self._demand += max(-step, min(step, target - self._demand))
        if self._demand <= 0.0 and target <= 0.0:
            self._throttle, self._integrator, self._error = 0.0, 0.0, 0.0
            return
        alpha = LOOP_S / (LOOP_S + 1.0 / (2.0 * math.pi * ERROR_FILTER_HZ))
        self._error += alpha * ((self._demand - self._measured) - self._error)
        slope = g.cruise_throttle / g.cruise_speed if g.cruise_speed > 0 and g.cruise_throttle > 0 else 0.0
        unlimited = self._demand * slope + g.p * self._error + self._integrator
        out = min(max(unlimited, 0.0), 1.0)
        if out == unlimited:
            self._integrator = min(max(self._integrator + g.i * self._error * LOOP_S, -INTEGRATOR_MAX),
                                   INTEGRATOR_MAX)
        self._throttle = out

    def _physics(self) -> None:
        tr = self.truth
        self._thrust += (self._throttle - self._thrust) * (1.0 - math.exp(-PHYSICS_S / tr.lag_s))
        decay = math.exp(-PHYSICS_S / tr.force_tau_s)
        self._force = decay * self._force + tr.force_sigma * math.sqrt(1.0 - decay * decay) * self._rng.standard_normal()
        steady = tr.gain * max(self._thrust, 0.0) ** tr.exponent
        self._u += PHYSICS_S * (tr.gamma * (steady * steady - self._u * abs(self._u)) + self._force)
        self._u = max(self._u, 0.0)

    def next_telemetry(self, timeout_s: float = 5.0) -> Telemetry:
        end = self.time_s + TELEMETRY_S
        loops = int(round(TELEMETRY_S / LOOP_S))
        for _ in range(loops):
            target, _ = self.phase(self.time_s)
            self._measured = self._u + self.truth.speed_noise * self._rng.standard_normal()
            self._loop(target)
            for _ in range(int(round(LOOP_S / PHYSICS_S))):
                self._physics()
            self.time_s += LOOP_S
        self.time_s = end
        _, turning = self.phase(self.time_s)
        rate = math.radians(self.shape.corner_rate_deg_s) if turning else 0.0
        self._yaw = math.remainder(self._yaw + rate * TELEMETRY_S, 2.0 * math.pi)
        return Telemetry(time_s=self.time_s, yaw=self._yaw, yaw_rate=rate, speed_water=self._measured,
                         thrust_ratio=self._throttle, speed_target=self._demand, speed_achieved=self._measured,
                         mode=self.mode, armed=True)


#: the parameters the port's ArduRover holds at start (native names): the frame's heading gains as
#: shipped and a speed loop whose feed-forward misses (``SpeedSurveyPort``)
ROVER_PARAMS = {"ATC_STR_ANG_P": 2.0, "ATC_STR_RAT_P": 0.2, "ATC_STR_RAT_I": 0.2, "ATC_STR_RAT_D": 0.0,
                "ATC_STR_RAT_FF": 0.75, "ATC_STR_RAT_IMAX": 1.0, "ATC_STR_RAT_MAX": 120.0, "ATC_STR_ACC_MAX": 120.0,
                "MOT_SPD_SCA_BASE": 1.0, "CRUISE_SPEED": 1.5, "CRUISE_THROTTLE": 45.0, "ATC_SPEED_P": 0.1,
                "ATC_SPEED_I": 0.05, "WP_SPEED": 2.0, "ATC_ACCEL_MAX": 1.0, "GCS_PID_MASK": 0.0}


class _Parameters(StubParameters):
    """A parameter channel that tells its listeners of every write, as the link's does (the trail
    records them: ``companion.procedures.trail.TrailRecorder``)."""

    def __init__(self) -> None:
        super().__init__()
        self.listeners: list[Callable[[str, float], None]] = []

    def on_write(self, listener: Callable[[str, float], None]) -> Callable[[], None]:
        self.listeners.append(listener)
        return lambda: self.listeners.remove(listener)


class SpeedSurveyPort(PortStub):
    """A vehicle port onto :class:`SpeedSurvey` with ArduRover's profile, in lockstep: its parameters
    (native names, ``params``) drive the simulated speed loop, ``set_param`` is what a PARAM_SET does,
    ``others_set`` a ground station's own PARAM_SET (seen as someone else's change), and
    ``statustexts`` keeps what the companion said."""

    def __init__(self, survey: SpeedSurvey, params: dict[str, float] | None = None) -> None:
        super().__init__(ARDUROVER)
        self.parameters = _Parameters()
        self.survey = survey
        self.params = dict(ROVER_PARAMS if params is None else params)
        self.mode = survey.mode
        self.texts: list[str] = []
        self._watched: set[str] = set()
        self._apply()

    def _apply(self) -> None:
        p = self.params
        self.survey.gains = SpeedLoopGains(p["CRUISE_SPEED"], p["CRUISE_THROTTLE"] / 100.0, p["ATC_SPEED_P"],
                                           p["ATC_SPEED_I"])

    def next_telemetry(self, timeout_s: float = 5.0) -> Telemetry:
        telemetry = self.survey.next_telemetry()
        self.clock.vehicle_time_s = telemetry.time_s
        self.latest_telemetry = telemetry
        return telemetry

    def execute(self, commands) -> None:
        for command in commands:
            if isinstance(command, SetParameters):
                self.set_params(command.values)
            elif isinstance(command, StatusText):
                self.texts.append(command.text)

    def get_params(self, neutral_names) -> dict[str, float]:
        return {name: self.profile.to_neutral_value(name, self.get_param(self.profile.native_param(name)))
                for name in neutral_names}

    def set_params(self, neutral_values: dict[str, float]) -> dict[str, float]:
        for name, value in neutral_values.items():
            self.set_param(self.profile.native_param(name), self.profile.to_native_value(name, value))
        return dict(neutral_values)

    def get_param(self, name: str) -> float:
        return self.params[name]

    def set_param(self, name: str, value: float) -> float:
        if name not in self.params:
            raise KeyError(name)
        self.params[name] = float(value)
        self._apply()
        for listener in list(self.parameters.listeners):
            listener(name, float(value))
        return float(value)

    def others_set(self, name: str, value: float) -> None:
        """Someone else's PARAM_SET (a ground station's): applied, and seen as their change."""
        before = self.params[name]
        self.set_param(name, value)
        self.parameters.foreign[name] = ForeignChange(name, before, float(value), self.survey.time_s)

    def status_text(self, text: str, severity: int = 6) -> None:
        self.texts.append(text)
