"""Autopilot profiles: the product's neutral notions mapped onto one autopilot (SPEC C1, SPEC §4).

A profile says which custom_mode number is "manual", "hold" (heading-and-depth hold) and "guided",
which RC channel drives the rudder / elevator / thrust, which servo output reports each actuator,
how PWM converts to SI, and which autopilot parameter holds each neutral quantity (``heading_p``,
``gcs_sysid``, ``override_timeout`` ...).

Profiles:

* ``sim`` — the project's simulator, exactly as ``docs/PROTOCOL.md`` defines it (tested end to end).
* ``ardusub`` and ``ardurover`` — **written from the ArduPilot documentation (SPEC §4), not yet
  flown**. Channel numbers are ArduPilot's defaults (RCMAP unchanged); the fin full-scale angle is
  a vehicle property, so ``angle_full_scale_rad`` is a default to replace with
  ``dataclasses.replace(profile, angle_full_scale_rad=...)`` for a real vehicle.

Heading gains on cascaded autopilots
------------------------------------
The product designs a heading PI acting directly on the rudder (SPEC C5):
``δ = Kp·e + Ki·∫e`` (rad of rudder per rad of heading error). ArduSub (``ATC_ANG_YAW_P`` then
``ATC_RAT_YAW_*``) and ArduRover (``ATC_STR_ANG_P`` then ``ATC_STR_RAT_*``) run an angle P loop
giving a rate demand ``r_d = Ka·e`` and a rate PI giving a normalised output
``u = Kr·(r_d − r) + Kri·∫(r_d − r)``, with ``δ = δfs·u`` (δfs = full-scale fin angle). Because
``∫r dt = −(e − e0)``, this equals
``δ = δfs·(Kr·Ka + Kri)·e + δfs·Kri·Ka·∫e − δfs·Kr·r + const``. :meth:`AutopilotProfile.heading_pi_to_native`
keeps the vehicle's rate P ``Kr`` and solves ``δfs·(Kr·Ka + Kri) = Kp``, ``δfs·Kri·Ka = Ki`` for
``Ka`` and ``Kri`` (a quadratic in Ka; the root that tends to ``Kp/(δfs·Kr)`` as Ki → 0); it sets
the rate D and FF to 0 and ``IMAX = imax/δfs``. What stays approximate: the cascade adds the rate
feedback ``−δfs·Kr·r`` the designed loop does not have (more damping than the design's 0.7071,
smaller as Kr is smaller); ArduRover additionally scales steering by speed and limits turn rate
and lateral acceleration; ArduSub mixes the yaw output into thrusters, so "fin angle" assumes a
frame whose yaw output drives the rudder one to one; both store the integrator limit in
normalised output, not radians.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from companion.link.errors import ProfileError

#: PWM values that mean "no data" in SERVO_OUTPUT_RAW / RC fields, and the plausible PWM range.
PWM_VALID_MIN = 800
PWM_VALID_MAX = 2200

#: neutral parameter names that the cascaded profiles translate through the PI mapping
HEADING_PI_NAMES = ("heading_p", "heading_i", "heading_imax")
#: neutral names of every parameter the cascaded heading mapping writes
CASCADED_HEADING_NAMES = ("heading_p", "heading_imax", "heading_rate_p", "heading_rate_i", "heading_rate_d",
                          "heading_rate_ff", "heading_rate_imax")


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
    cascaded_heading: bool = False  # heading = angle P + rate PID (ArduPilot attitude control)
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

    # ------------------------------------------------------------------ heading PI
    def heading_pi_to_native(self, kp: float, ki: float, imax: float, *, rate_p: float | None = None) -> dict[str, float]:
        """Autopilot parameters realising the heading PI ``δ = Kp·e + Ki·∫e`` (module docstring).

        For the simulator this is the identity (HDG_P, HDG_I, HDG_IMAX). For cascaded autopilots
        ``rate_p`` (the vehicle's current rate P, kept) is required; raises ProfileError when the
        PI cannot be represented (Ki too large for the given rate P: no real root).
        """
        for label, value in (("kp", kp), ("ki", ki), ("imax", imax)):
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f"heading gain {label}={value!r} must be finite and >= 0")
        if not self.cascaded_heading:
            return {self.native_param("heading_p"): kp, self.native_param("heading_i"): ki,
                    self.native_param("heading_imax"): imax}
        if rate_p is None or not math.isfinite(rate_p) or rate_p <= 0.0:
            raise ProfileError(f"profile {self.name!r}: the heading mapping needs the vehicle's rate P > 0")
        full_scale = self.angle_full_scale_rad
        # δfs·Kr·Ka² − Kp·Ka + Ki = 0 ; closed form because it is one quadratic
        a_coef = full_scale * rate_p
        discriminant = kp * kp - 4.0 * a_coef * ki
        if kp <= 0.0 or discriminant < 0.0:
            raise ProfileError(
                f"profile {self.name!r}: Kp={kp}, Ki={ki} not representable with rate P {rate_p} "
                "(increase the rate P or lower Ki)")
        angle_p = (kp + math.sqrt(discriminant)) / (2.0 * a_coef)
        rate_i = ki / (full_scale * angle_p)
        return {
            self.native_param("heading_p"): angle_p,
            self.native_param("heading_rate_i"): rate_i,
            self.native_param("heading_rate_d"): 0.0,
            self.native_param("heading_rate_ff"): 0.0,
            self.native_param("heading_rate_imax"): min(imax / full_scale, 1.0),
        }

    def native_to_heading_pi(self, native: dict[str, float]) -> dict[str, float]:
        """Inverse of :meth:`heading_pi_to_native`: neutral heading_p/heading_i/heading_imax."""
        if not self.cascaded_heading:
            return {"heading_p": native[self.native_param("heading_p")],
                    "heading_i": native[self.native_param("heading_i")],
                    "heading_imax": native[self.native_param("heading_imax")]}
        full_scale = self.angle_full_scale_rad
        angle_p = native[self.native_param("heading_p")]
        rate_p = native[self.native_param("heading_rate_p")]
        rate_i = native[self.native_param("heading_rate_i")]
        return {"heading_p": full_scale * (rate_p * angle_p + rate_i),
                "heading_i": full_scale * rate_i * angle_p,
                "heading_imax": full_scale * native[self.native_param("heading_rate_imax")]}

    def natives_touched(self, neutral_names) -> tuple[str, ...]:
        """Autopilot parameters that writing these neutral names may change: on a cascaded
        autopilot a heading gain is realised through the whole angle + rate loop, so every rate
        parameter the mapping writes is included; names the profile lacks are skipped."""
        names: list[str] = []
        for neutral in neutral_names:
            if neutral not in self.params:
                continue
            if self.cascaded_heading and neutral in HEADING_PI_NAMES:
                names += [self.params[n] for n in CASCADED_HEADING_NAMES if n in self.params]
            else:
                names.append(self.params[neutral])
        return tuple(dict.fromkeys(names))

    def heading_native_names(self) -> tuple[str, ...]:
        """Autopilot parameters that :meth:`native_to_heading_pi` reads."""
        if not self.cascaded_heading:
            return tuple(self.native_param(n) for n in HEADING_PI_NAMES)
        return tuple(self.native_param(n) for n in ("heading_p", "heading_rate_p", "heading_rate_i", "heading_rate_imax"))


def _pwm_valid(pwm: float) -> bool:
    try:
        return math.isfinite(pwm) and PWM_VALID_MIN <= pwm <= PWM_VALID_MAX
    except TypeError:
        return False


# ---------------------------------------------------------------------------- the profiles
SIM = AutopilotProfile(
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
)

# ArduSub: RC 1 pitch, 2 roll, 3 throttle (heave), 4 yaw, 5 forward, 6 lateral; sticks 1100..1900.
ARDUSUB = AutopilotProfile(
    name="ardusub",
    modes={"manual": 19, "hold": 2, "guided": 4, "stabilize": 0, "poshold": 16},  # hold = ALT_HOLD
    channels={"rudder": 4, "elevator": 1, "thrust": 5},
    servo_outputs={},  # thruster outputs are mixed: no fin position to read back without a custom frame
    params={
        # heading_p/heading_i/heading_imax are realised through heading_pi_to_native, not 1:1
        "heading_p": "ATC_ANG_YAW_P", "heading_i": "ATC_RAT_YAW_I", "heading_imax": "ATC_RAT_YAW_IMAX",
        "heading_rate_p": "ATC_RAT_YAW_P", "heading_rate_i": "ATC_RAT_YAW_I",
        "heading_rate_d": "ATC_RAT_YAW_D", "heading_rate_ff": "ATC_RAT_YAW_FF",
        "heading_rate_imax": "ATC_RAT_YAW_IMAX", "pitch_p": "ATC_ANG_PIT_P",
        "gcs_sysid": "SYSID_MYGCS", "override_timeout": "RC_OVERRIDE_TIME", "system_id": "SYSID_THISMAV",
    },
    aliases={"gcs_sysid": ("MAV_GCS_SYSID",), "system_id": ("MAV_SYSID",)},
    marker_param="ATC_ANG_YAW_P",
    cascaded_heading=True,
    angle_full_scale_rad=0.35,
    pwm_half_range=400,
    thrust_pwm_zero=1500,  # forward channel is bidirectional: 1500 = stop, 1900 = full ahead
    thrust_pwm_full=1900,
    mass_servo=None,
    int_encoding="cast",
)

# ArduRover (boat frame): RC 1 steering, RC 3 throttle; SERVO1 = GroundSteering, SERVO3 = Throttle.
ARDUROVER = AutopilotProfile(
    name="ardurover",
    modes={"manual": 0, "hold": 1, "guided": 15, "acro": 1, "steering": 3, "stop": 4, "loiter": 5, "auto": 10},
    # "hold" = ACRO: with a centred steering stick it holds zero turn rate (nearest to heading hold
    # that honours a per-channel override; Rover's HOLD mode stops the vehicle, so it is not used).
    channels={"rudder": 1, "thrust": 3},
    servo_outputs={"rudder": 1, "thrust": 3},
    params={
        # heading_p/heading_i/heading_imax are realised through heading_pi_to_native, not 1:1
        "heading_p": "ATC_STR_ANG_P", "heading_i": "ATC_STR_RAT_I", "heading_imax": "ATC_STR_RAT_IMAX",
        "heading_rate_p": "ATC_STR_RAT_P", "heading_rate_i": "ATC_STR_RAT_I",
        "heading_rate_d": "ATC_STR_RAT_D", "heading_rate_ff": "ATC_STR_RAT_FF",
        "heading_rate_imax": "ATC_STR_RAT_IMAX", "rudder_trim": "SERVO1_TRIM",
        "cruise_speed": "CRUISE_SPEED", "cruise_thrust": "CRUISE_THROTTLE",
        "gcs_sysid": "SYSID_MYGCS", "override_timeout": "RC_OVERRIDE_TIME", "system_id": "SYSID_THISMAV",
    },
    aliases={"gcs_sysid": ("MAV_GCS_SYSID",), "system_id": ("MAV_SYSID",)},
    native_scales={
        "cruise_thrust": NativeScale(scale=100.0),  # CRUISE_THROTTLE is percent
        "rudder_trim": NativeScale(scale=500.0 / 0.5236, offset=1500.0),  # SERVO1_TRIM is PWM (µs)
    },
    marker_param="ATC_STR_ANG_P",
    cascaded_heading=True,
    angle_full_scale_rad=0.5236,
    thrust_pwm_zero=1500,  # boats: throttle stick centred = stop
    thrust_pwm_full=2000,
    mass_servo=None,
    int_encoding="cast",
)

PROFILES: dict[str, AutopilotProfile] = {p.name: p for p in (SIM, ARDUSUB, ARDUROVER)}


def get_profile(name: str) -> AutopilotProfile:
    try:
        return PROFILES[name]
    except KeyError:
        raise ProfileError(f"unknown autopilot profile {name!r} (known: {sorted(PROFILES)})") from None


def detect_profile(param_names: set[str] | frozenset[str]) -> AutopilotProfile:
    """The profile whose marker parameter the vehicle has: HDG_P → sim, ATC_ANG_YAW_P → ardusub,
    ATC_STR_ANG_P → ardurover. Raises ProfileError when none (or more than one) matches."""
    matches = [p for p in PROFILES.values() if p.marker_param in param_names]
    if len(matches) != 1:
        found = [p.name for p in matches]
        raise ProfileError(
            f"cannot detect the autopilot profile from its parameters (matching: {found or 'none'}); "
            "pass profile= explicitly")
    return matches[0]


def marker_params() -> tuple[str, ...]:
    """The parameter names :func:`detect_profile` looks for (to probe a vehicle with)."""
    return tuple(p.marker_param for p in PROFILES.values())
