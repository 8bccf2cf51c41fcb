"""The gain schedules the companion can design and keep matched to speed, registered in one place.

A schedule kind (``behaviors.gain_scheduling.ScheduleKind``) turns accepted models into gains per
speed and names the autopilot parameters it writes. Adding one is its behaviour module, its
numerics and one line in :data:`GAIN_SCHEDULES`.
"""
from __future__ import annotations

from typing import Callable

from behaviors.cascade_schedule import cascade_kind
from behaviors.gain_scheduling import GainDesign, ScheduleKind
from behaviors.heading_schedule import heading_kind
from behaviors.pitch_schedule import pitch_kind
from behaviors.px4_schedule import px4_rover_kind, px4_uuv_kind

GAIN_SCHEDULES: dict[str, Callable[..., ScheduleKind]] = {
    "heading": heading_kind,
    "pitch": pitch_kind,
    "cascade": cascade_kind,  # ArduPilot's native heading gains (the ardurover/ardusub profiles' "heading")
    "px4_rover": px4_rover_kind,  # PX4's Ackermann rover gains (the px4-rover profile's "heading")
    "px4_uuv": px4_uuv_kind,  # PX4's UUV attitude gains (the px4-uuv profile's "heading")
}
#: the kinds designed with the cascade's rules (CampaignConfig.cascade, resolved for the profile)
CASCADE_RULED = ("cascade", "px4_rover", "px4_uuv")


#: the kinds whose fit takes the b2 speed law of the vehicle's actuation (eq. S.3)
SPEED_LAW_KINDS = ("heading", "cascade")


def kind_of(design: GainDesign) -> ScheduleKind | None:
    """The kind a stored design was made with: its own registered kind, with the rules and speed law
    it carries (None for a design stored before designs carried their rules)."""
    if design.rules is None:
        return None
    return schedule_kind(design.kind, design.rules, design.speed_law)


def schedule_kind(name: str, bounds=None, speed_law: str | None = None) -> ScheduleKind:
    """The registered kind ``name`` (with ``bounds`` when given, and the actuation's b2 speed law for
    the yaw kinds); ValueError for an unknown name."""
    try:
        factory = GAIN_SCHEDULES[name]
    except KeyError:
        raise ValueError(f"unknown gain schedule {name!r} (known: {', '.join(GAIN_SCHEDULES)})") from None
    extra = {"speed_law": speed_law} if speed_law is not None and name in SPEED_LAW_KINDS else {}
    return factory(bounds, **extra) if bounds is not None else factory(**extra)
