"""ArduRover boats (``FRAME_CLASS 2``), as seen live on ArduPilot 4.7 SITL (SPEC §4).

Which mode each phase uses (decided here, documented in the README):

* **settle on course at a thrust**, and the **heading-step checks**: GUIDED, with
  SET_ATTITUDE_TARGET carrying the heading (quaternion) and the "thrust" field, which ArduRover
  reads as a speed: thrust × WP_SPEED. So on ArduRover a campaign's thrust settings are fractions
  of WP_SPEED. The target is refreshed every vehicle second (Rover stops after 3 s without one).
  The neutral "hold" mode is GUIDED.
* **open-loop excitation**: MANUAL, the only mode that passes the steering stick to the steering
  servo (ACRO makes it a turn-rate demand). At the first rudder override the throttle the speed
  loop had settled on (SERVO3, read back) is held by a throttle override, so the speed stays put,
  and the steering override carries the doublet. Releasing the rudder holds the steering the
  heading loop had before the doublet (read back from SERVO1), still in MANUAL, so the whole
  training or validation record is open loop at constant throttle: measured, in GUIDED ArduRover
  slows in turns and b2 ∝ u² then drifts within the record (a22/b2 errors up to 10 %). The
  manoeuvre's next "hold" mode command ends the excitation: GUIDED again, targets re-sent.

Actuators are read back from SERVO_OUTPUT_RAW through the actuation read at connect
(:meth:`Strategy.configure`: SERVOn_FUNCTION, ``companion.link.actuation``): a steering servo (26 or
21) and a throttle (70), or a skid-steered pair (73/74) un-mixed into steering and throttle (eq. S.1);
a vehicle with neither is refused with what to set. On a skid boat the doublet is held inside the
mixer's room: MANUAL shrinks steering *and* throttle when |s| + |t| > 1 (Rover ``mode.cpp``), which
would slow the boat within the record, so an excitation that would reach it is scaled down around
its trim, and the strategy says so (STATUSTEXT); one that would be scaled to almost nothing is refused
(ProfileError: the campaign stops and restores) with what to change. Depth is not a boat's notion (a depth set-point is refused); the water speed is the ground speed (no water-speed
sensor; a current biases it). Rover refuses to arm with the throttle off neutral.
"""
from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import ClassVar

from companion.interface import Telemetry
from companion.link.actuation import OUTPUTS
from companion.link.autopilots.ardupilot import ArduPilotStrategy, yaw_quaternion
from companion.link.autopilots.skid_room import doublet_scale, refusal, scaled, with_actuation
from companion.link.errors import ProfileError
from companion.link.profile import AutopilotProfile, CampaignDefaults, NativeScale, PidTuningReport, SpeedLoopReport

log = logging.getLogger(__name__)

