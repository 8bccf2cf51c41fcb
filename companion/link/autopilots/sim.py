"""Our simulator's autopilot (docs/PROTOCOL.md): set-points by COMMAND_LONG, per-channel RC
override in the holding mode (ArduPilot's rules: from the ground station's id), the rolling mass by
DO_SET_SERVO, actuator positions read back from SERVO_OUTPUT_RAW, depth from SCALED_PRESSURE.
Every set-point must be acknowledged: a refusal or a missing answer aborts the procedure
(``VehicleLink.next_telemetry`` raises)."""
from __future__ import annotations

import math

from companion.link.autopilots.ardupilot import ArduPilotStrategy
from companion.link.autopilots.base import BASE_STREAMS
from companion.link.profile import AutopilotProfile

MAV_CMD_CONDITION_YAW = 115
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_CHANGE_ALTITUDE = 186

PROFILE = AutopilotProfile(
    name="sim",
    modes={"manual": 19, "hold": 2, "guided": 4},
    channels={"rudder": 1, "elevator": 2, "thrust": 3},
    servo_outputs={"rudder": 1, "elevator": 2, "thrust": 3},
    params={
        "heading_p": "HDG_P", "heading_i": "HDG_I", "heading_imax": "HDG_IMAX", "rudder_trim": "HDG_TRIM",
        "depth_p": "DPT_P", "depth_i": "DPT_I", "pitch_p": "PIT_P", "pitch_i": "PIT_I", "pitch_max": "PIT_MAX",
        "rudder_max": "RUD_MAX", "rudder_rate": "RUD_RATE", "elevator_max": "ELEV_MAX", "elevator_rate": "ELEV_RATE",
        "cruise_thrust": "CRUISE_THR", "override_timeout": "RC_OVR_TIME", "gcs_sysid": "SYSID_MYGCS",
        "system_id": "SYSID_THISMAV", "mass_servo": "MASS_SERVO", "mass_max": "MASS_MAX",
        "attitude_rate": "SR_ATT_HZ", "position_rate": "SR_POS_HZ",
        "roll_disturbance": "SIM_ROLL_DIST", "roll_kick": "SIM_ROLL_KICK",  # test hooks of the simulator
    },
    marker_param="HDG_P",
    angle_full_scale_rad=0.5236,
    thrust_pwm_zero=1000,
    thrust_pwm_full=2000,
    mass_servo=9,
    int_encoding="cast",
    flown=True,
    heading_schedule="heading",
    strategy="sim",
    reports_heading_target=True,
    thrust_meaning="the simulator's thrust ratio (its thruster map, SPEC §3.5), sent as DO_CHANGE_SPEED percent",
)


class Strategy(ArduPilotStrategy):
    streams = {**BASE_STREAMS, 29: 10.0, 62: 10.0}  # + SCALED_PRESSURE (depth), NAV_CONTROLLER_OUTPUT (targets)
    # the holding mode keeps the last thrust and heading commanded and the mass servo its position
    persistent_setpoints = ("thrust", "heading", "rolling_mass")

    def set_heading(self, heading: float) -> None:
        self.ports.commands.send_setpoint(MAV_CMD_CONDITION_YAW, (math.degrees(heading) % 360.0, 0.0, 0.0, 0.0))

    def set_depth(self, depth: float) -> None:
        self.ports.commands.send_setpoint(MAV_CMD_DO_CHANGE_ALTITUDE, (-depth, 0.0))

    def set_thrust(self, thrust_level: float) -> None:
        """The thrust level is the simulator's thrust ratio, sent as DO_CHANGE_SPEED percent."""
        self.ports.commands.send_setpoint(MAV_CMD_DO_CHANGE_SPEED, (0.0, -1.0, 100.0 * thrust_level))
