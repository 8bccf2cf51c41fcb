"""PX4 underwater vehicles on ``uuv_att_control`` (the HippoCampus, airframe 1021 in SITL: four
forward thrusters), as seen live on PX4 1.18-dev SITL flying our AUV (SPEC §4; PX4's shared habits:
``px4``).

Which mode each phase uses (measured):

* **settle on course at a thrust**, and the **heading-step checks**: OFFBOARD (the neutral "hold")
  with SET_ATTITUDE_TARGET: the attitude from the quaternion (PX4's PD on the attitude error,
  ``UUV_YAW_P``/``UUV_YAW_D``), the thrust field the surge thrust (thrust_body x; measured: 0.5 →
  un-mixed forward 0.499, 0.86 m/s on our AUV). PX4 has no depth loop for a torpedo AUV (its
  ``uuv_pos_control`` pushes a heave force four forward thrusters cannot make), and our slightly
  buoyant AUV rose 5 m in 100 s: so the set-point's pitch holds the depth the vehicle was taken at
  (:meth:`Strategy.pitch_for_depth`, a PI on depth with vertical-speed damping, on vehicle time),
  as the thesis' autopilot does (depth → desired pitch). STABILIZED integrates the yaw stick into
  its heading and ACRO makes it a rate: neither takes a heading from the companion.
* **open-loop excitation**: MANUAL with ``UUV_STICK_MODE`` 1 (torpedo sticks), where yaw, pitch and
  throttle sticks are the yaw torque, the pitch torque (negated) and the surge thrust, scaled by
  ``UUV_MGM_YAW``/``_PITCH``/``_THRTL`` (measured: yaw 0.3 → un-mixed yaw 0.300 with gain 1). The
  thrust and the mean pitch torque of the holding mode are held, so the heading is excited open
  loop at constant thrust with the pitch trimmed as it was.

The yaw actuator is read back by un-mixing the four thruster outputs of SERVO_OUTPUT_RAW
(reversible, 1500 ± 500 µs) with the airframe's geometry (thrusters at y = ∓0.3, z = ∓0.3 m:
yaw factor −sign y, pitch factor sign z): yaw ±1 ↔ ±``angle_full_scale_rad`` of equivalent rudder
(PX4's allocation gives un-mixed yaw = yaw torque set-point, measured). Depth is below where PX4
set home (GLOBAL_POSITION_INT.relative_alt): PX4 has no notion of the water surface.
"""
from __future__ import annotations

import math
from dataclasses import replace

from companion.interface import Telemetry
from companion.link.autopilots.px4 import MODES, Px4Profile, Px4Strategy, Sticks
from companion.link.errors import ParamTimeout
from companion.link.profile import CampaignDefaults

#: the design's bounds (CascadeRules fields, companion.numerics.px4_gains): PX4 documents no range
#: for UUV_YAW_P/UUV_YAW_D (defaults 4 and 2); the design keeps them within ten times the defaults
GAIN_RANGES = {"angle_p_range": (0.0, 40.0), "rate_p_range": (0.0, 20.0)}

PROFILE = Px4Profile(
    name="px4-uuv",
    modes=MODES,
    channels={},  # no RC channel: the sticks are MANUAL_CONTROL (the strategy's)
    servo_outputs={},  # thrusters are mixed: read back by un-mixing (Strategy.complete)
    params={
        "heading_angle_p": "UUV_YAW_P", "heading_rate_d": "UUV_YAW_D", "pitch_p": "UUV_PITCH_P",
        "pitch_d": "UUV_PITCH_D", "torque_max": "UUV_TORQUE_SAT", "manual_yaw_gain": "UUV_MGM_YAW",
        "manual_pitch_gain": "UUV_MGM_PITCH", "manual_thrust_gain": "UUV_MGM_THRTL",
        "rc_loss_exceptions": "COM_RCL_EXCEPT", "system_id": "MAV_SYS_ID",
    },
    marker_param="SYS_AUTOSTART",  # PX4 only; rover and UUV are told apart by MAV_TYPE
    mav_types=(12,),  # MAV_TYPE_SUBMARINE
    angle_full_scale_rad=0.35,  # equivalent rudder at full yaw torque: a property of the vehicle
    int_encoding="bytewise",
    flown=True,  # campaign, gain check and restores run against PX4 SITL (tests/test_px4_sitl.py)
    heading_schedule="px4_uuv",
    heading_controller="px4_uuv",
    # uuv_att_control_params.yaml (the HippoCampus airframe sets none of them)
    shipped_gains={"UUV_YAW_P": 4.0, "UUV_YAW_D": 2.0, "UUV_TORQUE_SAT": 0.3},
    strategy="px4_uuv",
    water_speed_sensor=False,
    depth_from_pressure=False,
    depth_setpoint=False,
    actuator_hold="zoh",
    output_lead_s=0.005,
    train_full_window=True,
    gain_ranges=GAIN_RANGES,
    # each thruster saturates at ±1: forward + |yaw torque| stays below 1 with a 0.12 rad training
    # doublet (0.34 of torque at 0.35 rad full scale) at 0.65 of thrust. The doublet is as large as
    # that allows: PX4's heading of our AUV is noisy against the small turns a thrust differential
    # makes (validation R² 0.96-0.99 at 0.10 rad), and at 0.4 of thrust (0.58 m/s) a22 came out
    # 6-10 % large; 0.45, 0.55, 0.65 run at 0.72, 1.00 and 1.26 m/s (measured)
    campaign_defaults=CampaignDefaults(thrusts=(0.45, 0.55, 0.65), axes=("yaw",), training_amplitude=0.12,
                                       validation_amplitude=0.10),
    thrust_meaning="the surge thrust (SET_ATTITUDE_TARGET's thrust in OFFBOARD; 1 = full ahead)",
)

