"""One autopilot's notions, as data: modes, channels, parameters, PWM conversions (SPEC C1, §4).

A profile says which custom_mode number is "manual", "hold" (the heading-and-depth/speed holding
mode) and "guided", which RC channel drives the rudder / elevator / thrust, which servo output
reports each actuator, how PWM converts to SI, and which autopilot parameter holds each neutral
quantity (``heading_p``, ``gcs_sysid``, ``override_timeout`` ...). How the autopilot is
*commanded* (set-points, excitation, telemetry sources) is its strategy, in the module named by
``strategy`` under ``companion.link.autopilots``: one module per autopilot holds both.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from companion.link.actuation import Actuation
from companion.link.errors import ProfileError
from companion.numerics.rate_loop import ARDUROVER_RATE_LOOP, RateLoopForm

#: PWM values that mean "no data" in SERVO_OUTPUT_RAW / RC fields, and the plausible PWM range.
PWM_VALID_MIN = 800
PWM_VALID_MAX = 2200
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1



@dataclass(frozen=True)
class NativeScale:
    """``native = neutral·scale + offset`` (e.g. a ratio written as percent, a trim as PWM)."""

    scale: float = 1.0
    offset: float = 0.0

    def to_native(self, neutral_value: float) -> float:
        return neutral_value * self.scale + self.offset

    def to_neutral(self, native_value: float) -> float:
        return (native_value - self.offset) / self.scale


@dataclass(frozen=True)
class CampaignDefaults:
    """What a campaign on one autopilot flies unless the user says otherwise: thrust levels, axes
    and doublet amplitudes it can fly (None: the campaign's own default)."""

    thrusts: tuple[float, ...] | None = None
    axes: tuple[str, ...] | None = None
    training_amplitude: float | None = None  # rad (of equivalent rudder)
    validation_amplitude: float | None = None

    def __post_init__(self) -> None:
        from companion.checks import check_thrust_levels

        if self.thrusts is not None:
            check_thrust_levels(self.thrusts, "CampaignDefaults.thrusts")
        for name in ("training_amplitude", "validation_amplitude"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float)) and 0.0 < value < 1.0):
                raise ValueError(f"CampaignDefaults.{name} must be in (0, 1) rad, not {value!r}")

    def given(self) -> dict:
        """The fields this autopilot sets (name → value)."""
        return {name: value for name, value in (("thrusts", self.thrusts), ("axes", self.axes),
                                                ("training_amplitude", self.training_amplitude),
                                                ("validation_amplitude", self.validation_amplitude))
                if value is not None}


@dataclass(frozen=True)
class PidTuningReport:
    """Which PID_TUNING message reports the heading's rate loop, how to ask for it and its units.

    ``mask_param`` is the neutral name of the parameter (``GCS_PID_MASK``) whose bit ``mask_bit``
    makes the autopilot send it; ``axis`` is its PID_TUNING_AXIS (MAVLink common: 3 YAW, 5 STEER);
    ``desired_to_rad_s`` and ``achieved_to_rad_s`` turn the message's ``desired`` and ``achieved``
    into rad/s (deg/s: π/180; ArduSub 4.7 sends its yaw rate target in rad/s × 0.01: 100)."""

    mask_param: str
    mask_bit: int
    axis: int
    desired_to_rad_s: float = math.pi / 180.0
    achieved_to_rad_s: float = math.pi / 180.0

    def __post_init__(self) -> None:
        if not self.mask_param:
            raise ValueError("PidTuningReport.mask_param: the neutral name of the mask parameter is needed")
        if not (isinstance(self.mask_bit, int) and self.mask_bit > 0 and self.mask_bit & (self.mask_bit - 1) == 0):
            raise ValueError(f"PidTuningReport.mask_bit must be one bit (1, 2, 4, ...), not {self.mask_bit!r}")
        if not (isinstance(self.axis, int) and 1 <= self.axis <= 6):
            raise ValueError(f"PidTuningReport.axis must be a PID_TUNING_AXIS (1..6), not {self.axis!r}")
        for name, value in (("desired_to_rad_s", self.desired_to_rad_s), ("achieved_to_rad_s", self.achieved_to_rad_s)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"PidTuningReport.{name} must be a finite factor > 0, not {value!r}")

    def with_bit(self, mask: float) -> float:
        """The mask parameter's value ``mask`` with this report's bit set."""
        return float(int(mask) | self.mask_bit)


