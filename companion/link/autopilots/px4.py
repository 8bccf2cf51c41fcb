"""What every PX4 vehicle shares, as the companion meets it (SPEC §4), measured on PX4 1.18-dev SITL.

* **Modes** pack a main and a sub mode: ``custom_mode = main << 16 | sub << 24``
  (``px4_custom_mode.h``: MANUAL 65536, POSCTL 196608, ACRO 327680, OFFBOARD 393216, STABILIZED
  458752, Hold = AUTO/LOITER 0x03040000, the mode PX4 boots in); MAV_CMD_DO_SET_MODE carries
  (CUSTOM_MODE_ENABLED, main, sub) (:class:`Px4Profile`).
* **Sticks** are MANUAL_CONTROL (``mavlink_receiver.cpp``): pitch = x/1000, roll = y/1000,
  yaw = r/1000, throttle = z/500 − 1 (z 500 is zero throttle), from any system id. PX4 drops them
  after ``COM_RC_LOSS_T`` (0.5 s) and then fails safe (``NAV_RCL_ACT``, default Return), unless the
  mode is excepted by ``COM_RCL_EXCEPT`` (bit 0 mission, 1 Hold and the other auto modes,
  2 offboard) or PX4 had no manual control when it was armed. So the strategy streams its sticks
  (:class:`Sticks`) every ``STICK_PERIOD_S`` of vehicle time from the moment it takes the vehicle
  until the vehicle is back in the mode it was found in, and only then stops: measured, a companion
  that stopped its sticks in Hold set off PX4's Return (Hold 5 s, Return, landed, disarmed).
  Before taking a vehicle that has no manual control of its own (SYS_STATUS: no RC receiver
  present), it refuses unless ``COM_RCL_EXCEPT`` excepts the mode it was found in: otherwise
  stopping its sticks afterwards would leave PX4 failing safe, not as found.
* **OFFBOARD** is accepted only while set-points already stream (the offboard signal, lost after
  ``COM_OF_LOSS_T``, 1 s): the strategy starts them before it asks for any mode
  (``before_mode_change``) and refreshes them every ``SETPOINT_PERIOD_S``; when the companion goes
  away PX4's offboard-loss failsafe (``COM_OBL_RC_ACT``) acts as designed.
* **Open-loop excitation** is MANUAL, where the sticks reach the actuators with no dead zone
  (measured: roll 0.03 → steering 0.030; ``RO_YAW_STICK_DZ`` applies only in the stabilised modes).
  At the first rudder override the sticks that reproduce the outputs the holding mode had (read
  back) are set, then MANUAL is entered; releasing the rudder keeps the steering it had before the
  doublet, so the whole record is open loop; the next "hold" ends the excitation.
* **Integer parameters** are bytewise (AUTOPILOT_VERSION.capabilities says so; measured 59647).
* **Arming**: PX4 gates arming on the throttle stick only in the manual modes (a rover's within
  ±0.2, other vehicles' below −0.8); arm the vehicle in Hold, where no stick is needed.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

from companion.interface import Telemetry
from companion.link.autopilots.base import AutopilotStrategy
from companion.link.errors import ParamTimeout, ProfileError
from companion.link.profile import MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, AutopilotProfile

log = logging.getLogger(__name__)

#: PX4 main modes and auto sub modes (px4_custom_mode.h)
MAIN_MANUAL, MAIN_ALTCTL, MAIN_POSCTL, MAIN_AUTO, MAIN_ACRO, MAIN_OFFBOARD, MAIN_STABILIZED = 1, 2, 3, 4, 5, 6, 7
SUB_LOITER, SUB_MISSION, SUB_RTL = 3, 4, 5
#: main modes that need the companion's sticks or set-points streaming (manual-control or offboard modes)
STREAMED_MAIN_MODES = (MAIN_MANUAL, MAIN_ALTCTL, MAIN_POSCTL, MAIN_ACRO, MAIN_OFFBOARD, MAIN_STABILIZED)
#: SYS_STATUS sensor bit of manual control (PX4 sets it while a stick source is valid)
SENSOR_RC_RECEIVER = 1 << 16
#: COM_RCL_EXCEPT bits (failsafe.cpp isFailsafeIgnored)
RCL_EXCEPT_MISSION, RCL_EXCEPT_AUTO, RCL_EXCEPT_OFFBOARD = 1, 2, 4


def custom_mode(main: int, sub: int = 0) -> int:
    """PX4's custom_mode of a main and sub mode."""
    return (main & 0xFF) << 16 | (sub & 0xFF) << 24


def main_sub(number: int) -> tuple[int, int]:
    """(main, sub) of a PX4 custom_mode."""
    return (number >> 16) & 0xFF, (number >> 24) & 0xFF


