"""The pitch PI schedule (thesis App. B): designed from the identified pitch models.

Fit: :func:`companion.numerics.pitch_gains.pitch_schedule_from_models` (models interpolated
linearly in speed). Gains: Kp = (c22²/2 − c23)/d2, Ki = Kp·ωn/100 (``companion.numerics.pitch_gains``),
written as ``pitch_p`` / ``pitch_i`` and kept matched to speed like the heading gains.
"""
from __future__ import annotations

from behaviors.gain_scheduling import ScheduleKind
from companion.numerics.identification import PitchModel
from companion.numerics.pitch_gains import (
    PitchGainBounds,
    PitchGains,
    PitchSchedule,
    design_pitch_gains,
    pitch_schedule_from_models,
)


def pitch_params(gains: PitchGains) -> dict[str, float]:
    return {"pitch_p": float(gains.kp), "pitch_i": float(gains.ki)}


def pitch_kind(bounds: PitchGainBounds = PitchGainBounds()) -> ScheduleKind:
    def gains(schedule: PitchSchedule, speed: float) -> dict[str, float]:
        return pitch_params(schedule.gains_at(speed, bounds))

    def model_gains(model: PitchModel, speed: float) -> dict[str, float]:
        return pitch_params(design_pitch_gains(model, bounds, speed=speed))

    return ScheduleKind(name="pitch", axis="pitch", scheduled=("pitch_p", "pitch_i"), fixed=(),
                        fit=pitch_schedule_from_models, gains=gains, model_gains=model_gains, live_value="sched_pp",
                        rules=bounds)


PITCH = pitch_kind()