@dataclass(frozen=True)
class SpeedLoopReport:
    """Which PID_TUNING message reports the autopilot's speed loop (the one ``companion run --learn``
    designs and verifies, eq. L.4): the mask parameter's neutral name and the bit that asks for it,
    and its PID_TUNING_AXIS. Its ``desired`` is the speed the loop is asked for after its
    acceleration limit and ``achieved`` the speed it measured, both in m/s (ArduRover 4.7:
    ``GCS_MAVLINK_Rover::send_pid_tuning`` sends ``AR_AttitudeControl``'s throttle-speed PID info for
    GCS_PID_MASK bit value 2 on axis 4, PID_TUNING_ACCZ)."""

    mask_param: str
    mask_bit: int
    axis: int

    def __post_init__(self) -> None:
        PidTuningReport(self.mask_param, self.mask_bit, self.axis)  # the same checks

    def with_bit(self, mask: float) -> float:
        """The mask parameter's value ``mask`` with this report's bit set."""
        return float(int(mask) | self.mask_bit)


@dataclass(frozen=True)
class AutopilotProfile:
    """How the product's neutral notions map onto one autopilot (see the module docstring)."""

    name: str
    modes: dict[str, int]
    channels: dict[str, int]  # neutral actuator -> RC input channel (1-based)
    params: dict[str, str]  # neutral -> autopilot parameter name
    servo_outputs: dict[str, int] = field(default_factory=dict)  # neutral actuator -> servo output read back
    aliases: dict[str, tuple[str, ...]] = field(default_factory=dict)  # neutral -> other native names to try
    native_scales: dict[str, NativeScale] = field(default_factory=dict)  # neutral -> unit conversion
    marker_param: str = ""  # a parameter only this autopilot has (profile detection)
    # HEARTBEAT.type (MAV_TYPE) values this profile flies, where one autopilot's profiles share a
    # marker (PX4's rover and UUV builds have the same parameters); empty: any
    mav_types: tuple[int, ...] = ()
    heading_schedule: str = "heading"  # the gain schedule of its heading loop (behaviors.schedules)
    # the step model of its heading controller, for predicted steps (companion.numerics.step_response):
    # "pi" (eq. A.1), "cascade" (A.2; ArduSub's shaping A.2s is read from its parameters), "px4_rover"
    # (A.4), "px4_uuv" (A.5)
    heading_controller: str = "pi"
    # its heading gains and limits as it ships them (native names): a design's "original" candidate
    # when the vehicle's own are not known (``companion design --autopilot``)
    shipped_gains: dict[str, float] = field(default_factory=dict)
    strategy: str = "sim"  # module of companion.link.autopilots that commands this autopilot
    water_speed_sensor: bool = True  # False: VFR_HUD.airspeed is not a water speed; ground speed stands in
    depth_from_pressure: bool = True  # False: depth is the autopilot's own estimate (GLOBAL_POSITION_INT)
    depth_setpoint: bool = True  # False: no depth target can be commanded (a boat; ArduSub ALT_HOLD)
    # what the vehicle is, for the envelope a procedure keeps (companion.procedures.limits): "surface"
    # (no depth: never checked on it), "underwater", or "any" (our simulator: boat or AUV by preset,
    # its depth is a pressure reading either way)
    vehicle_kind: str = "any"
    # NAV_CONTROLLER_OUTPUT.target_bearing is the heading set-point the holding mode holds (our simulator)
    reports_heading_target: bool = False
    # how learning during missions verifies gains (``behaviors.mission_learning``): "course_changes"
    # (heading set-point jumps as steps) or "turn_rate" (the rate loop's tracking of the turn rate the
    # navigation asks for, from PID_TUNING: ArduRover and ArduSub in AUTO)
    learning_verification: Literal["course_changes", "turn_rate"] = "course_changes"
    # the PID_TUNING message of its heading's rate loop: the mask bit that asks for it, its axis and
    # units (None: it sends none)
    pid_tuning: PidTuningReport | None = None
    # the PID_TUNING message of its speed loop, on an autopilot whose speed loop the companion
    # designs (ArduRover: eq. S.5) and learns during missions (eq. L.4); None: no speed loop learned
    speed_loop_report: SpeedLoopReport | None = None
    # the form of its heading rate loop (eq. A.2r): whether FF reaches the output and whether the
    # integrator stops at the output's limit, for the turn-rate verification's replay
    rate_loop: RateLoopForm = ARDUROVER_RATE_LOOP
    # its yaw moment comes from thrusters the autopilot mixes (ArduSub: it has no yaw fin), whose
    # authority does not depend on the speed through the water: learning writes a window's rows as
    # they are (eq. L.3 with p = n = 0), takes windows of any speed spread, and one band spans the
    # speeds of the mission
    yaw_from_thrusters: bool = False
    # how the actuator read-back behaves between samples, for the identifier's input filter:
    # "foh" a physical deflection (our simulator reports the rudder itself), "zoh" an output held
    # from one control loop to the next (ArduPilot reports its commanded output)
    actuator_hold: str = "foh"
    # the fin servo's slew rate (rad/s), a property of the vehicle: where the autopilot reports its
    # commanded output (ArduPilot), the snapshot carries the deflection a servo of this rate makes of
    # it; None: the commanded output as is
    actuator_rate_rad_s: float | None = None
    # how long before the first snapshot that shows a new output it took effect, on average: an
    # override lands at whichever control loop follows its arrival, and where the outputs are
    # sampled every n-th loop it may be any of the n loops since the previous sample; the mean lead
    # is (sample period − loop period)/2 (ArduRover: 25 Hz samples of a 50 Hz loop → 10 ms)
    output_lead_s: float = 0.0
    # train on the whole window (10.5 s after the doublet) instead of stopping at convergence: with
    # ArduPilot's low-noise attitude eq. 3.39 holds 0.8 s after the doublet, and a22/b2 then depend
    # on the few samples around its switches (measured: −2…−7 % against −1…−6 % on the full window)
    train_full_window: bool = False
    # the autopilot's documented ranges of its native heading gains, as CascadeRules fields
    # (e.g. {"rate_ff_range": (0.0, 0.0)}); empty: ArduRover's ranges, the design's defaults
    gain_ranges: dict = field(default_factory=dict)
    # points of step overshoot the designed gains may fly above their prediction on this autopilot
    # (the spread of flown minus predicted, measured): the optimised design keeps this far below the
    # keep rule's limit (companion.numerics.step_design, eq. D.1); None: the design's default
    prediction_margin_pct: float | None = None
    # what a campaign on this autopilot flies unless the user says otherwise: e.g. ArduSub's thrusts
    # that keep its vectored motors out of saturation; applied once, by CampaignConfig.resolved_for
    campaign_defaults: CampaignDefaults = field(default_factory=CampaignDefaults)
    # what a thrust level (SetThrust, 0..1) is on this autopilot: the one statement of its unit
    thrust_meaning: str = "the thruster's thrust ratio"
    # parameters the vehicle puts back by itself once it acted on them (one-shot triggers, neutral
    # names): not watched for other people's changes, whose reset would otherwise look like one
    self_resetting: tuple[str, ...] = ()
    # what drives the boat, read from the vehicle at connect (its SERVOn_FUNCTION): a steering servo
    # and a throttle, or a skid-steered pair un-mixed into steering and throttle; None: the fixed
    # ``servo_outputs`` above (companion.link.actuation)
    actuation: Actuation | None = None
    angle_full_scale_rad: float = 0.5236  # fin angle at pwm_center ± pwm_half_range
    pwm_center: int = 1500
    pwm_half_range: int = 500
    thrust_pwm_zero: int = 1000  # PWM of thrust ratio 0
    thrust_pwm_full: int = 2000  # PWM of thrust ratio 1
    mass_servo: int | None = None  # servo output of the rolling mass (DO_SET_SERVO), None = not fitted
    int_encoding: Literal["cast", "bytewise"] = "cast"
    flown: bool = False  # True only for profiles verified on the real autopilot / simulator

    # ------------------------------------------------------------------ PWM <-> SI
    def pwm_to_angle(self, pwm: float) -> float:
        """Fin angle (rad) from PWM; NaN for 0/65535/out-of-range ("no data")."""
        if not _pwm_valid(pwm):
            return math.nan
        return (pwm - self.pwm_center) / self.pwm_half_range * self.angle_full_scale_rad

    def angle_to_pwm(self, angle: float) -> int:
        """PWM for a fin angle (rad), clamped to the channel's full scale; ValueError if non-finite."""
        if not math.isfinite(angle):
            raise ValueError(f"non-finite actuator angle {angle!r}")
        pwm = self.pwm_center + angle / self.angle_full_scale_rad * self.pwm_half_range
        return int(round(min(max(pwm, self.pwm_center - self.pwm_half_range), self.pwm_center + self.pwm_half_range)))

    def pwm_to_thrust(self, pwm: float) -> float:
        """Thrust ratio (0..1 forward) from PWM; NaN when the PWM means "no data"."""
        if not _pwm_valid(pwm):
            return math.nan
        return (pwm - self.thrust_pwm_zero) / (self.thrust_pwm_full - self.thrust_pwm_zero)

    def thrust_to_pwm(self, thrust_ratio: float) -> int:
        """PWM for a thrust ratio, clamped to 0..1; ValueError if non-finite."""
        if not math.isfinite(thrust_ratio):
            raise ValueError(f"non-finite thrust ratio {thrust_ratio!r}")
        ratio = min(max(thrust_ratio, 0.0), 1.0)
        return int(round(self.thrust_pwm_zero + ratio * (self.thrust_pwm_full - self.thrust_pwm_zero)))

    def actuator_to_pwm(self, actuator: str, value: float) -> int:
        """PWM of an RC override for a neutral actuator (fins in rad, thrust as a ratio)."""
        self.channel(actuator)
        return self.thrust_to_pwm(value) if actuator == "thrust" else self.angle_to_pwm(value)

    # ------------------------------------------------------------------ names
    def channel(self, actuator: str) -> int:
        try:
            return self.channels[actuator]
        except KeyError:
            raise ProfileError(f"profile {self.name!r} has no RC channel for actuator {actuator!r}") from None

    def mode_number(self, neutral: str) -> int:
        """custom_mode of a neutral name; ``custom_<n>`` (a mode this profile does not name, as
        :meth:`mode_name` reports it) gives n back, so a vehicle found in it can be restored."""
        if neutral.startswith("custom_") and neutral[7:].isdigit():
            return int(neutral[7:])
        try:
            return self.modes[neutral]
        except KeyError:
            raise ProfileError(f"profile {self.name!r} has no mode {neutral!r} (has {sorted(self.modes)})") from None

    def mode_command_params(self, custom_mode: int) -> tuple[float, ...]:
        """MAV_CMD_DO_SET_MODE's parameters for a custom_mode number: (CUSTOM_MODE_ENABLED, number),
        ArduPilot's and our simulator's form (an autopilot that packs main and sub mode differently
        overrides this)."""
        return (float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(custom_mode))

    def mode_name(self, custom_mode: int) -> str:
        """Neutral name of a custom_mode number, ``custom_<n>`` when the profile does not name it."""
        for neutral, number in self.modes.items():
            if number == custom_mode:
                return neutral
        return f"custom_{custom_mode}"

    def native_param(self, neutral: str) -> str:
        """Autopilot name of a neutral parameter (the primary name; see :meth:`native_candidates`)."""
        try:
            return self.params[neutral]
        except KeyError:
            raise ProfileError(f"profile {self.name!r} has no parameter for {neutral!r}") from None

    def native_candidates(self, neutral: str) -> tuple[str, ...]:
        """Primary name followed by the aliases (renamed parameters across firmware versions)."""
        return (self.native_param(neutral),) + self.aliases.get(neutral, ())

    def to_native_value(self, neutral: str, value: float) -> float:
        scale = self.native_scales.get(neutral)
        return scale.to_native(value) if scale else value

    def to_neutral_value(self, neutral: str, native_value: float) -> float:
        scale = self.native_scales.get(neutral)
        return scale.to_neutral(native_value) if scale else native_value

    def natives_touched(self, neutral_names) -> tuple[str, ...]:
        """Autopilot parameters behind these neutral names (names the profile lacks are skipped)."""
        return tuple(dict.fromkeys(self.params[n] for n in neutral_names if n in self.params))


def _pwm_valid(pwm: float) -> bool:
    try:
        return math.isfinite(pwm) and PWM_VALID_MIN <= pwm <= PWM_VALID_MAX
    except TypeError:
        return False