#: neutral mode names; "hold" (and "guided") is the companion's holding mode, OFFBOARD; PX4's own
#: Hold (AUTO/LOITER) is "loiter"
MODES = {"manual": custom_mode(MAIN_MANUAL), "hold": custom_mode(MAIN_OFFBOARD), "guided": custom_mode(MAIN_OFFBOARD),
         "acro": custom_mode(MAIN_ACRO), "stabilized": custom_mode(MAIN_STABILIZED),
         "position": custom_mode(MAIN_POSCTL), "altitude": custom_mode(MAIN_ALTCTL),
         "loiter": custom_mode(MAIN_AUTO, SUB_LOITER), "mission": custom_mode(MAIN_AUTO, SUB_MISSION),
         "rtl": custom_mode(MAIN_AUTO, SUB_RTL)}


def rcl_excepted(number: int, mask: int) -> bool:
    """Whether PX4 ignores the loss of manual control in mode ``number`` (COM_RCL_EXCEPT ``mask``)."""
    main, sub = main_sub(number)
    if main == MAIN_AUTO:
        return bool(mask & (RCL_EXCEPT_MISSION if sub == SUB_MISSION else RCL_EXCEPT_AUTO))
    return main == MAIN_OFFBOARD and bool(mask & RCL_EXCEPT_OFFBOARD)


@dataclass(frozen=True)
class Px4Profile(AutopilotProfile):
    """A PX4 profile: DO_SET_MODE carries the main and sub mode as parameters 2 and 3."""

    def mode_command_params(self, custom_mode: int) -> tuple[float, ...]:
        main, sub = main_sub(custom_mode)
        return float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub)


def _stick(value: float, low: int, high: int, scale: float, offset: float = 0.0) -> int:
    if not math.isfinite(value):
        raise ValueError(f"non-finite stick value {value!r}")
    return int(round(min(max(value * scale + offset, low), high)))


@dataclass(frozen=True)
class Sticks:
    """MANUAL_CONTROL's four axes in PX4's units: pitch, roll, yaw in ±1, throttle in ±1 (0 = none)."""

    pitch: float = 0.0
    roll: float = 0.0
    throttle: float = 0.0
    yaw: float = 0.0

    def fields(self) -> tuple[int, int, int, int]:
        """(x, y, z, r) of MANUAL_CONTROL: x = 1000·pitch, y = 1000·roll, z = 500·(throttle + 1),
        r = 1000·yaw, each clamped to its range; ValueError for a non-finite axis."""
        return (_stick(self.pitch, -1000, 1000, 1000.0), _stick(self.roll, -1000, 1000, 1000.0),
                _stick(self.throttle, 0, 1000, 500.0, 500.0), _stick(self.yaw, -1000, 1000, 1000.0))


