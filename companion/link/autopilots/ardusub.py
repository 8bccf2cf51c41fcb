"""ArduSub (vectored frame), as seen live on ArduPilot 4.7 SITL (SPEC §4).

Which mode each phase uses (decided here, documented in the README):

* **settle on course at a thrust**, and the **heading-step checks**: ALT_HOLD (the neutral
  "hold"). ALT_HOLD holds the depth the vehicle had when it entered the mode; the heading comes
  from SET_ATTITUDE_TARGET (attitude only, refreshed every vehicle second: ArduSub drops it after
  5 s); the thrust is the pilot's forward channel (RC 5), held by an override the link keeps alive.
  A depth set-point is accepted only as "stay where you are" (within 0.5 m): ALT_HOLD has no
  depth target to set.
* **open-loop excitation**: MANUAL, where the yaw channel (RC 4) is passed to the thruster mix
  (ALT_HOLD makes it a yaw-rate demand). MANUAL scales the yaw stick by ACRO_YAW_P / 3.375
  (mode_manual.cpp): the override divides by that ratio, read from the vehicle, so the motors get
  the yaw asked for. The forward override stays; the throttle stick (RC 3) keeps the depth MANUAL
  was entered at: ALT_HOLD's mean vertical thrust (un-mixed from motors 5/6, averaged over
  ``VERTICAL_AVERAGE_S``) plus ``DEPTH_STICK_GAIN`` per metre of depth error, so the heading is
  excited open loop with the depth loop closed, as in the thesis (measured: ±0.15 m over a
  record). After the doublet the yaw stick is centred (MANUAL: a known zero output) and the
  record stays open loop; the manoeuvre's next "hold" mode command ends the excitation.

ArduSub habits the strategy answers for:

* without an RC receiver (a vehicle flown from a ground station) a released RC override leaves the
  channel at its **last value**: the forward channel would keep the thrust, the yaw channel a
  turn. So :meth:`Strategy.release` centres a stick (1500 µs: stop, no turn, no climb) and
  releases it ``RELEASE_AFTER_S`` later (both in one ArduSub loop leave the old value). A restore
  that released the overrides directly would bypass this: it goes through the strategy.
* ArduSub disarms after FS_PILOT_TIMEOUT (3 s) without pilot input (FS_PILOT_INPUT, "Lost manual
  control"), and after 5 s without a heartbeat from the ground station's system id
  (FS_GCS_ENABLE). While connected, the companion is the pilot: it sends a GCS heartbeat every
  vehicle second, and an RC override that changes no channel (every value "ignore") whenever no
  override is being refreshed. When the companion goes away, both failsafes act as designed.
* ArduSub 4.7 computes ATC_RAT_YAW_FF but never applies it (AC_AttitudeControl_Sub sends only the
  rate PID's P+I+D to the motors): a feed-forward written here changes nothing (measured).

The yaw actuator is read back by un-mixing the thruster outputs of SERVO_OUTPUT_RAW with the
vectored frame's factors (AP_Motors6DOF): yaw ±1 ↔ ±``angle_full_scale_rad`` of equivalent
rudder; forward ±1 ↔ thrust ratio. Each motor saturates at ±1, so forward + |yaw| above 1 clips
both (the read-back shows what the motors do). Attitude and outputs are paired per loop at 50 Hz:
at 20 Hz the doublet's switches fall up to 50 ms between samples and a22/b2 scattered by ±5 %
(measured). Depth: see :meth:`Strategy.depth`.
"""
from __future__ import annotations

import math
from dataclasses import replace

from companion.interface import Telemetry
from companion.link.autopilots.ardupilot import ArduPilotStrategy, yaw_quaternion
from companion.link.errors import ParamTimeout
from companion.link.profile import AutopilotProfile, CampaignDefaults, NativeScale, PidTuningReport
from companion.numerics.rate_loop import ARDUSUB_RATE_LOOP
from companion.link.autopilots.vectored_mix import (STICK_CENTRE, STICK_HALF_RANGE, VECTORED_FACTORS,  # noqa: F401
                                                    VectoredAxes, throttle_stick, unmix_vectored)