#: HippoCampus thrusters (y, z) in metres, all pushing along +x (airframe 1021, CA_ROTORn_P*)
ROTORS = ((-0.3, -0.3), (0.3, -0.3), (0.3, 0.3), (-0.3, 0.3))
MOTOR_PWM_CENTRE, MOTOR_PWM_HALF_RANGE = 1500.0, 500.0
#: SET_ATTITUDE_TARGET.type_mask: the attitude and the thrust (body rates ignored)
ATTITUDE_AND_THRUST = 0b0000_0111
#: depth hold on the pitch set-point (rad of pitch per metre, per metre·second, per m/s)
DEPTH_P, DEPTH_I, DEPTH_D = 0.15, 0.01, 0.5
PITCH_LIMIT = 0.2  # rad of pitch the depth hold may ask for
PITCH_TORQUE_AVERAGE_S = 5.0  # time constant of the mean pitch torque held in MANUAL


def unmix(pwm: list[float]) -> dict[str, float] | None:
    """Least-squares un-mix (Σ fᵢ·oᵢ / Σ fᵢ²) of thrusters 1–4 (µs) into forward, yaw and pitch
    (each ±1); None when one is missing or out of range."""
    outputs = []
    for value in list(pwm[:4]):
        if not (isinstance(value, (int, float)) and 800 <= value <= 2200):
            return None
        outputs.append((value - MOTOR_PWM_CENTRE) / MOTOR_PWM_HALF_RANGE)
    if len(outputs) < 4:
        return None
    factors = {"forward": [1.0] * 4, "yaw": [-math.copysign(1.0, y) for y, _ in ROTORS],
               "pitch": [math.copysign(1.0, z) for _, z in ROTORS]}
    return {axis: sum(f * o for f, o in zip(fs, outputs)) / sum(f * f for f in fs) for axis, fs in factors.items()}


def attitude_quaternion(pitch: float, yaw: float) -> list[float]:
    """(w, x, y, z) of zero roll, ``pitch`` (nose up +) and ``yaw`` (ZYX)."""
    cp, sp, cy, sy = math.cos(pitch / 2), math.sin(pitch / 2), math.cos(yaw / 2), math.sin(yaw / 2)
    return [cp * cy, -sp * sy, sp * cy, cp * sy]