class Px4Strategy(AutopilotStrategy):
    """Sticks and offboard set-points streamed on vehicle time, the excitation in MANUAL, and the
    release that stops streaming only once the vehicle is back as found (module docstring).
    Subclasses say how actuators map to sticks and which set-point holds the vehicle."""

    #: ATTITUDE and SERVO_OUTPUT_RAW at 50 Hz: PX4 sends each SERVO_OUTPUT_RAW right after the
    #: ATTITUDE of the same time stamp (measured): the snapshot pairs them by those stamps.
    #: PX4's onboard link also streams HIGHRES_IMU and ATTITUDE_QUATERNION at 50 Hz, ODOMETRY at 30,
    #: ALTITUDE and GPS_RAW_INT at 10: stopped (0), they were 60 % of the messages decoded, and a
    #: companion at a 10x desk speed-up fell seconds behind the stream (measured)
    streams = {30: 50.0, 36: 50.0, 32: 10.0, 33: 10.0, 74: 10.0, 1: 2.0,
               105: 0.0, 31: 0.0, 331: 0.0, 141: 0.0, 24: 0.0}
    STICK_PERIOD_S = 0.1  # vehicle seconds between MANUAL_CONTROL (PX4 drops them after COM_RC_LOSS_T)
    SETPOINT_PERIOD_S = 0.1  # between offboard set-points (OFFBOARD is left after COM_OF_LOSS_T)
    RELEASE_GRACE_S = 10.0  # released sticks stop anyway after this long outside the mode found
    IGNORED_AFTER_S = 1.0  # MANUAL output unlike the sticks for this long: PX4 takes another source
    IGNORED_TOLERANCE = 0.005  # rad of rudder between a stick asked for and the read-back (a few µs of PWM)

    def __init__(self, ports) -> None:
        super().__init__(ports)
        self.sticks: Sticks | None = None  # None: not streaming
        self.found_mode: int | None = None  # the custom_mode the vehicle was taken in
        self.manual_control_present: bool | None = None  # SYS_STATUS: a stick source PX4 uses
        self._excitation: dict | None = None
        self._releasing_since: float | None = None
        self._sticks_sent_at = -math.inf
        self._target_sent_at = -math.inf
        self._unlike_since: float | None = None
        self._ignored: str | None = None  # why PX4 does not obey the sticks (raised at the next excitation command)
        ports.transport.on("SYS_STATUS", self._on_sys_status)

    # ------------------------------------------------------------------ what subclasses supply
    def prepare(self) -> None:
        """Read what the strategy needs from the vehicle when it takes it (parameters)."""

    def neutral_sticks(self) -> Sticks:
        """The sticks while nothing is excited: centred, no throttle."""
        return Sticks()

    def held_sticks(self, telemetry: Telemetry) -> Sticks:
        """The sticks that reproduce in MANUAL the outputs the holding mode has now."""
        raise self._cannot("open-loop excitation")

    #: neutral actuator -> the Sticks axis that drives it in MANUAL
    AXES: dict[str, str] = {}

    def stick_value(self, actuator: str, value: float) -> float:
        """The stick position (PX4 units) that drives ``actuator`` to ``value`` (rad, thrust ratio)."""
        raise self._cannot(f"{actuator} stick")

    def stick_rudder(self, sticks: Sticks) -> float:
        """The rudder (rad) MANUAL makes of ``sticks``."""
        return math.nan

    def with_actuator(self, sticks: Sticks, actuator: str, value: float) -> Sticks:
        """``sticks`` with ``actuator`` put on its stick."""
        if actuator not in self.AXES:
            raise self._cannot(f"{actuator} stick")
        return replace(sticks, **{self.AXES[actuator]: self.stick_value(actuator, value)})

    def send_target(self) -> None:
        """Send the holding mode's set-point once."""

    # ------------------------------------------------------------------ taking the vehicle
    @property
    def taken(self) -> bool:
        return self.sticks is not None

    def _on_sys_status(self, msg) -> None:
        if self.ports.transport.from_autopilot(msg):
            self.manual_control_present = bool(msg.onboard_control_sensors_present & SENSOR_RC_RECEIVER)

    def take(self) -> None:
        """Start streaming sticks and set-points (once), after the preflight check."""
        if self.taken:
            return
        found = self.ports.announcements.custom_mode
        if not self.manual_control_present:
            try:
                mask = int(self.ports.parameters.get_param("COM_RCL_EXCEPT"))
            except ParamTimeout:
                mask = 0
            if found is None or not rcl_excepted(found, mask):
                raise ProfileError(
                    f"PX4 has no manual control of its own and fails safe (NAV_RCL_ACT) when the companion's sticks "
                    f"stop in mode {self.profile.mode_name(found or 0)!r}: set COM_RCL_EXCEPT to except it "
                    f"(now {mask}; bit 1 = Hold and the other auto modes), or give PX4 a stick source")
        self.prepare()
        self.found_mode, self.sticks, self._releasing_since, self._ignored = found, self.neutral_sticks(), None, None
        log.info("PX4 taken in %s: streaming sticks and set-points", self.profile.mode_name(found or 0))
        self._send_sticks()
        self.send_target()
        self._target_sent_at = self.now

    def before_mode_change(self, neutral: str) -> None:
        """Take the vehicle before a mode that needs the companion's sticks or set-points (not
        before a restore to an auto mode: that needs nothing)."""
        if main_sub(self.profile.mode_number(neutral))[0] in STREAMED_MAIN_MODES:
            self.take()

    def _stop(self, why: str) -> None:
        log.info("PX4 released (%s): sticks and set-points stopped", why)
        self.sticks, self._excitation, self._releasing_since = None, None, None

    def _companion_has_mode(self) -> bool:
        commanded = self.ports.modes.commanded
        return commanded is not None and self.ports.announcements.custom_mode == self.profile.mode_number(commanded)

    # ------------------------------------------------------------------ excitation
    def override(self, actuator: str, value: float) -> None:
        if self._ignored is not None:
            raise ProfileError(self._ignored)
        self.take()
        if self._excitation is None and not self.in_mode("manual"):
            latest = self.latest()
            if latest is None:
                raise self._cannot("excitation before the first telemetry")
            held = self.held_sticks(latest)
            self._excitation = {"held": held, "asked": [self.stick_rudder(held)]}
            self.sticks = self.with_actuator(held, actuator, value)
            self._send_sticks()  # before the switch: MANUAL never sees a stopped stick
            self.ports.modes.set_mode("manual")
            return
        self.sticks = self.with_actuator(self._streaming(), actuator, value)
        self._send_sticks()

    def _streaming(self) -> Sticks:
        """The sticks being streamed (the vehicle is taken: :meth:`take` started them)."""
        if self.sticks is None:
            raise ProfileError("PX4: no sticks are streamed before the vehicle is taken")
        return self.sticks

    def release(self, actuator: str | None) -> None:
        if not self.taken:
            return
        if actuator is not None and self._ignored is not None:
            raise ProfileError(self._ignored)
        if actuator is not None:  # open loop at what the holding mode had (or centred)
            base = self._excitation["held"] if self._excitation is not None else self.neutral_sticks()
            axis = self.AXES.get(actuator)
            if axis is not None:
                self.sticks = replace(self._streaming(), **{axis: getattr(base, axis)})
                self._send_sticks()
            return
        if not self._companion_has_mode():  # the pilot chose a mode: never fight it
            self._stop("someone else chose the mode")
            return
        self._releasing_since = self.now
        if self._excitation is not None:
            self.ports.modes.set_mode("hold")  # mode_changed ends the excitation
        self.sticks = self.neutral_sticks()
        self._send_sticks()
        if self.ports.announcements.custom_mode == self.found_mode:
            self._stop("in the mode it was found in")

    def mode_changed(self, neutral: str) -> None:
        if not self.taken:
            return
        if self._excitation is not None and not self.in_mode("manual"):
            self._excitation = None
            self.sticks = self.neutral_sticks()
            self._send_sticks()
        if self._releasing_since is not None and self.ports.announcements.custom_mode == self.found_mode:
            self._stop("back in the mode it was found in")
            return
        self.send_target()
        self._target_sent_at = self.now

    # ------------------------------------------------------------------ upkeep
    def _send_sticks(self) -> None:
        if self.sticks is None:
            return
        if self._excitation is not None:  # every rudder asked for in this excitation (the check's)
            asked = self._excitation["asked"]
            rudder = self.stick_rudder(self.sticks)
            if math.isfinite(rudder) and asked[-1] != rudder:
                asked.append(rudder)
        x, y, z, r = self.sticks.fields()
        log.debug("sticks at %.2f: x %d y %d z %d r %d (%s)", self.now, x, y, z, r, self.ports.announcements.mode)
        transport = self.ports.transport
        transport.mav.manual_control_send(transport.system_id, x, y, z, r, 0)
        self._sticks_sent_at = self.now

    def on_snapshot(self, telemetry: Telemetry) -> Telemetry:
        telemetry = self.complete(telemetry)
        if not self.taken:
            return telemetry
        now = telemetry.time_s
        if self._releasing_since is not None and now - self._releasing_since > self.RELEASE_GRACE_S:
            log.warning("PX4 not back in its found mode %.0f s after the release", self.RELEASE_GRACE_S)
            self._stop("grace period over")
            return telemetry
        if now - self._sticks_sent_at >= self.STICK_PERIOD_S - 1e-3:  # vehicle times are ms: no float drift
            self._send_sticks()
        if now - self._target_sent_at >= self.SETPOINT_PERIOD_S - 1e-3:
            self.send_target()
            self._target_sent_at = now
        self._check_sticks_obeyed(telemetry)
        return telemetry

    def complete(self, telemetry: Telemetry) -> Telemetry:
        """Complete a snapshot (a read-back to un-mix); unchanged by default."""
        return telemetry

    def _check_sticks_obeyed(self, telemetry: Telemetry) -> None:
        """In MANUAL the rudder must be one the sticks asked for during this excitation; if it is
        none of them for ``IGNORED_AFTER_S``, PX4 takes its sticks from another source
        (COM_RC_IN_MODE keeps the first valid one): the next excitation command raises (a
        behaviour's step, so the runner aborts and restores). Any stick asked for counts, not only
        the last: a companion that lags the stream sees each change late (measured: 1.4 s at 10x
        on a loaded machine), while sticks PX4 ignores match none."""
        excitation = self._excitation
        if excitation is None or self._releasing_since is not None or telemetry.mode != "manual":
            self._unlike_since = None
            return
        asked = excitation["asked"]
        if not math.isfinite(telemetry.rudder) or not asked or \
                min(abs(value - telemetry.rudder) for value in asked) <= self.IGNORED_TOLERANCE:
            self._unlike_since = None
            return
        if self._unlike_since is None:
            self._unlike_since = telemetry.time_s
        elif telemetry.time_s - self._unlike_since > self.IGNORED_AFTER_S and self._ignored is None:
            self._ignored = (f"PX4 ignores the companion's sticks in MANUAL (rudder {telemetry.rudder:.3f} rad, "
                             f"none of the {len(asked)} asked for): another manual-control source has priority "
                             "(COM_RC_IN_MODE)")
            log.error(self._ignored)