#: the native gain ranges the cascade design keeps to on ArduSub (AC_AttitudeControl_Sub's documented
#: ATC_ANG_YAW_P 0–6 and ATC_RAT_YAW_I 0–0.05). ATC_RAT_YAW_FF: 0, because ArduSub 4.7 computes the
#: rate feed-forward but never applies it (AC_AttitudeControl_Sub::rate_controller_run sends
#: update_all(), P+I+D, to the motors; measured: FF 6.3 left the yaw output at P+I). ATC_RAT_YAW_P
#: keeps the Rover bound 0–2: ArduSub documents 0–0.5, made for ROVs with 10–20× this AUV's yaw
#: authority per unit of output (0.35 rad of equivalent rudder), and with P ≤ 0.5 a 20° step takes
#: over 20 s (measured).
#: the vectored frame's forward thrust and yaw share motors 1-4, each saturating at ±1, so forward +
#: |yaw| must stay below 1 or both are clipped (forward 0.65 leaves 0.35 of yaw, the 0.12 rad of
#: equivalent rudder the heading loop and a 0.10 rad doublet need); yaw only (no pitch actuator).
#: On the STARFISH physics 0.45, 0.55, 0.65 run at about 0.7, 1.0 and 1.26 m/s.
CAMPAIGN_DEFAULTS = CampaignDefaults(thrusts=(0.45, 0.55, 0.65), axes=("yaw",),
                                     training_amplitude=0.10, validation_amplitude=0.08)  # rad of equivalent rudder
GAIN_RANGES = {"angle_p_range": (0.0, 6.0), "rate_p_range": (0.0, 2.0), "rate_i_range": (0.0, 0.05),
               "rate_ff_range": (0.0, 0.0)}

PROFILE = AutopilotProfile(
    name="ardusub",
    # hold = ALT_HOLD; auto = AUTO (a mission, where learning during missions runs)
    modes={"manual": 19, "hold": 2, "guided": 4, "stabilize": 0, "poshold": 16, "auto": 3},
    channels={"rudder": 4, "elevator": 1, "thrust": 5, "vertical": 3},
    servo_outputs={},  # thrusters are mixed: read back by un-mixing (Strategy.on_snapshot)
    params={
        "heading_angle_p": "ATC_ANG_YAW_P", "heading_rate_p": "ATC_RAT_YAW_P", "heading_rate_i": "ATC_RAT_YAW_I",
        "heading_rate_d": "ATC_RAT_YAW_D", "heading_rate_ff": "ATC_RAT_YAW_FF", "heading_rate_imax": "ATC_RAT_YAW_IMAX",
        "pitch_p": "ATC_ANG_PIT_P", "gcs_sysid": "MAV_GCS_SYSID", "override_timeout": "RC_OVERRIDE_TIME",
        "system_id": "MAV_SYSID", "gcs_failsafe": "FS_GCS_ENABLE",
        # read, never written: AC_AttitudeControl's yaw rate and acceleration limits, for the
        # predicted steps (eq. A.2); 0 is "no limit"
        "turn_rate_max": "ATC_RATE_Y_MAX", "turn_accel_max": "ATC_ACCEL_Y_MAX",
        # and the set-point's input shaping (eq. A.2s): on where the rate feed-forward is
        "input_tc": "ATC_INPUT_TC", "yaw_slew_max": "ATC_SLEW_YAW", "rate_ff_enabled": "ATC_RATE_FF_ENAB",
        # bit 2 (value 4) sends the yaw rate loop's PID_TUNING (learning during missions; restored after)
        "pid_tuning_mask": "GCS_PID_MASK",
    },
    aliases={"gcs_sysid": ("SYSID_MYGCS",), "system_id": ("SYSID_THISMAV",)},
    # ATC_ACCEL_Y_MAX is in centidegrees/s², ATC_SLEW_YAW in centidegrees/s
    native_scales={"turn_accel_max": NativeScale(scale=100.0), "yaw_slew_max": NativeScale(scale=100.0)},
    marker_param="ATC_ANG_YAW_P",
    angle_full_scale_rad=0.35,
    pwm_half_range=400,
    thrust_pwm_zero=1500,  # forward channel is bidirectional: 1500 = stop, 1900 = full ahead
    thrust_pwm_full=1900,
    mass_servo=None,
    int_encoding="cast",
    heading_schedule="cascade",
    heading_controller="cascade",
    # AC_AttitudeControl_Sub sets ANG_YAW_P 6 (AC_ATC_SUB_ANGLE_P) and ACCEL_Y_MAX 110000 cdeg/s²; the rest
    # are AC_AttitudeControl's (INPUT_TC 0.15, SLEW_YAW 6000 cdeg/s, RATE_FF_ENAB 1, RATE_Y_MAX 0: no limit)
    shipped_gains={"ATC_ANG_YAW_P": 6.0, "ATC_RAT_YAW_P": 0.18, "ATC_RAT_YAW_I": 0.018, "ATC_RAT_YAW_FF": 0.0,
                   "ATC_RAT_YAW_IMAX": 0.222, "ATC_ACCEL_Y_MAX": 110000.0, "ATC_INPUT_TC": 0.15,
                   "ATC_SLEW_YAW": 6000.0, "ATC_RATE_FF_ENAB": 1.0},
    strategy="ardusub",
    # in AUTO the angle loop turns the vehicle toward the next waypoint through the yaw rate loop:
    # learning verifies that loop's tracking of the rates it is asked for (PID_TUNING axis YAW, sent
    # for GCS_PID_MASK bit 2, value 4: GCS_MAVLink_Sub.cpp send_pid_tuning). Its ``desired`` is the
    # rate PID's (5 Hz filtered) target in rad/s × 0.01, its ``achieved`` the gyro in deg/s.
    learning_verification="turn_rate",
    pid_tuning=PidTuningReport(mask_param="pid_tuning_mask", mask_bit=4, axis=3, desired_to_rad_s=100.0),
    rate_loop=ARDUSUB_RATE_LOOP,  # no FF applied, no integrator freeze (eq. A.2r)
    # the vectored frame yaws by differential thrust; a vehicle slows at AUTO's corners (SITL's ROV:
    # 1.0 → 0.5 m/s) while its yaw authority stays: learning's windows hold those corners
    yaw_from_thrusters=True,
    water_speed_sensor=False,
    depth_from_pressure=False,
    vehicle_kind="underwater",
    depth_setpoint=False,
    actuator_hold="zoh",
    train_full_window=True,
    gain_ranges=GAIN_RANGES,
    campaign_defaults=CAMPAIGN_DEFAULTS,
    thrust_meaning="the pilot's forward stick (RC 5, held by an override; 1 = full ahead)",
)

