"""Our simulator's autopilot (docs/PROTOCOL.md): set-points by COMMAND_LONG, per-channel RC
override in the holding mode (ArduPilot's rules: from the ground station's id), the rolling mass by
DO_SET_SERVO, actuator positions read back from SERVO_OUTPUT_RAW, depth from SCALED_PRESSURE.
A boat reports SERVO1/3_FUNCTION as ArduRover does: 26/70 keep outputs 1 and 3 as rudder and thrust,
73/74 make them a skid-steered pair, un-mixed into steering and throttle (``companion.link.actuation``),
whose doublets are kept inside the mixer's room (``skid_room``); an AUV reports none.
Every set-point must be acknowledged: a refusal or a missing answer aborts the procedure
(``VehicleLink.next_telemetry`` raises)."""
from __future__ import annotations

import math

from companion.link.autopilots.ardupilot import ArduPilotStrategy
from companion.link.autopilots.base import BASE_STREAMS
from companion.link.autopilots.skid_room import doublet_scale, refusal, scaled, with_actuation
from companion.link.errors import ProfileError
from companion.link.profile import AutopilotProfile

MAV_CMD_CONDITION_YAW = 115
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_CHANGE_ALTITUDE = 186

PROFILE = AutopilotProfile(
    name="sim",
    # designed ±20° steps flew 0.8–1.4 points above their prediction (default rehearsal, seed 1)
    prediction_margin_pct=2.0,
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
    self_resetting=("roll_kick",),  # the simulator applies the impulse and sets it back to 0
    angle_full_scale_rad=0.5236,
    thrust_pwm_zero=1000,
    thrust_pwm_full=2000,
    mass_servo=9,
    int_encoding="cast",
    flown=True,
    heading_schedule="heading",
    heading_controller="pi",
    shipped_gains={"HDG_P": 1.0, "HDG_I": 0.05, "HDG_IMAX": 0.15, "HDG_TRIM": 0.0, "RUD_MAX": 0.35, "RUD_RATE": 0.5},
    strategy="sim",
    reports_heading_target=True,
    thrust_meaning="the simulator's thrust ratio (its thruster map, SPEC §3.5), sent as DO_CHANGE_SPEED percent",
)


class Strategy(ArduPilotStrategy):
    streams = {**BASE_STREAMS, 29: 10.0, 62: 10.0}  # + SCALED_PRESSURE (depth), NAV_CONTROLLER_OUTPUT (targets)
    # the holding mode keeps the last thrust and heading commanded and the mass servo its position
    persistent_setpoints = ("thrust", "heading", "rolling_mass")

    #: the outputs whose function a simulated boat reports
    FUNCTION_OUTPUTS = (1, 3)
    #: (trim, scale) of the current skid excitation (None between excitations)
    _doublet: tuple[float, float] | None = None

    def configure(self):
        """A skid-steered boat (SERVO1/3_FUNCTION 73/74) reads its steering and throttle un-mixed from
        outputs 1 and 3; a rudder boat and an AUV keep the fixed outputs of the profile."""
        actuation = self.read_actuation(self.FUNCTION_OUTPUTS, required=False)
        if actuation is None or not actuation.skid:
            return self.profile
        return with_actuation(self.profile, actuation)

    def override(self, actuator: str, value: float) -> None:
        """An open-loop rudder on a skid boat is scaled into the mixer's room (``skid_room``), one factor
        per excitation (from its first override until the rudder is released)."""
        if actuator == "rudder" and self.profile.actuation is not None:
            if self._doublet is None:
                latest = self.latest()
                throttle = latest.thrust_ratio if latest is not None else math.nan
                trim = latest.rudder if latest is not None and math.isfinite(latest.rudder) else 0.0
                scale, text = doublet_scale(self.profile.actuation, self.profile.angle_full_scale_rad,
                                            throttle if math.isfinite(throttle) else 0.0, trim, value)
                if text is not None:
                    self.ports.ground.status_text(text, 4)
                reason = refusal(throttle, scale)
                if reason is not None:
                    raise ProfileError(reason)
                self._doublet = (trim, scale)
            value = scaled(value, *self._doublet)
        self.ports.overrides.override(actuator, value)

    def release(self, actuator: str | None) -> None:
        if actuator in ("rudder", None):
            self._doublet = None
        self.ports.overrides.release(actuator)

    def set_heading(self, heading: float) -> None:
        self.ports.commands.send_setpoint(MAV_CMD_CONDITION_YAW, (math.degrees(heading) % 360.0, 0.0, 0.0, 0.0))

    def set_depth(self, depth: float) -> None:
        self.ports.commands.send_setpoint(MAV_CMD_DO_CHANGE_ALTITUDE, (-depth, 0.0))

    def set_thrust(self, thrust_level: float) -> None:
        """The thrust level is the simulator's thrust ratio, sent as DO_CHANGE_SPEED percent."""
        self.ports.commands.send_setpoint(MAV_CMD_DO_CHANGE_SPEED, (0.0, -1.0, 100.0 * thrust_level))
