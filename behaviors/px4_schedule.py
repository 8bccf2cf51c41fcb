"""The heading schedules of PX4's boats and UUVs: native gains designed from the yaw models
(``companion.numerics.px4_gains``, eq. P.1–P.6), scheduled on speed with the same fitted laws as the
heading PI (``schedule_from_models``). On the Ackermann rover the equivalent wheel base and the
rate gains follow b2 ∝ u²; on the UUV the PD gains do. The design rules are the cascade's
(``CascadeRules``, resolved for the vehicle's profile by the campaign)."""
from __future__ import annotations

from behaviors.gain_scheduling import ScheduleKind
from companion.numerics.cascade_gains import CascadeRules
from companion.numerics.identification import YawModel
from companion.numerics.px4_gains import design_ackermann_gains, design_uuv_gains
from companion.numerics.schedule import YawSchedule, schedule_from_models


def px4_rover_kind(rules: CascadeRules = CascadeRules()) -> ScheduleKind:
    """RO_YAW_P, RO_YAW_RATE_P/I and RA_WHEEL_BASE per speed; RO_YAW_RATE_CORR 1 written once."""
    def gains(schedule: YawSchedule, speed: float) -> dict[str, float]:
        return design_ackermann_gains(schedule.model_at(speed), float(speed), rules).params()

    def model_gains(model: YawModel, speed: float) -> dict[str, float]:
        return design_ackermann_gains(model, float(speed), rules).params()

    return ScheduleKind(name="px4_rover", axis="yaw",
                        scheduled=("heading_ff_length", "heading_rate_p", "heading_rate_i", "heading_angle_p"),
                        fixed=("heading_ff_correction",), fit=schedule_from_models, gains=gains,
                        model_gains=model_gains, live_value="sched_L", rules=rules)


def px4_uuv_kind(rules: CascadeRules = CascadeRules()) -> ScheduleKind:
    """UUV_YAW_P and UUV_YAW_D per speed."""
    def gains(schedule: YawSchedule, speed: float) -> dict[str, float]:
        return design_uuv_gains(schedule.model_at(speed), rules, speed=float(speed)).params()

    def model_gains(model: YawModel, speed: float) -> dict[str, float]:
        return design_uuv_gains(model, rules, speed=float(speed)).params()

    return ScheduleKind(name="px4_uuv", axis="yaw", scheduled=("heading_angle_p", "heading_rate_d"), fixed=(),
                        fit=schedule_from_models, gains=gains, model_gains=model_gains, live_value="sched_yp",
                        rules=rules)
