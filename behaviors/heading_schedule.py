"""The heading PI schedule (SPEC C5; thesis §3.5–3.6): designed from the yaw models.

Fit: :func:`companion.numerics.schedule.schedule_from_models` (a22 constant or with its significant
speed trend, b2 = k·u² + c or k·u + c as the models support, eq. S.3, δ0 constant). Gains: Kp = a22²/(2·b2) with the integral rule of
``companion.numerics.gains``; the trim δ0 is written once, Kp and Ki follow the speed.
"""
from __future__ import annotations

from functools import partial

from behaviors.gain_scheduling import ScheduleKind
from companion.numerics.gains import GainBounds, HeadingGains, design_heading_gains
from companion.numerics.identification import YawModel
from companion.numerics.schedule import YawSchedule, schedule_from_models


def heading_params(gains: HeadingGains) -> dict[str, float]:
    """Neutral parameter names (see ``companion.link.profiles``) of a heading gain set."""
    return {"heading_p": float(gains.kp), "heading_i": float(gains.ki), "rudder_trim": float(gains.trim)}


def heading_kind(bounds: GainBounds = GainBounds(), speed_law: str | None = None) -> ScheduleKind:
    """The heading schedule with the given gain bounds; ``speed_law`` the b2 law of the vehicle's
    actuation, kept when the models cannot tell (eq. S.3)."""

    def gains(schedule: YawSchedule, speed: float) -> dict[str, float]:
        return heading_params(schedule.gains_at(speed, bounds))

    def model_gains(model: YawModel, speed: float) -> dict[str, float]:
        return heading_params(design_heading_gains(model, bounds, speed=speed))

    return ScheduleKind(name="heading", axis="yaw", scheduled=("heading_p", "heading_i"), fixed=("rudder_trim",),
                        fit=partial(schedule_from_models, prior_law=speed_law), gains=gains, model_gains=model_gains,
                        live_value="sched_kp", rules=bounds, speed_law=speed_law)


HEADING = heading_kind()
