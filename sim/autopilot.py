"""The simulator's autopilot logic, without sockets or clocks (docs/PROTOCOL.md, SPEC C2, SPEC §4).

Modes use ArduSub's numbers: MANUAL (19) actuators straight from RC, ALT_HOLD (2) heading-and-depth
hold with per-channel RC override, GUIDED (4) like ALT_HOLD with RC ignored. Heading PI with the
trim δ0 fed forward; depth PI → desired pitch → pitch PI → elevator (Table 5.1 cascade). RC
overrides are accepted only from ``SYSID_MYGCS`` and expire ``RC_OVR_TIME`` seconds of VEHICLE time
after the last message that set them. DO_SET_SERVO moves only the rolling mass (``MASS_SERVO``);
channels with a function are denied, as in ArduPilot. Disarmed: zero thrust, fins centred.

A skid-steered vessel (twin thrusters, ``Vessel3Dof.skid``) has no rudder: the heading PI's output,
or RC channel 1, is a steering demand s = δ/0.5236 (±1) that ArduRover's skid mix
(``sim.skid_mixer``) turns, with the throttle (set-point or RC channel 3), into left/right motor
demands; a steering stick (RC channel 1) is first shrunk with the throttle as Rover's MANUAL does.

Everything runs on the vehicle clock (``Vehicle.time_s``); the server owns the wall clock.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from enum import IntEnum
from typing import Any, Sequence

from sim.controllers import DepthPitchCascade, HeadingPI
from sim.params import FULL_SCALE_RAD, ParamTable, SetResult
from sim.skid_mixer import pilot_skid_limit, skid_mix
from sim.vehicle import ActuatorDemand, Vehicle
from sim.vehicle import wrap_angle as wrap_pi  # the simulator's one wrap (sim.telemetry imports it from here)

log = logging.getLogger(__name__)

MODE_MANUAL = 19
MODE_ALT_HOLD = 2
MODE_GUIDED = 4
MODE_NAMES = {MODE_MANUAL: "MANUAL", MODE_ALT_HOLD: "ALT_HOLD", MODE_GUIDED: "GUIDED"}

RUDDER_CHANNEL, ELEVATOR_CHANNEL, THRUST_CHANNEL = 1, 2, 3
FUNCTION_CHANNELS = (RUDDER_CHANNEL, ELEVATOR_CHANNEL, THRUST_CHANNEL)
RC_RELEASE = 0
RC_IGNORE = 65535


class Result(IntEnum):
    """Command outcomes, numerically equal to MAVLink's MAV_RESULT (no pymavlink import here)."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4


def fin_from_pwm(pwm: float) -> float:
    """Fin / mass angle (rad) from PWM: (pwm − 1500)/500 · 0.5236 (PROTOCOL.md channels)."""
    return (pwm - 1500.0) / 500.0 * FULL_SCALE_RAD


def thrust_from_pwm(pwm: float) -> float:
    """Thrust ratio from PWM: (pwm − 1000)/1000, clamped to 0…1 (PROTOCOL.md channels)."""
    return min(1.0, max(0.0, (pwm - 1000.0) / 1000.0))


def pwm_from_fin(angle: float) -> int:
    """Inverse of :func:`fin_from_pwm`, rounded to a whole microsecond and clamped to 1000…2000."""
    return int(min(2000.0, max(1000.0, round(1500.0 + angle / FULL_SCALE_RAD * 500.0))))


def pwm_from_thrust(ratio: float) -> int:
    """Inverse of :func:`thrust_from_pwm`."""
    return int(min(2000.0, max(1000.0, round(1000.0 + ratio * 1000.0))))


@dataclass
class _Override:
    pwm: int
    refreshed_s: float  # vehicle time of the last RC_CHANNELS_OVERRIDE that set it