#: the base streams, GLOBAL_POSITION_INT (depth) and HOME_POSITION (the surface, see Strategy.depth),
#: and PID_TUNING (the yaw rate loop, once GCS_PID_MASK asks for it) at 25 Hz for learning during
#: missions: at the port's default EXTRA1 rate the verification missed a 1.4 Hz yaw limit cycle of
#: learned gains on SITL's ROV (±18 °/s, 10.5 °/s RMS of tracking error in its log; a lane's segment
#: read 1.9 °/s) and kept them (measured)
STREAMS = {30: 50.0, 36: 50.0, 32: 10.0, 33: 10.0, 74: 10.0, 242: 0.5, 194: 25.0}

ACRO_YAW_P_DEFAULT = 3.375  # ArduSub's ACRO_YAW_P define: MANUAL's yaw scale is ACRO_YAW_P / this
RELEASE_AFTER_S = 0.25  # a centred stick is held this long (vehicle time) before it is released
VERTICAL_AVERAGE_S = 10.0  # time constant of ALT_HOLD's mean vertical thrust (its depth loop swings ±0.3)
DEPTH_STICK_GAIN = 0.3  # MANUAL: throttle (±1) per metre of depth error, around ALT_HOLD's mean
DEPTH_STICK_LIMIT = 0.3  # the most throttle the depth stick adds
PILOT_PRESENCE_S = 1.0  # vehicle seconds between "no change" overrides (FS_PILOT_TIMEOUT is 3 s)