PROFILE = AutopilotProfile(
    name="ardurover",
    # the schedule's ±20° step at the highest speed flew 2.5–3 points above its prediction (SITL)
    prediction_margin_pct=3.5,
    # "hold" = GUIDED: heading and speed held from SET_ATTITUDE_TARGET (Rover's HOLD mode stops)
    modes={"manual": 0, "hold": 15, "guided": 15, "acro": 1, "steering": 3, "stop": 4, "loiter": 5, "auto": 10,
           "rtl": 11},
    channels={"rudder": 1, "thrust": 3},
    servo_outputs={"rudder": 1, "thrust": 3},
    params={
        "heading_angle_p": "ATC_STR_ANG_P", "heading_rate_p": "ATC_STR_RAT_P", "heading_rate_i": "ATC_STR_RAT_I",
        "heading_rate_d": "ATC_STR_RAT_D", "heading_rate_ff": "ATC_STR_RAT_FF", "heading_rate_imax": "ATC_STR_RAT_IMAX",
        "turn_rate_max": "ATC_STR_RAT_MAX", "cruise_speed": "CRUISE_SPEED", "cruise_thrust": "CRUISE_THROTTLE",
        "speed_default": "WP_SPEED", "gcs_sysid": "MAV_GCS_SYSID", "override_timeout": "RC_OVERRIDE_TIME",
        "speed_p": "ATC_SPEED_P", "speed_i": "ATC_SPEED_I", "accel_max": "ATC_ACCEL_MAX",
        "system_id": "MAV_SYSID",
        # read, never written: the heading design and its predicted steps (eq. A.2)
        "turn_accel_max": "ATC_STR_ACC_MAX", "steering_scale_speed": "MOT_SPD_SCA_BASE",
        # bit 0 sends the steering loop's PID_TUNING (learning during missions; restored after)
        "pid_tuning_mask": "GCS_PID_MASK",
    },
    aliases={"gcs_sysid": ("SYSID_MYGCS",), "system_id": ("SYSID_THISMAV",)},
    native_scales={"cruise_thrust": NativeScale(scale=100.0)},  # CRUISE_THROTTLE is percent
    marker_param="ATC_STR_ANG_P",
    angle_full_scale_rad=0.5236,  # steering output ±1 ↔ ±30° of rudder: a property of the boat
    thrust_pwm_zero=1500,  # boats: throttle centred = stop
    thrust_pwm_full=2000,
    mass_servo=None,
    int_encoding="cast",
    flown=True,  # campaign, gain check and restores run against ArduRover 4.7 SITL (tests/test_ardupilot_rover.py)
    heading_schedule="cascade",
    heading_controller="cascade",
    # AR_AttitudeControl's defaults (ArduPilot 4.7)
    shipped_gains={"ATC_STR_ANG_P": 2.0, "ATC_STR_RAT_P": 0.2, "ATC_STR_RAT_I": 0.2, "ATC_STR_RAT_FF": 0.2,
                   "ATC_STR_RAT_IMAX": 1.0, "ATC_STR_RAT_MAX": 120.0, "ATC_STR_ACC_MAX": 120.0,
                   "MOT_SPD_SCA_BASE": 1.0},
    strategy="ardurover",
    # in AUTO the navigation asks the rate loop for a turn rate: learning verifies its tracking
    learning_verification="turn_rate",
    # GCS_PID_MASK bit 0: the steering rate loop, PID_TUNING axis STEER, both rates in deg/s
    # (Rover GCS_MAVLink_Rover.cpp send_pid_tuning)
    pid_tuning=PidTuningReport(mask_param="pid_tuning_mask", mask_bit=1, axis=5),
    # GCS_PID_MASK bit value 2: the speed loop (AR_AttitudeControl::get_throttle_out_speed), PID_TUNING
    # axis 4 (ACCZ): desired = the accel-limited speed demand, achieved = the measured speed, m/s
    speed_loop_report=SpeedLoopReport(mask_param="pid_tuning_mask", mask_bit=2, axis=4),
    water_speed_sensor=False,
    depth_from_pressure=False,
    vehicle_kind="surface",
    depth_setpoint=False,
    actuator_hold="zoh",
    output_lead_s=0.010,  # 25 Hz snapshots of the 50 Hz rover loop (STREAMS below)
    # yaw only (a boat has no dive plane); thrusts are fractions of WP_SPEED: 60, 80, 100 %
    campaign_defaults=CampaignDefaults(thrusts=(0.6, 0.8, 1.0), axes=("yaw",)),
    thrust_meaning="a speed demand: the fraction of WP_SPEED sent as SET_ATTITUDE_TARGET's thrust in GUIDED",
    train_full_window=True,
)

#: GLOBAL_POSITION_INT joins the base streams (the autopilot's own position and altitude).
#: ATTITUDE and SERVO_OUTPUT_RAW at 25 Hz, every second loop of the 50 Hz rover loop: at 20 Hz the
#: samples come 40 and 60 ms apart in turn (measured), and 50 Hz is refused (DENIED). Each snapshot
#: pairs a loop's attitude with that loop's outputs (by their time stamps, ``companion.link.snapshot``), which the next
#: physics step applies: a zero-order hold for the identifier (``actuator_hold``). Pairing with the
#: previous message instead scattered a22 and b2 by ±5 %, and same-loop pairing with a first-order
#: hold biased them by −13 % (measured on SITL).
#: PID_TUNING (the steering loop, once GCS_PID_MASK asks for it) and NAV_CONTROLLER_OUTPUT (cross-track)
#: for learning during missions.
STREAMS = {30: 25.0, 36: 25.0, 32: 10.0, 33: 10.0, 74: 10.0, 194: 25.0, 62: 5.0}


