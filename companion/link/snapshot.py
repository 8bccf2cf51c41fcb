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
from collections import deque
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
    """Latest values of every telemetry field; snapshots completed on ATTITUDE (module docstring).

    **Pairing by time stamp.** Each attitude sample is paired with the actuator sample of the same
    instant, found by SERVO_OUTPUT_RAW's own ``time_usec``, not by arrival order: over a link that
    delays and reorders (UDP, a radio) the outputs of the next or the previous sample can arrive
    first, and pairing by arrival put the rudder up to a sample period off its attitude. The match
    is the earliest output sample stamped within [t − 1 ms, t + ``match_ms``]: our simulator stamps a
    tick's outputs with the tick's time (sent just before its ATTITUDE); ArduPilot sends each loop's
    outputs just after that loop's ATTITUDE, stamped a few ms later.
    A snapshot whose outputs have not arrived waits (in order, behind nothing newer) until they do,
    or until an attitude ``reorder_window`` samples newer arrives; it is then released with the
    outputs last held at or before its time (a lost output message).

    **Order.** Snapshots are returned in time order. An attitude sample that arrives after a newer
    one is placed in order if no newer snapshot was returned yet; on a link that has delivered a
    sample late, complete snapshots are held ``hold_ms`` (set by the telemetry feed) so late ones
    still find their place. A link that delivers in order is never held."""

    profile: AutopilotProfile
    depth_sensor: DepthSensor = field(default_factory=DepthSensor)
    _fields: dict[str, Any] = field(default_factory=dict)
    _have_pressure: bool = False
    servo_pwm: list[float] = field(default_factory=list)  # latest SERVO_OUTPUT_RAW, µs, outputs 1..16
    _warned: set[str] = field(default_factory=set)
    latest: Telemetry | None = None
    reorder_window: int = 2  # attitude samples a snapshot may wait for its outputs
    # snapshots not yet returned, oldest first, each with whether its outputs are known
    _pending: list[list] = field(default_factory=list)
    _outputs: deque = field(default_factory=lambda: deque(maxlen=64))  # (time_ms, actuator fields)
    _period_ms: float = 50.0  # between the latest two attitude samples
    _last_attitude_ms: float = math.nan
    released_without_outputs: int = 0  # snapshots whose output message never came (lost)
    released_ms: float = -math.inf  # time of the newest snapshot returned
    # how long a complete snapshot is held before it is returned (ms of vehicle time): 0 on a link
    # that delivers in order; the telemetry feed raises it once the link has delivered a sample late
    hold_ms: float = 0.0
    # wait for a snapshot's own outputs (False in lockstep with our simulator: it sends a tick's outputs
    # before its attitude over an ordered link, so outputs not there with their attitude were lost)
    wait_for_outputs: bool = True

    def __post_init__(self) -> None:
        self._handlers: dict[str, Callable[[Any], list[Telemetry] | None]] = {
            "ATTITUDE": self._on_attitude,
            "SERVO_OUTPUT_RAW": self._on_servo_output_raw,
            "LOCAL_POSITION_NED": self._on_local_position_ned,
            "VFR_HUD": self._on_vfr_hud,
            "SCALED_PRESSURE": self._on_scaled_pressure,
            "GLOBAL_POSITION_INT": self._on_global_position_int,
            "NAV_CONTROLLER_OUTPUT": self._on_nav_controller_output,
            "PID_TUNING": self._on_pid_tuning,
            "HEARTBEAT": self._on_heartbeat,
        }

    @property
    def message_types(self) -> frozenset[str]:
        return frozenset(self._handlers)

    def take(self, msg: Any) -> list[Telemetry]:
        """Fold one message in; returns the snapshots it completed, oldest first."""
        handler = self._handlers.get(msg.get_type())
        return (handler(msg) or []) if handler else []

    def on_message(self, msg: Any) -> Telemetry | None:
        """Fold one message in; the newest snapshot it completed (None if none)."""
        done = self.take(msg)
        return done[-1] if done else None

    # ------------------------------------------------------------------ attitude and outputs
    @property
    def match_ms(self) -> float:
        """How far after an attitude sample its outputs may be stamped (half a sample period)."""
        return 0.5 * self._period_ms

    def restart(self) -> None:
        """The vehicle rebooted: its clock starts again, so nothing stamped before carries over."""
        self._pending.clear()
        self._outputs.clear()
        self._last_attitude_ms = math.nan
        self.released_ms = -math.inf

    def accepts(self, time_ms: float) -> bool:
        """An attitude sample stamped ``time_ms`` can still be placed in order: it is newer than every
        snapshot already returned and not a duplicate of one waiting."""
        if time_ms <= self.released_ms:
            return False
        return all(round(entry[0].time_s * 1000.0) != round(time_ms) for entry in self._pending)

    def _on_attitude(self, msg: Any) -> list[Telemetry]:
        time_ms = self._number(msg, "time_boot_ms")
        if not math.isfinite(time_ms) or not self.accepts(time_ms):
            return []  # without a time stamp a snapshot is useless to vehicle-time logic; too late to place
        late = math.isfinite(self._last_attitude_ms) and time_ms < self._last_attitude_ms
        yaw = self._number(msg, "yaw")
        attitude = dict(roll=self._number(msg, "roll"), pitch=self._number(msg, "pitch"),
                        yaw=wrap_pi(yaw) if math.isfinite(yaw) else math.nan,
                        roll_rate=self._number(msg, "rollspeed"), pitch_rate=self._number(msg, "pitchspeed"),
                        yaw_rate=self._number(msg, "yawspeed"))
        if not late:
            if math.isfinite(self._last_attitude_ms):
                self._period_ms = min(max(time_ms - self._last_attitude_ms, 1.0), 1000.0)
            self._last_attitude_ms = time_ms
            self._fields.update(attitude)
        snapshot = Telemetry(time_s=time_ms / 1000.0, **{**self._fields, **attitude})
        outputs = self._outputs_for(time_ms)
        if outputs is not None:
            snapshot = replace(snapshot, **outputs)
        elif not (self.wait_for_outputs and self._outputs_streaming(time_ms)):
            outputs = self._held_at(time_ms)  # no output stream to wait for: the outputs last held
        if not late:
            self.latest = snapshot
        if outputs is not None and not self._pending and self.hold_ms <= 0.0:
            self.released_ms = time_ms
            return [snapshot]
        position = sum(1 for entry in self._pending if entry[0].time_s * 1000.0 < time_ms)
        self._pending.insert(position, [snapshot, outputs is not None])
        return self._release(self._last_attitude_ms)

    def _on_servo_output_raw(self, msg: Any) -> list[Telemetry]:
        actuators = self._fold_servo_outputs(msg)
        time_usec = self._number(msg, "time_usec")
        reference = self._last_attitude_ms if math.isfinite(self._last_attitude_ms) else time_usec / 1000.0
        time_ms = _unwrap_usec_ms(time_usec, reference)
        if not math.isfinite(time_ms):
            return []
        self._outputs.append((time_ms, actuators))
        for entry in self._pending:
            stamp = entry[0].time_s * 1000.0
            if not entry[1] and stamp - 1.0 <= time_ms <= stamp + self.match_ms:
                entry[0], entry[1] = replace(entry[0], **actuators), True
        return self._release(self._last_attitude_ms)

    def _outputs_streaming(self, time_ms: float) -> bool:
        """Output samples arrive with every attitude sample: the recent ones came a median of one
        attitude period apart (within 50 %) and the newest is within a few periods of ``time_ms``. Otherwise (no
        output stream, or a slower one) a snapshot never waits: it takes the outputs last held."""
        stamps = sorted(stamp for stamp, _ in list(self._outputs)[-6:])
        spacings = sorted(b - a for a, b in zip(stamps, stamps[1:]))
        if not spacings:
            return False
        median = spacings[len(spacings) // 2]  # one lost or reordered output does not stop the stream
        return 0.0 < median <= 1.5 * self._period_ms and stamps[-1] >= time_ms - 5.0 * self._period_ms

    def _outputs_for(self, time_ms: float) -> dict | None:
        """The actuator fields of the earliest output sample stamped within the match window of ``time_ms``."""
        matches = [(stamp, fields) for stamp, fields in self._outputs
                   if time_ms - 1.0 <= stamp <= time_ms + self.match_ms]
        return min(matches, key=lambda item: item[0])[1] if matches else None

    def _held_at(self, time_ms: float) -> dict:
        """The outputs last held at or before ``time_ms`` (a snapshot whose own outputs were lost)."""
        before = [(stamp, fields) for stamp, fields in self._outputs if stamp <= time_ms + 1.0]
        return max(before, key=lambda item: item[0])[1] if before else {}

    def _release(self, newest_ms: float) -> list[Telemetry]:
        """The oldest pending snapshots that are complete, or too old to wait any longer, in order."""
        out: list[Telemetry] = []
        while self._pending:
            snapshot, complete = self._pending[0]
            stamp = snapshot.time_s * 1000.0
            age = newest_ms - stamp if math.isfinite(newest_ms) else 0.0
            if not complete:
                if age < self.reorder_window * self._period_ms - 1.0:
                    break
                snapshot = replace(snapshot, **self._held_at(stamp))
                self.released_without_outputs += 1
            elif age < self.hold_ms - 1.0:
                break  # held a little, so a sample the link delivers late can still take its place
            self._pending.pop(0)
            self.released_ms = stamp
            out.append(snapshot)
        return out

    def _fold_servo_outputs(self, msg: Any) -> dict[str, float]:
        """The actuator fields one SERVO_OUTPUT_RAW reports (through the profile), also kept as the
        latest values; ``servo_pwm`` holds its raw outputs."""
        self.servo_pwm = [self._number(msg, f"servo{i}_raw") if hasattr(msg, f"servo{i}_raw") else math.nan
                          for i in range(1, 17)]
        actuators: dict[str, float] = {}
        outputs = self.profile.servo_outputs
        actuation = self.profile.actuation
        if actuation is not None:  # read from the vehicle: steering and throttle (un-mixed for a pair),
            steering, throttle = actuation.demands(self.servo_pwm)  # paired with their attitude like any output
            actuators["rudder"] = steering * self.profile.angle_full_scale_rad
            actuators["thrust_ratio"] = throttle
        for actuator, telemetry_field in (("rudder", "rudder"), ("elevator", "elevator"), ("thrust", "thrust_ratio")):
            output = outputs.get(actuator)
            if output is None or (actuation is not None and actuator != "elevator"):
                continue
            pwm = self._number(msg, f"servo{output}_raw")
            actuators[telemetry_field] = (
                self.profile.pwm_to_thrust(pwm) if actuator == "thrust" else self.profile.pwm_to_angle(pwm))
        if self.profile.mass_servo is not None:
            pwm = self._number(msg, f"servo{self.profile.mass_servo}_raw")
            actuators["mass_angle"] = self.profile.pwm_to_angle(pwm)
        self._fields.update(actuators)
        return actuators

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
        """The autopilot's own (surface-calibrated) altitude: depth where pressure is not used. A
        surface vessel has no depth (its GPS altitude is not one)."""
        if not self.profile.depth_from_pressure and self.profile.vehicle_kind != "surface":
            relative_alt = self._number(msg, "relative_alt")
            self._fields["depth"] = -relative_alt / 1000.0 if math.isfinite(relative_alt) else math.nan

    def _on_nav_controller_output(self, msg: Any) -> None:
        """The heading set-point the autopilot reports holding (whole degrees), where its profile
        says that is what ``target_bearing`` means."""
        if self.profile.reports_heading_target:
            bearing = self._number(msg, "target_bearing")
            self._fields["heading_target"] = wrap_pi(math.radians(bearing)) if math.isfinite(bearing) else math.nan
        self._fields["cross_track"] = self._number(msg, "xtrack_error")

    def _on_pid_tuning(self, msg: Any) -> None:
        """The heading rate loop's asked-for and measured turn rates: the PID_TUNING axis and units
        the profile names (ArduRover: STEER, deg/s; ArduSub: YAW, its target in rad/s × 0.01)."""
        speed = self.profile.speed_loop_report
        if speed is not None and self._number(msg, "axis") == speed.axis:  # the speed loop's, in m/s
            self._fields["speed_target"] = self._number(msg, "desired")
            self._fields["speed_achieved"] = self._number(msg, "achieved")
            return
        report = self.profile.pid_tuning
        if report is None or self._number(msg, "axis") != report.axis:
            return
        desired, achieved = self._number(msg, "desired"), self._number(msg, "achieved")
        self._fields["turn_rate_target"] = desired * report.desired_to_rad_s if math.isfinite(desired) else math.nan
        self._fields["turn_rate_achieved"] = achieved * report.achieved_to_rad_s if math.isfinite(achieved) else math.nan

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
            number = float(value) if value is not None else math.nan
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