class Strategy(ArduPilotStrategy):
    streams = STREAMS
    refresh_s = 1.0

    def __init__(self, ports) -> None:
        super().__init__(ports)
        self.heading = math.nan
        self._sent_at = -math.inf
        self._gcs_heartbeat_at = -math.inf
        self._pilot_at = -math.inf
        self._vertical_mean = math.nan  # mean ALT_HOLD throttle (±1), from motors 5/6
        self._vertical_at = math.nan
        self._manual_yaw_scale: float | None = None  # ACRO_YAW_P / 3.375
        self._release_at: dict[str, float] = {}  # centred sticks -> vehicle time to release them
        self._manual_depth = math.nan  # the depth MANUAL was entered at (the throttle stick keeps it)
        self._home_altitude_mm: float | None = None  # HOME_POSITION.altitude (mm above sea level)
        self._altitude_mm: float | None = None  # GLOBAL_POSITION_INT.alt
        ports.transport.on("HOME_POSITION", self._on_home_position)
        ports.transport.on("GLOBAL_POSITION_INT", self._on_global_position)

    def _in_hold(self) -> bool:
        return self.in_mode("hold")

    def _in_manual(self) -> bool:
        return self.in_mode("manual")

    def _on_home_position(self, msg) -> None:
        if self.ports.transport.from_vehicle(msg):
            self._home_altitude_mm = msg.altitude

    def _on_global_position(self, msg) -> None:
        if self.ports.transport.from_vehicle(msg):
            self._altitude_mm = msg.alt

    # ------------------------------------------------------------------ set-points
    def set_heading(self, heading: float) -> None:
        self.heading = heading
        self._send()

    def set_thrust(self, thrust_level: float) -> None:
        """The thrust level is the pilot's forward stick here (RC 5, held by an override)."""
        if not 0.0 <= thrust_level <= 1.0:
            raise ValueError(f"thrust level {thrust_level!r} outside 0..1")
        self._release_at.pop("thrust", None)
        self.ports.overrides.override("thrust", thrust_level)

    def set_depth(self, depth: float) -> None:
        latest = self.latest()
        here = latest.depth if latest is not None else math.nan
        if not (math.isfinite(here) and abs(here - depth) <= 0.5):
            raise self._cannot(f"depth target: ALT_HOLD holds the depth it is entered at ({here:.2f} m), "
                               f"not {depth:.2f} m; bring the vehicle there first or run without a depth")

    def forget_targets(self) -> None:
        """After a restore the procedure's heading is no longer refreshed (ALT_HOLD then holds the
        heading it has, as it does without a companion)."""
        self.heading = math.nan

    def release_after_crash(self, actuators: list[str]) -> None:
        """ArduSub keeps a released override's last value: each stick a dead companion may have
        held is centred, then released ``RELEASE_AFTER_S`` later (as :meth:`release` does)."""
        for actuator in actuators:
            self.ports.overrides.override_raw(actuator, STICK_CENTRE)
            self._release_at[actuator] = self.now + RELEASE_AFTER_S

    def on_reboot(self) -> None:
        super().on_reboot()
        self._release_at.clear()  # the old boot's sticks: nothing is held on the new one
        self._manual_depth = math.nan

    def _send(self) -> None:
        if not self._in_hold() or not math.isfinite(self.heading):
            return
        self.send_attitude_target(yaw_quaternion(self.heading), 0.5, ignore_thrust=True)
        self._sent_at = self.now

    def mode_changed(self, neutral: str) -> None:
        if self._in_hold():  # MANUAL's sticks are not ALT_HOLD's: centre them, then give them back
            self._centre_and_release("rudder")
            self._centre_and_release("vertical")
        self._send()

    # ------------------------------------------------------------------ excitation
    def override(self, actuator: str, value: float) -> None:
        self._release_at.pop(actuator, None)
        if actuator == "rudder" and self._in_hold():
            scale = self._yaw_scale()
            latest = self.latest()
            self._manual_depth = latest.depth if latest is not None else math.nan
            self._release_at.pop("vertical", None)
            self.ports.overrides.override_raw("vertical", throttle_stick(self._vertical_mean))  # before the switch
            self.ports.overrides.override(actuator, value / scale)
            self.ports.modes.set_mode("manual")
            return
        if actuator == "rudder" and self._in_manual():
            value /= self._yaw_scale()
        self.ports.overrides.override(actuator, value)

    def release(self, actuator: str | None) -> None:
        if actuator == "rudder" and self._in_manual():
            self.ports.overrides.override(actuator, 0.0)  # MANUAL: centred yaw stick, a known zero output
            return
        names = [actuator] if actuator is not None else [name for name in self.profile.channels
                                                        if self.ports.overrides.holds(name)]
        for name in names:
            self._centre_and_release(name)

    def _centre_and_release(self, actuator: str) -> None:
        """Centre the stick, and release it ``RELEASE_AFTER_S`` later: ArduSub keeps a released
        override's last value, and a centring and a release that arrive within one of its loops
        leave the stick where it was (measured: a descent demand outlived its release)."""
        if not self.ports.overrides.holds(actuator):
            self.ports.overrides.release(actuator)
            return
        self.ports.overrides.override_raw(actuator, STICK_CENTRE)
        self._release_at[actuator] = self.now + RELEASE_AFTER_S

    def _release_centred(self, now: float) -> None:
        for actuator, due in list(self._release_at.items()):
            if now < due:
                continue
            del self._release_at[actuator]
            if self.ports.overrides.held_pwm(actuator) == STICK_CENTRE:
                self.ports.overrides.release(actuator)

    def _yaw_scale(self) -> float:
        """MANUAL's yaw scale ACRO_YAW_P / 3.375, read once (1 when the vehicle does not answer)."""
        if self._manual_yaw_scale is None:
            try:
                value = self.ports.parameters.get_param("ACRO_YAW_P", retries=2)
            except ParamTimeout:
                value = ACRO_YAW_P_DEFAULT
            self._manual_yaw_scale = value / ACRO_YAW_P_DEFAULT if value > 0 else 1.0
        return self._manual_yaw_scale

    # ------------------------------------------------------------------ upkeep
    def on_snapshot(self, telemetry: Telemetry) -> Telemetry:
        now = telemetry.time_s
        if now - self._gcs_heartbeat_at >= 1.0:
            self.send_gcs_heartbeat()
            self._gcs_heartbeat_at = now
        if self.ports.overrides.pending:
            self._pilot_at = now  # the link refreshes what is held with this snapshot
        elif now - self._pilot_at >= PILOT_PRESENCE_S:
            # the pilot is present, no stick moves: an override whose every channel says "ignore"
            self.ports.overrides.no_change()
            self._pilot_at = now
        self._release_centred(now)
        if self._in_hold() and now - self._sent_at >= self.refresh_s:
            self._send()
        mixed = unmix_vectored(self.ports.telemetry.servo_pwm())
        if mixed is None:
            return telemetry
        if self._in_hold() and self.ports.announcements.armed and math.isfinite(mixed.throttle):
            self._average_vertical(now, mixed.throttle)
        depth = self.depth(telemetry.depth)
        if self._in_manual():
            self._hold_depth(depth)
        return replace(telemetry, rudder=mixed.yaw * self.profile.angle_full_scale_rad,
                       thrust_ratio=max(0.0, mixed.forward), depth=depth)

    def depth(self, reported: float) -> float:
        """Depth below the surface: home's altitude minus the vehicle's (both above mean sea level).

        ArduSub puts home at the surface (its depth sensor's zero) and reports as relative_alt the
        EKF's down position from the EKF origin minus home's altitude above sea level: right when
        the origin was set at the surface (a GPS fix only comes there), off by the origin's depth
        otherwise (SITL gives a fix under water: measured 0.0 m at 2 m). GLOBAL_POSITION_INT.alt is
        the origin's altitude minus that down position, so home minus it is the depth either way.
        Before home is set, relative_alt is ArduSub's depth sensor reading: ``reported`` is kept."""
        if self._home_altitude_mm is None or self._altitude_mm is None:
            return reported
        return (self._home_altitude_mm - self._altitude_mm) / 1000.0

    def _hold_depth(self, depth: float) -> None:
        """MANUAL with the vertical stick held by this strategy: keep the depth MANUAL was entered at
        (the thesis excites the heading open loop with the depth loop closed). ALT_HOLD's mean
        thrust alone let the AUV rise 1.1 m in one record (its 10 s mean still swings ±0.03 of
        throttle, 2 N against 1.9 N of buoyancy; measured), and ArduSub's EKF re-aligned its yaw
        on the magnetometer in the middle of the record (a 2° heading jump)."""
        if not self.ports.overrides.holds("vertical") or "vertical" in self._release_at:
            return
        if not (math.isfinite(depth) and math.isfinite(self._manual_depth)):
            return
        correction = DEPTH_STICK_GAIN * (depth - self._manual_depth)  # deeper than wanted: climb
        correction = min(max(correction, -DEPTH_STICK_LIMIT), DEPTH_STICK_LIMIT)
        base = self._vertical_mean if math.isfinite(self._vertical_mean) else 0.0
        self.ports.overrides.override_raw("vertical", throttle_stick(base + correction))

    def _average_vertical(self, now: float, throttle: float) -> None:
        """First-order mean (``VERTICAL_AVERAGE_S``, vehicle time) of ALT_HOLD's vertical thrust."""
        if not math.isfinite(self._vertical_mean):
            self._vertical_mean = throttle
        elif now > self._vertical_at:
            weight = 1.0 - math.exp(-(now - self._vertical_at) / VERTICAL_AVERAGE_S)
            self._vertical_mean += weight * (throttle - self._vertical_mean)
        self._vertical_at = now
