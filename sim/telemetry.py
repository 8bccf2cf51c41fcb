"""The MAVLink messages the simulated autopilot sends, built from the vehicle's state at one tick
(docs/PROTOCOL.md, "Telemetry"). When they are sent is :mod:`sim.streams`'s; how they reach the
clients is :mod:`sim.routing`'s.

Position is reported about a fixed local origin; depth also as SCALED_PRESSURE over a fixed water
density, so that a client can invert it. SERVO_OUTPUT_RAW carries the actuators as an ArduPilot
vehicle does (rudder or left motor on output 1, elevator on 2, thrust or right motor on 3, the
moving mass on MASS_SERVO).
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim.autopilot import Autopilot, pwm_from_fin, pwm_from_thrust, wrap_pi
from sim.params import ParamTable
from sim.skid_mixer import pwm_from_motor
from sim.vehicle import Measurements, Vehicle

GRAVITY = 9.80665
PRESSURE_RHO = 1000.0  # kg/m³, fixed so a client can invert SCALED_PRESSURE (PROTOCOL.md)
SEA_LEVEL_HPA = 1013.25
ORIGIN_LAT_DEG, ORIGIN_LON_DEG = 63.4400, 10.3900  # fixed local origin (Trondheimsfjord)
EARTH_RADIUS_M = 6378137.0

CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
)


def heartbeat(autopilot: Autopilot) -> mavlink.MAVLink_message:
    """The autopilot's HEARTBEAT: a submarine flown by ArduPilot, in its custom mode, armed or not."""
    base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if autopilot.armed:
        base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    state = mavlink.MAV_STATE_ACTIVE if autopilot.armed else mavlink.MAV_STATE_STANDBY
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_SUBMARINE, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode, autopilot.mode,
        state, 3,
    )


def autopilot_version(system_id: int) -> mavlink.MAVLink_message:
    """AUTOPILOT_VERSION: 0.1.0 official, with the capabilities the endpoint has (CAPABILITIES)."""
    version = (0 << 24) | (1 << 16) | (0 << 8) | 255  # 0.1.0 official
    return mavlink.MAVLink_autopilot_version_message(
        CAPABILITIES, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
        0x51AB_0000 + system_id,
    )


class TelemetryEncoder:
    """Builds the streamed messages (and AUTOPILOT_VERSION) from one vehicle's state; the vehicle is
    measured once per tick, so the messages of one tick carry one sample."""

    def __init__(self, vehicle: Vehicle, params: ParamTable) -> None:
        self.vehicle = vehicle
        self.params = params
        self._measure: Measurements | None = None
        self._measure_tick = -1

    def _measurements(self, tick: int) -> Measurements:
        measured = self._measure
        if measured is None or self._measure_tick != tick:
            measured = self._measure = self.vehicle.measure()
            self._measure_tick = tick
        return measured

    def build(self, msg_id: int, tick: int, time_boot_ms: int,
              autopilot: Autopilot) -> mavlink.MAVLink_message | None:
        """Build one message of the streamed set at ``tick`` (PROTOCOL.md Telemetry); None for
        another message."""
        ms = time_boot_ms
        if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE:
            m = self._measurements(tick)
            return mavlink.MAVLink_attitude_message(
                ms, m.roll, m.pitch, wrap_pi(m.yaw), m.roll_rate, m.pitch_rate, m.yaw_rate
            )
        if msg_id == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
            m = self._measurements(tick)
            servos = [0] * 16
            if autopilot.skid:  # ArduRover skid steering: ThrottleLeft on 1, ThrottleRight on 3
                servos[0] = pwm_from_motor(m.motor_left)
                servos[2] = pwm_from_motor(m.motor_right)
            else:
                servos[0] = pwm_from_fin(m.rudder)
                servos[2] = pwm_from_thrust(m.thrust_ratio)
            servos[1] = pwm_from_fin(m.elevator)
            mass_output = int(self.params["MASS_SERVO"])
            servos[mass_output - 1] = pwm_from_fin(m.mass_angle)
            # time_usec is a uint32 (micros() on ArduPilot): it wraps every 71.6 minutes; unwrapped it
            # could not be packed after 4295 s and the outputs vanished from telemetry (the fault bench)
            return mavlink.MAVLink_servo_output_raw_message((ms * 1000) & 0xFFFFFFFF, 0, *servos)
        if msg_id == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            m = self._measurements(tick)
            return mavlink.MAVLink_local_position_ned_message(
                ms, m.north, m.east, m.depth, m.vel_north, m.vel_east, m.vel_down
            )
        if msg_id == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            m = self._measurements(tick)
            lat = ORIGIN_LAT_DEG + math.degrees(m.north / EARTH_RADIUS_M)
            lon = ORIGIN_LON_DEG + math.degrees(
                m.east / (EARTH_RADIUS_M * math.cos(math.radians(ORIGIN_LAT_DEG))))
            heading = int(round(math.degrees(m.yaw) * 100.0)) % 36000
            return mavlink.MAVLink_global_position_int_message(
                ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(-m.depth * 1000)),
                int(round(-m.depth * 1000)), _cm(m.vel_north), _cm(m.vel_east), _cm(m.vel_down),
                heading,
            )
        if msg_id == mavlink.MAVLINK_MSG_ID_VFR_HUD:
            m = self._measurements(tick)
            heading = int(round(math.degrees(m.yaw))) % 360
            throttle = int(round(m.thrust_ratio * 100.0))
            return mavlink.MAVLink_vfr_hud_message(
                m.speed_water, m.speed_ground, heading, throttle, -m.depth, -m.vel_down
            )
        if msg_id == mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE:
            m = self._measurements(tick)
            press = SEA_LEVEL_HPA + PRESSURE_RHO * GRAVITY * m.depth / 100.0
            return mavlink.MAVLink_scaled_pressure_message(ms, press, 0.0, 1500)
        if msg_id == mavlink.MAVLINK_MSG_ID_NAV_CONTROLLER_OUTPUT:
            # the holding mode's targets, as an autopilot reports them: the heading set-point (whole
            # degrees, as the message carries it) and the depth error
            m = self._measurements(tick)
            bearing = int(round(math.degrees(autopilot.heading_setpoint))) % 360
            return mavlink.MAVLink_nav_controller_output_message(
                0.0, 0.0, bearing, bearing, 0, float(m.depth - autopilot.depth_setpoint), 0.0, 0.0)
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return heartbeat(autopilot)
        if msg_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            return mavlink.MAVLink_sys_status_message(0, 0, 0, 0, 16000, -1, 100, 0, 0, 0, 0, 0, 0)
        if msg_id == mavlink.MAVLINK_MSG_ID_SYSTEM_TIME:
            return mavlink.MAVLink_system_time_message(0, ms)
        if msg_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return autopilot_version(int(self.params["SYSID_THISMAV"]))
        return None


def _cm(speed: float) -> int:
    """m/s → cm/s clamped to int16 (GLOBAL_POSITION_INT velocity fields)."""
    return max(-32768, min(32767, int(round(speed * 100.0))))
