"""The heading schedule of cascaded autopilots (ArduPilot): native angle-P / rate-PID / FF gains
designed from the yaw models (``companion.numerics.cascade_gains``), scheduled on speed with the
same fitted laws as the heading PI (``schedule_from_models``): FF and P follow b2's speed law (u² for
a rudder, u for differential thrust, chosen by the models, eq. S.3), which ArduPilot itself cannot
schedule."""
from __future__ import annotations

from functools import partial

from behaviors.gain_scheduling import ScheduleKind
from companion.numerics.cascade_gains import CascadeRules, design_cascade_gains
from companion.numerics.identification import YawModel
from companion.numerics.schedule import YawSchedule, schedule_from_models


def cascade_kind(rules: CascadeRules = CascadeRules(), speed_law: str | None = None) -> ScheduleKind:
    """The native heading schedule with these design rules; ``speed_law`` as in ``heading_kind``."""
    def gains(schedule: YawSchedule, speed: float) -> dict[str, float]:
        return design_cascade_gains(schedule.model_at(speed), rules, speed=float(speed)).params()

    def model_gains(model: YawModel, speed: float) -> dict[str, float]:
        return design_cascade_gains(model, rules, speed=speed).params()

    return ScheduleKind(name="cascade", axis="yaw",
                        scheduled=("heading_rate_ff", "heading_rate_p", "heading_rate_i", "heading_angle_p"),
                        fixed=(), fit=partial(schedule_from_models, prior_law=speed_law), gains=gains,
                        model_gains=model_gains, live_value="sched_ff", rules=rules, speed_law=speed_law)


CASCADE = cascade_kind()
