"""Telemetry snapshot assembly from MAVLink messages (SPEC C1; docs/PROTOCOL.md "Telemetry").

:class:`TelemetryAssembler` keeps the latest value of every field and, on each ATTITUDE, returns a
:class:`companion.interface.Telemetry` stamped with that ATTITUDE's ``time_boot_ms``. No I/O and no
clock: it is fed messages (live, or from a recorded log) and is unit-tested with fabricated ones.

Field sources: ATTITUDE → attitude, rates, time; SERVO_OUTPUT_RAW → actual actuator positions
(profile conversions; a boat's steering and throttle through the actuation read from the vehicle,
un-mixed for a skid-steered pair, eq. S.1); LOCAL_POSITION_NED → north/east/down, NED velocities; VFR_HUD → water speed
(airspeed) and ground speed; SCALED_PRESSURE → depth (LOCAL_POSITION_NED.z until a pressure
arrives); HEARTBEAT → mode (neutral name) and armed. Non-finite or non-numeric fields become NaN
and are logged once per field, never raised.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable

from companion.interface import Telemetry
from companion.link.profile import AutopilotProfile
from companion.numerics.angles import wrap_pi

log = logging.getLogger(__name__)

#: MAV_MODE_FLAG_SAFETY_ARMED
SAFETY_ARMED = 128
STANDARD_GRAVITY = 9.80665
SEA_LEVEL_PRESSURE_HPA = 1013.25


@dataclass(frozen=True)
class DepthSensor:
    """Pressure → depth: ``depth = (press_abs − surface_hpa)·100 / (ρ·g)`` (PROTOCOL.md)."""

    water_density: float = 1000.0  # kg/m³ (fresh water; 1025 for sea water)
    surface_pressure_hpa: float = SEA_LEVEL_PRESSURE_HPA

    def depth(self, press_abs_hpa: float) -> float:
        return (press_abs_hpa - self.surface_pressure_hpa) * 100.0 / (self.water_density * STANDARD_GRAVITY)


@dataclass
class TelemetryAssembler:
    """Latest values of every telemetry field; :meth:`on_message` returns a snapshot on ATTITUDE."""

    profile: AutopilotProfile
    depth_sensor: DepthSensor = field(default_factory=DepthSensor)
    _fields: dict[str, Any] = field(default_factory=dict)
    _have_pressure: bool = False
    servo_pwm: list[float] = field(default_factory=list)  # latest SERVO_OUTPUT_RAW, µs, outputs 1..16
    _warned: set[str] = field(default_factory=set)
    latest: Telemetry | None = None
    _held: Telemetry | None = None  # a snapshot waiting for its loop's SERVO_OUTPUT_RAW

    def __post_init__(self) -> None:
        self._handlers: dict[str, Callable[[Any], Telemetry | None]] = {
            "ATTITUDE": self._on_attitude,
            "SERVO_OUTPUT_RAW": self._on_servo_output_raw,
            "LOCAL_POSITION_NED": self._on_local_position_ned,
            "VFR_HUD": self._on_vfr_hud,
            "SCALED_PRESSURE": self._on_scaled_pressure,
            "GLOBAL_POSITION_INT": self._on_global_position_int,
            "HEARTBEAT": self._on_heartbeat,
        }

    @property
    def message_types(self) -> frozenset[str]:
        return frozenset(self._handlers)

    def on_message(self, msg: Any) -> Telemetry | None:
        """Fold one message in; returns the completed snapshot when ``msg`` is an ATTITUDE."""
        handler = self._handlers.get(msg.get_type())
        return handler(msg) if handler else None

    # ------------------------------------------------------------------ handlers
    def _on_attitude(self, msg: Any) -> Telemetry | None:
        time_ms = self._number(msg, "time_boot_ms")
        if not math.isfinite(time_ms):
            return None  # a snapshot without a time stamp is useless to vehicle-time logic
        yaw = self._number(msg, "yaw")
        self._fields.update(
            roll=self._number(msg, "roll"), pitch=self._number(msg, "pitch"),
            yaw=wrap_pi(yaw) if math.isfinite(yaw) else math.nan,
            roll_rate=self._number(msg, "rollspeed"), pitch_rate=self._number(msg, "pitchspeed"),
            yaw_rate=self._number(msg, "yawspeed"))
        self.latest = Telemetry(time_s=time_ms / 1000.0, **self._fields)
        if not self.profile.servo_follows_attitude:
            return self.latest
        # ArduPilot: this loop's actuator outputs follow in SERVO_OUTPUT_RAW; a snapshot whose
        # servo message never came is released by the next ATTITUDE, with the last outputs known
        released, self._held = self._held, self.latest
        return released

    def _on_servo_output_raw(self, msg: Any) -> Telemetry | None:
        self._fold_servo_outputs(msg)
        held = self._held
        if held is None:
            return None
        time_ms = _unwrap_usec_ms(self._number(msg, "time_usec"), held.time_s * 1000.0)
        if not (math.isfinite(time_ms) and time_ms >= held.time_s * 1000.0 - 1.0):
            return None  # an older loop's outputs
        self._held = None
        actuators = {name: self._fields[name] for name in ("rudder", "elevator", "thrust_ratio", "mass_angle")
                     if name in self._fields}
        self.latest = replace(held, **actuators)
        return self.latest

    def _fold_servo_outputs(self, msg: Any) -> None:
        self.servo_pwm = [self._number(msg, f"servo{i}_raw") if hasattr(msg, f"servo{i}_raw") else math.nan
                          for i in range(1, 17)]
        outputs = self.profile.servo_outputs
        actuation = self.profile.actuation
        if actuation is not None:  # read from the vehicle: steering and throttle (un-mixed for a pair)
            steering, throttle = actuation.demands(self.servo_pwm)
            self._fields["rudder"] = steering * self.profile.angle_full_scale_rad
            self._fields["thrust_ratio"] = throttle
        for actuator, telemetry_field in (("rudder", "rudder"), ("elevator", "elevator"), ("thrust", "thrust_ratio")):
            output = outputs.get(actuator)
            if output is None or (actuation is not None and actuator != "elevator"):
                continue
            pwm = self._number(msg, f"servo{output}_raw")
            self._fields[telemetry_field] = (
                self.profile.pwm_to_thrust(pwm) if actuator == "thrust" else self.profile.pwm_to_angle(pwm))
        if self.profile.mass_servo is not None:
            pwm = self._number(msg, f"servo{self.profile.mass_servo}_raw")
            self._fields["mass_angle"] = self.profile.pwm_to_angle(pwm)

    def _on_local_position_ned(self, msg: Any) -> None:
        down = self._number(msg, "z")
        self._fields.update(
            north=self._number(msg, "x"), east=self._number(msg, "y"), down=down,
            vel_north=self._number(msg, "vx"), vel_east=self._number(msg, "vy"), vel_down=self._number(msg, "vz"))
        if not self._have_pressure and self.profile.depth_from_pressure:
            self._fields["depth"] = down

    def _on_vfr_hud(self, msg: Any) -> None:
        ground = self._number(msg, "groundspeed")
        # without a water-speed sensor (ArduPilot boats and subs) the ground speed stands in
        water = self._number(msg, "airspeed") if self.profile.water_speed_sensor else ground
        self._fields.update(speed_water=water, speed_ground=ground)

    def _on_global_position_int(self, msg: Any) -> None:
        """The autopilot's own (surface-calibrated) altitude: depth where pressure is not used."""
        if not self.profile.depth_from_pressure:
            relative_alt = self._number(msg, "relative_alt")
            self._fields["depth"] = -relative_alt / 1000.0 if math.isfinite(relative_alt) else math.nan

    def _on_scaled_pressure(self, msg: Any) -> None:
        if not self.profile.depth_from_pressure:
            return  # raw pressure against 1013.25 hPa is wrong at any elevation (SPEC §4)
        press_abs = self._number(msg, "press_abs")
        self._have_pressure = True
        self._fields["depth"] = self.depth_sensor.depth(press_abs) if math.isfinite(press_abs) else math.nan

    def _on_heartbeat(self, msg: Any) -> None:
        custom_mode = self._number(msg, "custom_mode")
        base_mode = self._number(msg, "base_mode")
        self._fields["mode"] = self.profile.mode_name(int(custom_mode)) if math.isfinite(custom_mode) else ""
        self._fields["armed"] = bool(int(base_mode) & SAFETY_ARMED) if math.isfinite(base_mode) else False

    # ------------------------------------------------------------------ helpers
    def _number(self, msg: Any, name: str) -> float:
        """``msg.name`` as a finite float, else NaN (logged once per message field)."""
        value = getattr(msg, name, None)
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        if not math.isfinite(number):
            key = f"{msg.get_type()}.{name}"
            if key not in self._warned:
                self._warned.add(key)
                log.warning("telemetry field %s is not a finite number (%r): NaN in snapshots", key, value)
            return math.nan
        return number


#: SERVO_OUTPUT_RAW.time_usec is a uint32 of microseconds: it wraps every 2**32 µs (71.6 minutes)
USEC_WRAP_MS = 2 ** 32 / 1000.0


def _unwrap_usec_ms(time_usec: float, reference_ms: float) -> float:
    """A wrapped uint32 ``time_usec`` as milliseconds of boot time, the lap nearest ``reference_ms``
    (the attitude it is paired with: ``time_boot_ms`` is a uint32 of milliseconds and wraps only
    after 49 days). Without it, after 71.6 minutes of autopilot uptime every output message looked
    older than its attitude and was never paired (found by the fault bench's long runs)."""
    if not (math.isfinite(time_usec) and math.isfinite(reference_ms)):
        return math.nan
    time_ms = time_usec / 1000.0
    return time_ms + round((reference_ms - time_ms) / USEC_WRAP_MS) * USEC_WRAP_MS