class Strategy(Px4Strategy):
    AXES = {"rudder": "yaw", "thrust": "throttle"}

    def __init__(self, ports) -> None:
        super().__init__(ports)
        self.heading = math.nan
        self.thrust = math.nan
        self.gains = {"yaw": 1.0, "pitch": 1.0, "thrust": 1.0}  # UUV_MGM_*: manual stick -> torque/thrust
        self.depth_target = math.nan
        self.pitch_setpoint = 0.0
        self._integral = 0.0
        self._depth_at = math.nan
        self._pitch_torque = math.nan  # mean un-mixed pitch torque (held in MANUAL)
        self._torque_at = math.nan

    def prepare(self) -> None:
        for axis, name in (("yaw", "UUV_MGM_YAW"), ("pitch", "UUV_MGM_PITCH"), ("thrust", "UUV_MGM_THRTL")):
            try:
                value = self.ports.parameters.get_param(name)
            except ParamTimeout:
                continue
            self.gains[axis] = value if value > 0 else 1.0
        latest = self.latest()
        self.depth_target = latest.depth if latest is not None else math.nan
        self._integral, self._depth_at = 0.0, math.nan

    # ------------------------------------------------------------------ set-points
    def set_heading(self, heading: float) -> None:
        self.heading = heading
        if self.taken:
            self.send_target()

    def set_thrust(self, thrust_level: float) -> None:
        """The thrust level is the surge thrust (SET_ATTITUDE_TARGET's thrust)."""
        if not 0.0 <= thrust_level <= 1.0:
            raise ValueError(f"thrust level {thrust_level!r} outside 0..1")
        self.thrust = thrust_level
        if self.taken:
            self.send_target()

    def set_depth(self, depth: float) -> None:
        latest = self.latest()
        here = latest.depth if latest is not None else math.nan
        if not (math.isfinite(here) and abs(here - depth) <= 0.5):
            raise self._cannot(f"depth target: the companion holds the depth it took the vehicle at ({here:.2f} m "
                               f"below PX4's home), not {depth:.2f} m")

    def send_target(self) -> None:
        latest = self.latest()
        heading = self.heading
        if not math.isfinite(heading):
            heading = latest.yaw if latest is not None and math.isfinite(latest.yaw) else 0.0
        thrust = self.thrust
        if not math.isfinite(thrust):
            thrust = max(0.0, latest.thrust_ratio) if latest is not None and math.isfinite(latest.thrust_ratio) else 0.0
        now = self.now
        transport = self.ports.transport
        transport.mav.set_attitude_target_send(int(now * 1000) & 0xFFFFFFFF if math.isfinite(now) else 0,
                                               transport.system_id, transport.autopilot_component,
                                               ATTITUDE_AND_THRUST, attitude_quaternion(self.pitch_setpoint, heading),
                                               0.0, 0.0, 0.0, float(thrust))

    def pitch_for_depth(self, telemetry: Telemetry) -> float:
        """The pitch set-point that holds ``depth_target``: nose up when too deep (a PI on the depth
        error with damping on the vertical speed, integrated on vehicle time, clamped to
        ±``PITCH_LIMIT`` with the integral kept inside it)."""
        if not (math.isfinite(self.depth_target) and telemetry.finite("depth")):
            return 0.0
        error = telemetry.depth - self.depth_target
        if math.isfinite(self._depth_at) and telemetry.time_s > self._depth_at:
            self._integral += DEPTH_I * error * (telemetry.time_s - self._depth_at)
            self._integral = max(-PITCH_LIMIT, min(PITCH_LIMIT, self._integral))
        self._depth_at = telemetry.time_s
        sink = telemetry.vel_down if telemetry.finite("vel_down") else 0.0
        return max(-PITCH_LIMIT, min(PITCH_LIMIT, DEPTH_P * error + self._integral + DEPTH_D * sink))

    # ------------------------------------------------------------------ sticks
    def stick_value(self, actuator: str, value: float) -> float:
        if actuator == "rudder":
            stick = value / self.profile.angle_full_scale_rad / self.gains["yaw"]
            if abs(stick) > 1.0:
                raise self._cannot(f"yaw stick for {value:.3f} rad: UUV_MGM_YAW {self.gains['yaw']:g} is too small")
            return stick
        return value / self.gains["thrust"]

    def stick_rudder(self, sticks: Sticks) -> float:
        return sticks.yaw * self.gains["yaw"] * self.profile.angle_full_scale_rad

    def held_sticks(self, telemetry: Telemetry) -> Sticks:
        if not telemetry.finite("rudder", "thrust_ratio"):
            raise self._cannot("thruster read-back (SERVO_OUTPUT_RAW 1-4): the outputs cannot be held")
        torque = self._pitch_torque if math.isfinite(self._pitch_torque) else 0.0
        return Sticks(yaw=self.stick_value("rudder", telemetry.rudder), throttle=self.stick_value("thrust", telemetry.thrust_ratio),
                      pitch=-torque / self.gains["pitch"])  # MANUAL's pitch torque is −stick × UUV_MGM_PITCH

    # ------------------------------------------------------------------ read-back
    def complete(self, telemetry: Telemetry) -> Telemetry:
        axes = unmix(self.ports.telemetry.servo_pwm())
        if axes is None:
            return telemetry
        now = telemetry.time_s
        if self.taken and self._excitation is None and not self.in_mode("manual"):
            self.pitch_setpoint = self.pitch_for_depth(telemetry)
            if not math.isfinite(self._pitch_torque) or not now > self._torque_at:
                self._pitch_torque = axes["pitch"]
            else:
                weight = 1.0 - math.exp(-(now - self._torque_at) / PITCH_TORQUE_AVERAGE_S)
                self._pitch_torque += weight * (axes["pitch"] - self._pitch_torque)
            self._torque_at = now
        return replace(telemetry, rudder=axes["yaw"] * self.profile.angle_full_scale_rad,
                       thrust_ratio=max(0.0, axes["forward"]))