class Strategy(ArduPilotStrategy):
    streams = STREAMS
    refresh_s = 1.0  # vehicle seconds between target refreshes (Rover gives up after 3 s)

    def __init__(self, ports) -> None:
        super().__init__(ports)
        self.heading = math.nan
        self.speed_fraction = math.nan
        self._sent_at = -math.inf
        self._excitation: dict | None = None
        self._refreshing = False  # targets of a procedure to refresh while in GUIDED (False once forgotten)
        #: learnt override corrections (actuator -> offset in its units), kept between excitations
        self._override_bias: dict[str, float] = {}

    def configure(self):
        """This boat's actuation (SERVOn_FUNCTION, required) and its pilot channels (RCMAP_ROLL and
        RCMAP_THROTTLE: the steering and throttle sticks an override moves in MANUAL)."""
        actuation = self.read_actuation(OUTPUTS, required=True)
        outputs = actuation.outputs()
        rcmap = self.read_present(("RCMAP_ROLL", "RCMAP_THROTTLE"), self.profile.marker_param)
        channels = {"rudder": int(rcmap.get("RCMAP_ROLL", 1)), "thrust": int(rcmap.get("RCMAP_THROTTLE", 3))}
        return replace(with_actuation(self.profile, actuation), channels=channels,
                       servo_outputs={"rudder": outputs.get("steering", outputs.get("left")),
                                      "thrust": outputs.get("throttle", outputs.get("right"))})

    def _excitation_scale(self, throttle: float, steering: float, value: float) -> float:
        """1, or the factor that keeps a skid boat's doublet inside MANUAL's room (``skid_room``)."""
        scale, text = doublet_scale(self.profile.actuation, self.profile.angle_full_scale_rad, throttle, steering,
                                    value)
        if text is not None:
            log.warning("%s", text)
            self.ports.ground.status_text(text, 4)
        reason = refusal(throttle, scale)
        if reason is not None:
            raise ProfileError(reason)
        return scale

    def _in_guided(self) -> bool:
        return self.in_mode("guided")

    def set_heading(self, heading: float) -> None:
        self.heading = heading
        self._refreshing = True
        self._send()

    def set_thrust(self, thrust_level: float) -> None:
        """The thrust level is a speed demand here: a fraction of WP_SPEED (SET_ATTITUDE_TARGET's thrust)."""
        if not 0.0 <= thrust_level <= 1.0:
            raise ValueError(f"thrust (fraction of WP_SPEED) {thrust_level!r} outside 0..1")
        self.speed_fraction = thrust_level
        self._refreshing = True
        self._send()

    def forget_targets(self) -> None:
        """After a restore the procedure's heading and speed are no longer refreshed: a boat left in
        GUIDED then does what Rover does when its targets stop (it stops after 3 s), as it would had
        the companion not been there; the next procedure sends its own."""
        self.heading = self.speed_fraction = math.nan
        self._refreshing = False

    def forget_excitation(self) -> None:
        self._excitation = None

    def set_depth(self, depth: float) -> None:
        raise self._cannot("depth set-point: it is a boat (run the campaign without a depth)")

    def mode_accepted(self, neutral: str) -> None:
        """GUIDED accepted: send the targets at once. On entry a boat loiters, braking towards a
        stopping point, until a target arrives; waiting for the HEARTBEAT that verifies the mode
        (up to a second) let the speed dip (measured on the skid boat: the throttle fell from 0.60 to
        0.13, even astern, and the speed from 1.5 to 0.9 m/s after every record), and the default
        speed loop took longer than a resettle to recover."""
        if self.profile.modes.get(neutral) == self.profile.modes["guided"]:
            self._send(force=True)

    def _send(self, *, force: bool = False) -> None:
        if not force and (not self._in_guided() or self._excitation is not None):
            return  # kept, and sent when GUIDED is entered
        heading = self.heading
        if not math.isfinite(heading):
            latest = self.latest()
            heading = latest.yaw if latest is not None and math.isfinite(latest.yaw) else 0.0
        thrust = self.speed_fraction if math.isfinite(self.speed_fraction) else 0.0
        self.send_attitude_target(yaw_quaternion(heading), thrust)
        self._sent_at = self.now

    def override(self, actuator: str, value: float) -> None:
        if actuator == "rudder" and self._excitation is None and self._in_guided():
            latest = self.latest()
            throttle = latest.thrust_ratio if latest is not None and math.isfinite(latest.thrust_ratio) else None
            steering = latest.rudder if latest is not None and math.isfinite(latest.rudder) else 0.0
            if throttle is None:
                raise self._cannot("throttle read-back (SERVO3): the speed cannot be held open loop")
            self._excitation = {"mode": self.ports.announcements.mode, "steering": steering, "held": {},
                                "scale": self._excitation_scale(throttle, steering, value)}
            self._hold("thrust", throttle)  # before the switch: MANUAL never sees a stopped stick
            self.ports.overrides.override(actuator, self._scaled(actuator, value))
            self.ports.modes.set_mode("manual")
            return
        if self._excitation is not None:
            self._excitation["held"].pop(actuator, None)  # a doublet value: its read-back is what counts
        self.ports.overrides.override(actuator, self._scaled(actuator, value))

    def _scaled(self, actuator: str, value: float) -> float:
        """A rudder override of the current excitation, scaled around its trim (skid room)."""
        excitation = self._excitation
        if excitation is None or actuator != "rudder" or excitation["scale"] == 1.0:
            return value
        return scaled(value, excitation["steering"], excitation["scale"])

    def release(self, actuator: str | None) -> None:
        if self._excitation is not None and actuator == "rudder":
            self._hold("rudder", self._excitation["steering"])  # open loop at the found steering
            return
        if self._excitation is not None and actuator is None:
            self.ports.modes.set_mode(self._excitation["mode"])  # mode_changed ends the excitation, re-sends targets
        self.ports.overrides.release(actuator)

    def mode_changed(self, neutral: str) -> None:
        in_manual = self.in_mode("manual")
        ended = self._excitation is not None and not in_manual
        if not in_manual:
            self._excitation = None  # whoever left MANUAL ended the excitation
        if ended:
            self.ports.overrides.release(None)
        if self._in_guided():
            self._refreshing = True  # the companion put it in GUIDED: its targets are kept alive
        self._send()

    # ------------------------------------------------------------------ held outputs
    def _hold(self, actuator: str, target: float) -> None:
        """Override ``actuator`` so that its *output* (read back) stays at ``target``.

        MANUAL does not pass a stick straight to the servo: measured on ArduRover 4.7 SITL, a
        throttle override of 1801 µs (the 0.602 the speed loop had output) came out at 0.570, and a
        steering override of 1519 µs came out at 0 — the speed then sagged 5 % within the
        identification record and biased a22 and b2. So a held output is trimmed on its read-back
        (:meth:`_trim_held`), and the correction learnt is kept for the next excitation."""
        if self._excitation is None:
            raise RuntimeError(f"{actuator} held with no excitation under way")
        command = target + self._override_bias.get(actuator, 0.0)
        self._excitation["held"][actuator] = {"target": target, "command": command, "sent_s": self.now,
                                              "last_read": math.nan}
        self.ports.overrides.override(actuator, command)

    #: a read-back within this of its target is held as it is (about one PWM step of either channel)
    HOLD_TOLERANCE: ClassVar[dict[str, float]] = {"thrust": 0.0025, "rudder": 0.0015}
    #: vehicle seconds after a correction before the read-back is trusted again (throttle slew)
    HOLD_SETTLE_S = 0.08

    def _trim_held(self, telemetry: Telemetry) -> None:
        """Integral trim of each held override on its read-back, once the output has stopped moving
        (two equal read-backs) — the outputs are exact PWM read-backs, so one or two corrections do."""
        if self._excitation is None or not self.in_mode("manual"):
            return
        readings = {"thrust": telemetry.thrust_ratio, "rudder": telemetry.rudder}
        for actuator, held in self._excitation["held"].items():
            read = readings[actuator]
            steady = math.isfinite(read) and read == held["last_read"]
            held["last_read"] = read
            if not steady or telemetry.time_s - held["sent_s"] < self.HOLD_SETTLE_S:
                continue
            error = held["target"] - read
            if abs(error) <= self.HOLD_TOLERANCE[actuator]:
                continue
            held["command"] += error
            held["sent_s"] = telemetry.time_s
            self._override_bias[actuator] = held["command"] - held["target"]
            log.debug("%s held at %.4f reads %.4f: override now %.4f", actuator, held["target"], read, held["command"])
            self.ports.overrides.override(actuator, held["command"])

    def not_ready(self, telemetry: Telemetry) -> str | None:
        """GUIDED (the campaign's holding mode) needs the EKF's position: Rover refuses the mode without
        it (measured on SITL before its EKF used GPS: MAV_RESULT_FAILED)."""
        if not telemetry.finite("north", "east"):
            return "no position estimate yet (GUIDED, the holding mode, needs one: the EKF is still initialising)"
        return None

    def on_snapshot(self, telemetry: Telemetry) -> Telemetry:
        if (self._refreshing and self._excitation is None and self._in_guided()
                and telemetry.time_s - self._sent_at >= self.refresh_s):
            self._send()
        self._trim_held(telemetry)
        return self.servo_model(telemetry)