class Autopilot:
    """Modes, arming, set-points, RC override and the holding controllers over one :class:`Vehicle`."""

    def __init__(self, vehicle: Vehicle, params: ParamTable) -> None:
        self.vehicle = vehicle
        self.params = params
        self.mode = MODE_MANUAL
        self.armed = False
        self.heading_setpoint = 0.0
        self.depth_setpoint = 0.0
        self.thrust_setpoint = params["CRUISE_THR"]
        self.mass_angle_demand = 0.0
        self._overrides: dict[int, _Override] = {}
        self.heading_pi = HeadingPI(
            kp=params["HDG_P"], ki=params["HDG_I"], imax=params["HDG_IMAX"], trim=params["HDG_TRIM"]
        )
        self.depth_pitch = DepthPitchCascade(
            depth_kp=params["DPT_P"],
            depth_ki=params["DPT_I"],
            pitch_kp=params["PIT_P"],
            pitch_ki=params["PIT_I"],
            pitch_max=params["PIT_MAX"],
            elevator_max=params["ELEV_MAX"],
        )
        self.demand = ActuatorDemand(rudder=0.0, elevator=0.0, thrust_ratio=0.0, mass_angle=0.0)
        self.skid = bool(getattr(vehicle, "skid", False))  # twin thrusters: steering is mixed, not a rudder
        for name in params:
            self._apply(name)

    # ------------------------------------------------------------------ clock
    @property
    def time_s(self) -> float:
        return self.vehicle.time_s

    @property
    def mode_name(self) -> str:
        return MODE_NAMES.get(self.mode, str(self.mode))

    # ------------------------------------------------------------------ commands
    def set_mode(self, custom_mode: int) -> Result:
        """Switch mode; entering ALT_HOLD/GUIDED captures heading and depth, thrust = CRUISE_THR."""
        if custom_mode not in MODE_NAMES:
            return Result.FAILED
        if custom_mode != self.mode:
            if custom_mode in (MODE_ALT_HOLD, MODE_GUIDED):
                state = self.vehicle.state
                self.heading_setpoint = wrap_pi(state.yaw)
                self.depth_setpoint = state.depth
                self.thrust_setpoint = self.params["CRUISE_THR"]
                self.heading_pi.reset()
                # bumpless entry, as a real autopilot's depth hold does (ArduSub ALT_HOLD captures the
                # current state): the desired pitch starts at the current pitch and the elevator where
                # it is, so entering the mode in trimmed flight causes no depth transient (before,
                # a reset integrator made the vehicle pitch to 0 and climb for ~60 s on every entry)
                self.depth_pitch.initialize(state.pitch, self.vehicle.elevator)
            log.info("mode %s -> %s at t=%.2f", self.mode_name, MODE_NAMES[custom_mode], self.time_s)
            self.mode = custom_mode
        return Result.ACCEPTED

    def arm(self, armed: bool) -> Result:
        if armed != self.armed:
            log.info("%s at t=%.2f", "armed" if armed else "disarmed", self.time_s)
            self.heading_pi.reset()
            self.depth_pitch.reset()
        self.armed = armed
        return Result.ACCEPTED

    def _holding(self) -> bool:
        return self.mode in (MODE_ALT_HOLD, MODE_GUIDED)

    def set_heading(self, heading: float, relative: bool = False) -> Result:
        """Heading set-point (rad); refused outside the holding modes (PROTOCOL.md Commands)."""
        if not self._holding():
            return Result.TEMPORARILY_REJECTED
        if not math.isfinite(heading):
            return Result.DENIED
        self.heading_setpoint = wrap_pi(self.heading_setpoint + heading if relative else heading)
        return Result.ACCEPTED

    def set_depth(self, depth: float) -> Result:
        if not self._holding():
            return Result.TEMPORARILY_REJECTED
        if not math.isfinite(depth) or depth < 0.0:
            return Result.DENIED
        self.depth_setpoint = depth
        return Result.ACCEPTED

    def set_thrust(self, ratio: float) -> Result:
        if not self._holding():
            return Result.TEMPORARILY_REJECTED
        if not math.isfinite(ratio) or not 0.0 <= ratio <= 1.0:
            return Result.DENIED
        self.thrust_setpoint = ratio
        return Result.ACCEPTED

    def set_servo(self, output: int, pwm: float) -> Result:
        """DO_SET_SERVO: the rolling mass on MASS_SERVO; outputs with a function are denied."""
        if output in FUNCTION_CHANNELS or not 1 <= output <= 16 or not math.isfinite(pwm):
            return Result.DENIED
        if output == int(self.params["MASS_SERVO"]):
            limit = self.params["MASS_MAX"]
            self.mass_angle_demand = min(limit, max(-limit, fin_from_pwm(pwm)))
        return Result.ACCEPTED  # spare outputs without a function: accepted, nothing attached

    def rc_override(self, source_system: int, channels: Sequence[int]) -> bool:
        """RC_CHANNELS_OVERRIDE (channels 1…n as PWM); False if the sender is not SYSID_MYGCS.

        0 releases a channel, 65535 leaves it as it is (MAVLink RC_CHANNELS_OVERRIDE).
        """
        if source_system != int(self.params["SYSID_MYGCS"]):
            return False
        now = self.time_s
        for channel in FUNCTION_CHANNELS:
            if channel > len(channels):
                continue
            pwm = channels[channel - 1]
            if pwm == RC_IGNORE:
                continue
            if pwm == RC_RELEASE:
                if self._overrides.pop(channel, None) is not None:
                    self._on_release(channel)
            elif 800 <= pwm <= 2200:
                self._overrides[channel] = _Override(int(pwm), now)
        return True

    def overridden(self, channel: int) -> bool:
        return channel in self._overrides

    def _on_release(self, channel: int) -> None:
        """The autopilot takes the channel back: restart its loop without a stale integrator."""
        log.info("RC channel %d released at t=%.2f", channel, self.time_s)
        if channel == RUDDER_CHANNEL:
            self.heading_pi.reset()
        elif channel == ELEVATOR_CHANNEL:
            self.depth_pitch.reset()

    def _expire_overrides(self) -> None:
        timeout = self.params["RC_OVR_TIME"]
        if timeout < 0.0 or not self._overrides:
            return
        now = self.time_s
        for channel in [c for c, o in self._overrides.items() if now - o.refreshed_s > timeout]:
            del self._overrides[channel]
            log.info("RC override of channel %d expired", channel)
            self._on_release(channel)

    # ------------------------------------------------------------------ parameters
    def set_param(self, name: str, value: float) -> SetResult:
        """Validate, store and apply a parameter live (gains, limits, current, roll kick)."""
        result = self.params.set(name, value)
        if result.accepted:
            self._apply(name)
        return result

    def _apply(self, name: str) -> None:
        p = self.params
        value = p[name]
        if name == "HDG_P":
            self.heading_pi.kp = value
        elif name == "HDG_I":
            self.heading_pi.ki = value
        elif name == "HDG_IMAX":
            self.heading_pi.imax = value
        elif name == "HDG_TRIM":
            self.heading_pi.trim = value
        elif name == "DPT_P":
            self.depth_pitch.depth_kp = value
        elif name == "DPT_I":
            self.depth_pitch.depth_ki = value
        elif name == "PIT_P":
            self.depth_pitch.pitch_kp = value
        elif name == "PIT_I":
            self.depth_pitch.pitch_ki = value
        elif name == "PIT_MAX":
            self.depth_pitch.pitch_max = value
        elif name in ("RUD_MAX", "RUD_RATE", "ELEV_MAX", "ELEV_RATE", "MASS_MAX"):
            self._apply_limits()
        elif name in ("SIM_CUR_VN", "SIM_CUR_VE"):
            self.vehicle.set_current(p["SIM_CUR_VN"], p["SIM_CUR_VE"])
        elif name == "SIM_ROLL_KICK":
            if value != 0.0:
                self.vehicle.kick_roll(math.radians(value))
                p.force(name, 0.0)  # one shot: the echo carries the written value, reads give 0
        elif name == "SIM_ROLL_DIST":
            self.vehicle.roll_disturbance_amplitude = value

    def _apply_limits(self) -> None:
        p = self.params
        limits = self.vehicle.limits
        limits.rudder_max = p["RUD_MAX"]
        limits.rudder_rate = p["RUD_RATE"]
        limits.elevator_max = p["ELEV_MAX"]
        limits.elevator_rate = p["ELEV_RATE"]
        limits.mass_max = p["MASS_MAX"]
        self.depth_pitch.elevator_max = p["ELEV_MAX"]
        self.heading_pi.output_max = p["RUD_MAX"]  # the PI's anti-windup needs the real limit
        self.mass_angle_demand = min(p["MASS_MAX"], max(-p["MASS_MAX"], self.mass_angle_demand))

    # ------------------------------------------------------------------ the loop
    def _compute_demand(self, dt: float) -> ActuatorDemand:
        mass = self.mass_angle_demand
        if not self.armed:
            return ActuatorDemand(rudder=0.0, elevator=0.0, thrust_ratio=0.0, mass_angle=mass)
        overrides = self._overrides
        if self.mode == MODE_MANUAL:
            rud = overrides.get(RUDDER_CHANNEL)
            elev = overrides.get(ELEVATOR_CHANNEL)
            thr = overrides.get(THRUST_CHANNEL)
            return ActuatorDemand(
                rudder=fin_from_pwm(rud.pwm) if rud else 0.0,
                elevator=fin_from_pwm(elev.pwm) if elev else 0.0,
                thrust_ratio=thrust_from_pwm(thr.pwm) if thr else 0.0,
                mass_angle=mass,
            )
        honour_rc = self.mode == MODE_ALT_HOLD
        vehicle = self.vehicle  # true state attributes: cheaper than building a VehicleState
        rud = overrides.get(RUDDER_CHANNEL) if honour_rc else None
        if rud is not None:
            rudder = fin_from_pwm(rud.pwm)
        else:
            rudder = self.heading_pi.update(dt, self.heading_setpoint, vehicle.yaw)
        elev = overrides.get(ELEVATOR_CHANNEL) if honour_rc else None
        if elev is not None:
            elevator = fin_from_pwm(elev.pwm)
        else:
            elevator = self.depth_pitch.update(
                dt, self.depth_setpoint, vehicle.depth, vehicle.pitch
            )
        thr = overrides.get(THRUST_CHANNEL) if honour_rc else None
        thrust = thrust_from_pwm(thr.pwm) if thr is not None else self.thrust_setpoint
        return ActuatorDemand(rudder=rudder, elevator=elevator, thrust_ratio=thrust, mass_angle=mass)

    def _steering_from_rc(self) -> bool:
        """Whether the steering demand comes from a pilot's stick (RC channel 1) this step."""
        return self.armed and (self.mode == MODE_MANUAL
                               or (self.mode == MODE_ALT_HOLD and RUDDER_CHANNEL in self._overrides))

    def _skid_demand(self, demand: ActuatorDemand) -> ActuatorDemand:
        """Steering (the rudder demand / 0.5236, ±1) and throttle mixed to motor demands as ArduRover
        does (``sim.skid_mixer``); disarmed, both motors stop (ArduPilot outputs the 1500 µs trim)."""
        if not self.armed:
            return replace(demand, motor_left=0.0, motor_right=0.0)
        steering = max(-1.0, min(1.0, demand.rudder / FULL_SCALE_RAD))
        throttle = demand.thrust_ratio
        if self._steering_from_rc():
            steering, throttle = pilot_skid_limit(steering, throttle)
        left, right = skid_mix(steering, throttle)
        return replace(demand, rudder=steering * FULL_SCALE_RAD, thrust_ratio=throttle, motor_left=left,
                       motor_right=right)

    def step(self, dt: float) -> None:
        """Advance autopilot and vehicle by ``dt`` seconds of vehicle time."""
        self._expire_overrides()
        self.demand = self._compute_demand(dt)
        if self.skid:
            self.demand = self._skid_demand(self.demand)
        self.vehicle.step(dt, self.demand)

    def status(self) -> dict[str, Any]:
        """A summary for logs and tests."""
        return {
            "time_s": self.time_s,
            "mode": self.mode_name,
            "armed": self.armed,
            "heading_setpoint": self.heading_setpoint,
            "depth_setpoint": self.depth_setpoint,
            "thrust_setpoint": self.thrust_setpoint,
            "overrides": {c: o.pwm for c, o in self._overrides.items()},
        }
