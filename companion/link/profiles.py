"""The autopilot profiles the companion knows, and how one is recognised (SPEC C1, §4).

Each autopilot is one module of ``companion.link.autopilots`` holding its profile (data) and its
strategy (how it is commanded); adding an autopilot is one new module there and one name in
``companion.link.autopilots.MODULES``.
"""
from __future__ import annotations

from companion.link.autopilots import registered_profiles
from companion.link.autopilots.ardurover import PROFILE as ARDUROVER
from companion.link.autopilots.ardusub import PROFILE as ARDUSUB
from companion.link.autopilots.sim import PROFILE as SIM
from companion.link.errors import ProfileError
from companion.link.profile import PWM_VALID_MAX, PWM_VALID_MIN, AutopilotProfile, NativeScale  # noqa: F401

__all__ = ["ARDUROVER", "ARDUSUB", "SIM", "PROFILES", "get_profile", "detect_profile", "marker_params"]

PROFILES: dict[str, AutopilotProfile] = {p.name: p for p in registered_profiles()}


def get_profile(name: str) -> AutopilotProfile:
    try:
        return PROFILES[name]
    except KeyError:
        raise ProfileError(f"unknown autopilot profile {name!r} (known: {sorted(PROFILES)})") from None


def detect_profile(param_names: set[str] | frozenset[str], mav_type: int | None = None) -> AutopilotProfile:
    """The profile whose marker parameter the vehicle has: HDG_P → sim, ATC_ANG_YAW_P → ardusub,
    ATC_STR_ANG_P → ardurover, SYS_AUTOSTART → PX4, told apart by the HEARTBEAT's ``mav_type``
    (px4-rover a rover or boat, px4-uuv a submarine). Raises ProfileError when none (or more than
    one) matches."""
    matches = [p for p in PROFILES.values() if p.marker_param in param_names
               and (not p.mav_types or mav_type is None or mav_type in p.mav_types)]
    if len(matches) != 1:
        found = [p.name for p in matches]
        raise ProfileError(
            f"cannot detect the autopilot profile from its parameters (matching: {found or 'none'}); "
            "name the autopilot with --profile")
    return matches[0]


def marker_params() -> tuple[str, ...]:
    """The parameter names :func:`detect_profile` looks for (to probe a vehicle with)."""
    return tuple(dict.fromkeys(p.marker_param for p in PROFILES.values()))
