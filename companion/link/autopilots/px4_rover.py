"""PX4 boats on the Ackermann rover module (``rover_ackermann``; airframe 51000 in SITL), as seen
live on PX4 1.18-dev SITL flying our rudder boat (SPEC §4; PX4's shared habits: ``px4``).

Which mode each phase uses (measured):

* **settle on course at a thrust**, and the **heading-step checks**: OFFBOARD (the neutral "hold")
  with SET_POSITION_TARGET_LOCAL_NED velocity set-points: PX4's rover turns the velocity into a
  course (atan2 of its components, held by RO_YAW_P and the yaw-rate loop) and a speed (held by
  RO_SPEED_P/I on the ground speed). A thrust level is a fraction of ``RO_MAX_THR_SPEED`` (measured:
  0.6 → 1.504 m/s on our boat at throttle 0.598). STABILIZED holds only the heading it is in, and
  POSCTL only a course line: neither takes a heading from the companion.
* **open-loop excitation**: MANUAL, where the roll stick is the steering (normalised by
  ``RA_MAX_STR_ANG``) and the throttle stick the motor, both straight through (measured: y 30 →
  steering 0.030, z 800 → motor 0.600, no dead zone). The throttle the speed loop had and the
  steering the heading loop had are read back and put on the sticks before MANUAL is entered.

Actuators are read back from SERVO_OUTPUT_RAW (output 2 steering = Servo 1, 1500 ± 500 µs; output 1
the reversible motor, 1500 µs = stop), paired with the ATTITUDE of the same time stamp. PX4 slews
the steering itself (``RA_STR_RATE_LIM``), so the read-back is the rudder the boat gets: no servo
model is added. The rudder full scale the companion is told must equal ``RA_MAX_STR_ANG`` (checked
when the vehicle is taken): the native gains are in radians of PX4's steering angle.
"""
from __future__ import annotations

import logging
import math

from companion.interface import Telemetry
from companion.link.autopilots.px4 import MODES, Px4Profile, Px4Strategy, Sticks
from companion.link.errors import ParamTimeout, ProfileError
from companion.link.profile import CampaignDefaults

log = logging.getLogger(__name__)

#: PX4's documented ranges (rover_ackermann/module.yaml, rovercontrol_params.yaml) as CascadeRules
#: fields: RO_YAW_P, RO_YAW_RATE_P, RO_YAW_RATE_I 0–100; the feed-forward is the equivalent wheel
#: base RA_WHEEL_BASE in metres, 0–100 (companion.numerics.px4_gains)
GAIN_RANGES = {"angle_p_range": (0.0, 100.0), "rate_p_range": (0.0, 100.0), "rate_i_range": (0.0, 100.0),
               "rate_ff_range": (0.0, 100.0)}

PROFILE = Px4Profile(
    name="px4-rover",
    modes=MODES,
    channels={},  # no RC channel: the sticks are MANUAL_CONTROL (the strategy's)
    servo_outputs={"rudder": 2, "thrust": 1},  # PWM_MAIN_FUNC2 201 (Servo 1), PWM_MAIN_FUNC1 101 (Motor 1)
    params={
        "heading_angle_p": "RO_YAW_P", "heading_rate_p": "RO_YAW_RATE_P", "heading_rate_i": "RO_YAW_RATE_I",
        "heading_ff_length": "RA_WHEEL_BASE", "heading_ff_correction": "RO_YAW_RATE_CORR",
        "turn_rate_max": "RO_YAW_RATE_LIM", "speed_full_throttle": "RO_MAX_THR_SPEED", "speed_max": "RO_SPEED_LIM",
        "steering_max": "RA_MAX_STR_ANG", "rc_loss_exceptions": "COM_RCL_EXCEPT", "system_id": "MAV_SYS_ID",
        # read for the predicted steps (eq. A.4), never written
        "steering_rate_max": "RA_STR_RATE_LIM", "turn_accel_max": "RO_YAW_ACCEL_LIM",
        "yaw_rate_threshold": "RO_YAW_RATE_TH",
    },
    marker_param="SYS_AUTOSTART",  # PX4 only; rover and UUV are told apart by MAV_TYPE
    mav_types=(10, 11),  # MAV_TYPE_GROUND_ROVER, MAV_TYPE_SURFACE_BOAT
    angle_full_scale_rad=0.5236,  # rudder at steering ±1: RA_MAX_STR_ANG of our boat
    pwm_center=1500,
    pwm_half_range=500,
    thrust_pwm_zero=1500,  # reversible motor (CA_R_REV): 1500 µs = stop
    thrust_pwm_full=2000,
    int_encoding="bytewise",
    flown=True,  # campaign, gain check and restores run against PX4 SITL (tests/test_px4_sitl.py)
    heading_schedule="px4_rover",
    heading_controller="px4_rover",
    # the generic Ackermann rover airframe (51000: ROMFS rc defaults, RO_YAW_RATE_TH from
    # rovercontrol_params.yaml)
    shipped_gains={"RO_YAW_P": 3.0, "RO_YAW_RATE_P": 0.25, "RO_YAW_RATE_I": 0.01, "RA_WHEEL_BASE": 0.5,
                   "RO_YAW_RATE_CORR": 1.0, "RO_YAW_RATE_LIM": 130.0, "RO_YAW_ACCEL_LIM": 800.0,
                   "RA_STR_RATE_LIM": 360.0, "RA_MAX_STR_ANG": 0.5236, "RO_YAW_RATE_TH": 3.0},
    strategy="px4_rover",
    water_speed_sensor=False,
    depth_from_pressure=False,
    depth_setpoint=False,
    actuator_hold="zoh",
    output_lead_s=0.005,  # 50 Hz snapshots of the 100 Hz rover loop
    train_full_window=True,
    gain_ranges=GAIN_RANGES,
    campaign_defaults=CampaignDefaults(thrusts=(0.5, 0.7, 0.9), axes=("yaw",)),
    thrust_meaning="a speed demand: the fraction of RO_MAX_THR_SPEED sent as OFFBOARD's velocity set-point",
)

