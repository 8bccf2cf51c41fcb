"""A step's figures of merit, as records: flown, predicted, or flown with where it was flown.

:class:`StepFigures` is what ``companion.numerics.step_response.step_metrics`` measures of one step
(a heading step, or a speed step scored the same way): overshoot (% of the step), 90 % rise time,
settling time (within 5 % to the end; NaN if never), the integrated absolute error normalised by the
step (``iae_s``) and the reversals of the error (eq. A.3 judges flown and predicted steps by them).
:class:`PredictedStep` is a step flown on the identified model instead (eq. A.1, A.2, A.2k, A.4,
A.5): its figures and what the rudder did. :class:`FlownStepFigures` is a flown heading step's
figures with its size, speed and, for a verification step, how and when it ended (eq. A.3).

Each is validated where it is made (ValueError naming the field) and read by attribute; its
``to_dict()`` is its JSON (strict: NaN and infinities ``null``, ``behaviors.json_form``'s form), the
keys in the order the product has always written them (docs/store.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from companion.checks import require_count

#: how a verification step's record ended (``behaviors.verification``): settled, or not within
#: ``max_s`` (timeout), or undecided (disturbed, saturated)
STEP_ENDINGS = ("settled", "timeout", "disturbed", "saturated")


def _strict(value: float) -> float | None:
    """A figure as JSON holds it: NaN and infinities ``null``."""
    return value if math.isfinite(value) else None


def _require_figure(obj: Any, *names: str) -> None:
    """Each named field is a number ≥ 0 (infinity included) or NaN (not measured)."""
    for name in names:
        value = getattr(obj, name)
        if not (isinstance(value, (int, float)) and not isinstance(value, bool)
                and (math.isnan(value) or value >= 0.0)):
            raise ValueError(f"{type(obj).__name__}.{name} must be a number ≥ 0 or NaN (not measured), "
                             f"not {value!r}")


@dataclass(frozen=True)
class StepFigures:
    """One step's figures of merit (module docstring): ``overshoot_pct``, ``rise_time_s``,
    ``settling_time_s`` and ``iae_s`` each ≥ 0 or NaN (not measured), ``oscillations`` an integer ≥ 0."""

    overshoot_pct: float
    rise_time_s: float
    settling_time_s: float
    iae_s: float
    oscillations: int

    def __post_init__(self) -> None:
        _require_figure(self, "overshoot_pct", "rise_time_s", "settling_time_s", "iae_s")
        require_count(self, "oscillations")

    @classmethod
    def unmeasured(cls) -> "StepFigures":
        """A step too short or too small to score: every figure NaN, no reversal."""
        return cls(math.nan, math.nan, math.nan, math.nan, 0)

    def to_dict(self) -> dict[str, Any]:
        return {"overshoot_pct": _strict(self.overshoot_pct), "rise_time_s": _strict(self.rise_time_s),
                "settling_time_s": _strict(self.settling_time_s), "iae_s": _strict(self.iae_s),
                "oscillations": self.oscillations}


@dataclass(frozen=True)
class PredictedStep:
    """A step flown on the model (``step_response.predict_step``): its ``figures``, the largest rudder
    deflection (``rudder_peak``, rad, ≥ 0 or NaN), whether it reached the limit (``saturated``), how
    long it sat there (``saturated_s`` ≥ 0) and, on a skid-steered boat only (eq. A.2k), the speed it
    lost (``speed_dip_pct``, % of the starting speed; None for every other vehicle)."""

    figures: StepFigures
    rudder_peak: float
    saturated: bool
    saturated_s: float
    speed_dip_pct: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.figures, StepFigures):
            raise ValueError(f"PredictedStep.figures must be StepFigures, not {self.figures!r}")
        _require_figure(self, "rudder_peak")
        if not isinstance(self.saturated, bool):
            raise ValueError(f"PredictedStep.saturated must be a bool, not {self.saturated!r}")
        if not (isinstance(self.saturated_s, (int, float)) and math.isfinite(self.saturated_s)
                and self.saturated_s >= 0.0):
            raise ValueError(f"PredictedStep.saturated_s must be a finite time ≥ 0, not {self.saturated_s!r}")
        if self.speed_dip_pct is not None and not (isinstance(self.speed_dip_pct, (int, float))
                                                   and not isinstance(self.speed_dip_pct, bool)):
            raise ValueError(f"PredictedStep.speed_dip_pct must be a number or None, not {self.speed_dip_pct!r}")

    def to_dict(self) -> dict[str, Any]:
        """The figures' keys, then ``speed_dip_pct`` (skid boats only), ``rudder_peak``, ``saturated``,
        ``saturated_s``."""
        out = self.figures.to_dict()
        if self.speed_dip_pct is not None:
            out["speed_dip_pct"] = _strict(self.speed_dip_pct)
        out.update(rudder_peak=_strict(self.rudder_peak), saturated=self.saturated, saturated_s=self.saturated_s)
        return out


@dataclass(frozen=True)
class FlownStepFigures:
    """A flown heading step's ``figures`` with its size (``step_deg``, signed) and the mean water speed
    over it (``speed``, NaN: none measured); a verification step's also how its record ended
    (``ended``, one of :data:`STEP_ENDINGS`) and its length (``duration_s`` ≥ 0), both or neither."""

    figures: StepFigures
    step_deg: float
    speed: float
    ended: str | None = None
    duration_s: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.figures, StepFigures):
            raise ValueError(f"FlownStepFigures.figures must be StepFigures, not {self.figures!r}")
        if not (isinstance(self.step_deg, (int, float)) and math.isfinite(self.step_deg)):
            raise ValueError(f"FlownStepFigures.step_deg must be a finite angle, not {self.step_deg!r}")
        if not isinstance(self.speed, (int, float)) or isinstance(self.speed, bool):
            raise ValueError(f"FlownStepFigures.speed must be a number (NaN: not measured), not {self.speed!r}")
        if (self.ended is None) != (self.duration_s is None):
            raise ValueError("FlownStepFigures: a step's ending and its duration come together, "
                             f"not ended={self.ended!r} with duration_s={self.duration_s!r}")
        if self.ended is not None and self.ended not in STEP_ENDINGS:
            raise ValueError(f"FlownStepFigures.ended must be one of {', '.join(STEP_ENDINGS)}, not {self.ended!r}")
        if self.duration_s is not None and not (isinstance(self.duration_s, (int, float))
                                                and math.isfinite(self.duration_s) and self.duration_s >= 0.0):
            raise ValueError(f"FlownStepFigures.duration_s must be a finite time ≥ 0, not {self.duration_s!r}")

    def to_dict(self) -> dict[str, Any]:
        """The figures' keys, then ``step_deg``, ``speed`` and (a verification step) ``ended``, ``duration_s``."""
        out = self.figures.to_dict()
        out.update(step_deg=self.step_deg, speed=_strict(self.speed))
        if self.ended is not None:
            out.update(ended=self.ended, duration_s=self.duration_s)
        return out
