"""ArduSub (vectored frame), as seen live on ArduPilot 4.7 SITL (SPEC §4).

Which mode each phase uses (decided here, documented in the README):

* **settle on course at a thrust**, and the **heading-step checks**: ALT_HOLD (the neutral
  "hold"). ALT_HOLD holds the depth the vehicle had when it entered the mode; the heading comes
  from SET_ATTITUDE_TARGET (attitude only, refreshed every vehicle second: ArduSub drops it after
  5 s); the thrust is the pilot's forward channel (RC 5), held by an override the link keeps alive.
  A depth set-point is accepted only as "stay where you are" (within 0.5 m): ALT_HOLD has no
  depth target to set.
* **open-loop excitation**: MANUAL, where the yaw channel (RC 4) is passed to the thruster mix
  (ALT_HOLD makes it a yaw-rate demand). The forward override stays; the vertical thrusters get
  neutral (the vehicle's buoyancy acts for the ~16 s of a training window). Returning to
  ALT_HOLD (the next "hold" mode command, which the manoeuvre sends after training) ends it.

The yaw actuator is read back by un-mixing the thruster outputs of SERVO_OUTPUT_RAW with the
vectored frame's factors (AP_Motors6DOF): yaw ±1 ↔ ±``angle_full_scale_rad`` of equivalent
rudder; forward ±1 ↔ thrust ratio. Depth is the autopilot's own estimate (GLOBAL_POSITION_INT),
never raw pressure against 1013.25 hPa. ArduSub's GCS failsafe (FS_GCS_ENABLE) disarms 5 s after
the last heartbeat from the ground station's system id: the strategy sends one every vehicle second.
"""
from __future__ import annotations

import math
from dataclasses import replace

from companion.interface import Telemetry
from companion.link.autopilots.base import AutopilotStrategy, yaw_quaternion
from companion.link.profile import AutopilotProfile

PROFILE = AutopilotProfile(
    name="ardusub",
    modes={"manual": 19, "hold": 2, "guided": 4, "stabilize": 0, "poshold": 16},  # hold = ALT_HOLD
    channels={"rudder": 4, "elevator": 1, "thrust": 5, "vertical": 3},
    servo_outputs={},  # thrusters are mixed: read back by un-mixing (Strategy.on_snapshot)
    params={
        "heading_angle_p": "ATC_ANG_YAW_P", "heading_rate_p": "ATC_RAT_YAW_P", "heading_rate_i": "ATC_RAT_YAW_I",
        "heading_rate_d": "ATC_RAT_YAW_D", "heading_rate_ff": "ATC_RAT_YAW_FF", "heading_rate_imax": "ATC_RAT_YAW_IMAX",
        "pitch_p": "ATC_ANG_PIT_P", "gcs_sysid": "MAV_GCS_SYSID", "override_timeout": "RC_OVERRIDE_TIME",
        "system_id": "MAV_SYSID", "gcs_failsafe": "FS_GCS_ENABLE",
    },
    aliases={"gcs_sysid": ("SYSID_MYGCS",), "system_id": ("SYSID_THISMAV",)},
    marker_param="ATC_ANG_YAW_P",
    angle_full_scale_rad=0.35,
    pwm_half_range=400,
    thrust_pwm_zero=1500,  # forward channel is bidirectional: 1500 = stop, 1900 = full ahead
    thrust_pwm_full=1900,
    mass_servo=None,
    int_encoding="cast",
    heading_schedule="cascade",
    strategy="ardusub",
    water_speed_sensor=False,
    depth_from_pressure=False,
    depth_setpoint=False,
)

STREAMS = {30: 20.0, 36: 20.0, 32: 10.0, 33: 10.0, 74: 10.0}

#: AP_Motors6DOF SUB_FRAME_VECTORED factors (yaw, forward) of motors 1..4
VECTORED_YAW_FORWARD = ((1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0), (1.0, 1.0))
MOTOR_PWM_CENTRE, MOTOR_PWM_HALF_RANGE = 1500.0, 400.0


def unmix_vectored(pwm: list[float]) -> tuple[float, float] | None:
    """(yaw, forward) in ±1 from the first four thruster outputs; None when one is missing."""
    if len(pwm) < 4 or any(not (800 <= p <= 2200) for p in pwm[:4]):
        return None
    outputs = [(p - MOTOR_PWM_CENTRE) / MOTOR_PWM_HALF_RANGE for p in pwm[:4]]
    yaw = sum(f[0] * o for f, o in zip(VECTORED_YAW_FORWARD, outputs)) / 4.0
    forward = sum(f[1] * o for f, o in zip(VECTORED_YAW_FORWARD, outputs)) / 4.0
    return yaw, forward


class Strategy(AutopilotStrategy):
    streams = STREAMS
    refresh_s = 1.0

    def __init__(self, link) -> None:
        super().__init__(link)
        self.heading = math.nan
        self._sent_at = -math.inf
        self._gcs_heartbeat_at = -math.inf

    def _in_hold(self) -> bool:
        return self.link.custom_mode == self.profile.modes["hold"]

    def set_heading(self, heading: float) -> None:
        self.heading = heading
        self._send()

    def set_thrust(self, thrust_ratio: float) -> None:
        if not 0.0 <= thrust_ratio <= 1.0:
            raise ValueError(f"thrust ratio {thrust_ratio!r} outside 0..1")
        self.link.override("thrust", thrust_ratio)

    def set_depth(self, depth: float) -> None:
        latest = self.link.latest_telemetry
        here = latest.depth if latest is not None else math.nan
        if not (math.isfinite(here) and abs(here - depth) <= 0.5):
            raise self._cannot(f"depth target: ALT_HOLD holds the depth it is entered at ({here:.2f} m), "
                               f"not {depth:.2f} m; bring the vehicle there first or run without a depth")

    def _send(self) -> None:
        if not self._in_hold() or not math.isfinite(self.heading):
            return
        self.link.send_attitude_target(yaw_quaternion(self.heading), 0.5, ignore_thrust=True)
        self._sent_at = self.link.vehicle_time_s

    def mode_changed(self, neutral: str) -> None:
        if self._in_hold():
            self.link.release("rudder")
            self.link.release("vertical")
        self._send()

    def override(self, actuator: str, value: float) -> None:
        if actuator == "rudder" and self._in_hold():
            self.link.override_raw("vertical", 1500)  # MANUAL: neutral vertical thrust
            self.link.override(actuator, value)
            self.link.set_mode("manual")
            return
        self.link.override(actuator, value)

    def release(self, actuator: str | None) -> None:
        if actuator == "rudder" and self.link.custom_mode == self.profile.modes["manual"]:
            self.link.override(actuator, 0.0)  # MANUAL: centred yaw stick, a known zero output
            return
        self.link.release(actuator)

    def on_snapshot(self, telemetry: Telemetry) -> Telemetry:
        now = telemetry.time_s
        if now - self._gcs_heartbeat_at >= 1.0:
            self.link.send_gcs_heartbeat()
            self._gcs_heartbeat_at = now
        if self._in_hold() and now - self._sent_at >= self.refresh_s:
            self._send()
        mixed = unmix_vectored(self.link.servo_pwm())
        if mixed is None:
            return telemetry
        yaw, forward = mixed
        return replace(telemetry, rudder=yaw * self.profile.angle_full_scale_rad, thrust_ratio=max(0.0, forward))