#: SET_POSITION_TARGET_LOCAL_NED.type_mask: velocity only (position, acceleration, yaw, yaw rate ignored)
VELOCITY_ONLY = 0b0000_1101_1100_0111
MAV_FRAME_LOCAL_NED = 1


class Strategy(Px4Strategy):
    AXES = {"rudder": "roll", "thrust": "throttle"}

    def __init__(self, ports) -> None:
        super().__init__(ports)
        self.heading = math.nan
        self.speed_fraction = math.nan
        self.full_throttle_speed = math.nan  # RO_MAX_THR_SPEED (m/s)

    def prepare(self) -> None:
        self.full_throttle_speed = self.ports.parameters.get_param("RO_MAX_THR_SPEED")
        try:
            steering_max = self.ports.parameters.get_param("RA_MAX_STR_ANG")
        except ParamTimeout:
            return
        if abs(steering_max - self.profile.angle_full_scale_rad) > 1e-3:
            raise ProfileError(f"RA_MAX_STR_ANG is {steering_max:.4f} rad but the companion was told a rudder full scale "
                               f"of {self.profile.angle_full_scale_rad:.4f} rad: they must be equal (--rudder-full-scale)")

    # ------------------------------------------------------------------ set-points
    def set_heading(self, heading: float) -> None:
        self.heading = heading
        self._resend()

    def set_thrust(self, thrust_level: float) -> None:
        """The thrust level is a speed demand: a fraction of RO_MAX_THR_SPEED (OFFBOARD velocity)."""
        if not 0.0 <= thrust_level <= 1.0:
            raise ValueError(f"thrust (fraction of RO_MAX_THR_SPEED) {thrust_level!r} outside 0..1")
        self.speed_fraction = thrust_level
        self._resend()

    def set_depth(self, depth: float) -> None:
        raise self._cannot("depth set-point: it is a boat (run the campaign without a depth)")

    def _resend(self) -> None:
        if self.taken:
            self.send_target()

    def send_target(self) -> None:
        """Velocity over ground: the course is the heading set-point (the heading now until one is
        given), the speed the thrust level × RO_MAX_THR_SPEED (the speed now until one is given)."""
        latest = self.latest()
        heading = self.heading
        if not math.isfinite(heading):
            heading = latest.yaw if latest is not None and math.isfinite(latest.yaw) else 0.0
        speed = self.speed_fraction * self.full_throttle_speed
        if not math.isfinite(speed):
            speed = latest.speed_ground if latest is not None and math.isfinite(latest.speed_ground) else 0.0
        now = self.now
        transport = self.ports.transport
        transport.mav.set_position_target_local_ned_send(
            int(now * 1000) & 0xFFFFFFFF if math.isfinite(now) else 0, transport.system_id,
            transport.autopilot_component, MAV_FRAME_LOCAL_NED, VELOCITY_ONLY, 0.0, 0.0, 0.0,
            speed * math.cos(heading), speed * math.sin(heading), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ sticks
    def stick_value(self, actuator: str, value: float) -> float:
        if actuator == "rudder":
            return value / self.profile.angle_full_scale_rad
        return value  # MANUAL: the throttle stick is the motor output

    def stick_rudder(self, sticks: Sticks) -> float:
        return max(-1.0, min(1.0, sticks.roll)) * self.profile.angle_full_scale_rad

    def held_sticks(self, telemetry: Telemetry) -> Sticks:
        if not telemetry.finite("rudder", "thrust_ratio"):
            raise self._cannot("steering and motor read-back (SERVO_OUTPUT_RAW 1, 2): the outputs cannot be held")
        return Sticks(roll=telemetry.rudder / self.profile.angle_full_scale_rad, throttle=telemetry.thrust_ratio)
