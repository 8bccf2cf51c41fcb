"""What an identification campaign found, as one typed record (``IdentificationCampaign.result()``'s
figures; ``companion identify --json`` prints them, docs/store.md lists the keys).

:class:`CampaignFigures` holds the campaign's typed records themselves (its configuration, each
manoeuvre's :class:`IdentificationResult`, the accepted :class:`IdentificationAttempt`\\ s, each
:class:`GainDesign`, the heading checks, the verification's :class:`VerifiedSteps`, the speed loop's
:class:`SpeedTuningResult`, eq. D.1's :class:`DesignChoice`) and converts them only in ``to_dict``;
:class:`LoopOutcome` is what one loop was left with, :class:`ThrustLevels` the levels flown.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Union

from behaviors.gain_scheduling import GainDesign
from behaviors.heading_steps import HeadingStepsResult
from behaviors.identification import IdentificationAttempt, IdentificationResult
from behaviors.json_form import json_form
from behaviors.speed_tuning import SpeedTuningResult
from companion.checks import is_number, require_choice
from companion.numerics.step_design import DesignChoice
from companion.procedures.campaign_config import CHECKS, CampaignConfig
from companion.procedures.campaign_verification import VerifiedSteps
from companion.procedures.verified_design import FlownStep

#: a heading-step check as the campaign keeps it: the thesis comparison's steps, or a verification step
#: with its prediction
HeadingCheck = Union[HeadingStepsResult, FlownStep]

#: what a loop (heading, speed) was left with: gains designed, verified and written; the vehicle's own
#: gains kept as verified at least as good; refused (nothing written, the campaign fails); not tuned
LOOP_OUTCOMES = ("written", "original kept", "refused", "not tuned")
#: the loops a campaign tunes
LOOPS = ("heading", "speed")


@dataclass(frozen=True)
class LoopOutcome:
    """What one loop was left with (:data:`LOOP_OUTCOMES`) and why. The JSON: ``outcome``, ``why``."""

    outcome: str
    why: str

    def __post_init__(self) -> None:
        require_choice(self, "outcome", LOOP_OUTCOMES)

    def to_dict(self) -> dict:
        return {"outcome": self.outcome, "why": self.why}


def loops_to_dict(loops: dict[str, LoopOutcome]) -> dict[str, dict]:
    """Loop by loop (:data:`LOOPS`), each outcome's JSON."""
    return {name: loop.to_dict() for name, loop in loops.items()}


def designs_to_json(designs: dict[str, GainDesign]) -> dict | None:
    """Each designed schedule as stored (the one serialiser), keyed by kind; None when none."""
    from companion.records.serialise import to_json

    return {name: to_json(design) for name, design in designs.items()} or None


@dataclass(frozen=True)
class ThrustLevels:
    """The thrust levels the campaign flew (or still meant to, in order; fractions in (0, 1]) and
    what re-planned them, in words (a level that gave a lower one's speed). The JSON: ``flown``,
    ``respacing``."""

    flown: tuple[float, ...]
    respacing: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not all(is_number(t) and 0.0 < t <= 1.0 for t in self.flown):
            raise ValueError(f"ThrustLevels.flown must be thrust levels in (0, 1], not {self.flown!r}")

    def to_dict(self) -> dict:
        return json_form({"flown": self.flown, "respacing": self.respacing})


@dataclass(frozen=True)
class CampaignFigures:
    """What the campaign found (module docstring): its configuration as flown, each identification
    manoeuvre, the accepted attempts, the designed schedules by kind and why others were not, the
    heading verdict (None: no heading gains to judge; ``passed``), the heading checks flown and which
    ones (:data:`CHECKS`), the verification's steps (None: not flown), vehicle seconds by phase, the
    gains written (None: none), the speed loop (None: not tuned), eq. D.1's heading design (None: not
    optimised), what each loop was left with and the thrust levels.

    The JSON keys, in order: ``config``, ``manoeuvres`` (without ``attempts``), ``accepted`` (each
    attempt's summary), ``design`` (each schedule tagged as the store writes it, by kind; null
    without any), ``design_errors``, ``verification``, ``steps`` (without ``series``), ``checks``,
    ``verified``, ``vehicle_time_by_phase``, ``final_gains``, ``speed_loop``, ``heading_design``,
    ``loops``, ``thrust_levels``."""

    config: CampaignConfig
    manoeuvres: tuple[IdentificationResult, ...]
    accepted: tuple[IdentificationAttempt, ...]
    designs: dict[str, GainDesign]
    design_errors: dict[str, str]
    verification: str | None
    steps: tuple[HeadingCheck, ...]
    checks: str
    verified: VerifiedSteps | None
    vehicle_time_by_phase: dict[str, float]
    final_gains: dict[str, float] | None
    speed_loop: SpeedTuningResult | None
    heading_design: DesignChoice | None
    loops: dict[str, LoopOutcome]
    thrust_levels: ThrustLevels

    def __post_init__(self) -> None:
        require_choice(self, "checks", CHECKS)
        rejected = [a.attempt for a in self.accepted if not a.accepted]
        if rejected:
            raise ValueError(f"CampaignFigures.accepted holds accepted attempts only, not attempts {rejected}")
        if not all(is_number(s) and s >= 0.0 for s in self.vehicle_time_by_phase.values()):
            raise ValueError("CampaignFigures.vehicle_time_by_phase holds seconds ≥ 0 by phase, not "
                             f"{self.vehicle_time_by_phase!r}")
        if set(self.loops) - set(LOOPS):
            raise ValueError(f"CampaignFigures.loops are by loop ({', '.join(LOOPS)}), not {', '.join(self.loops)}")

    def to_dict(self) -> dict:
        return json_form({
            "config": self.config.to_dict(),
            # the attempts are stored as runs, and the accepted ones listed below
            "manoeuvres": [{k: v for k, v in m.to_dict().items() if k != "attempts"} for m in self.manoeuvres],
            "accepted": [a.summary() for a in self.accepted],
            "design": designs_to_json(self.designs),
            "design_errors": self.design_errors,
            "verification": self.verification,
            "steps": [{k: v for k, v in r.to_dict().items() if k != "series"} for r in self.steps],
            "checks": self.checks,
            "verified": self.verified.to_dict() if self.verified is not None else None,
            "vehicle_time_by_phase": self.vehicle_time_by_phase,
            "final_gains": self.final_gains,
            "speed_loop": self.speed_loop.to_dict() if self.speed_loop is not None else None,
            "heading_design": self.heading_design.to_dict() if self.heading_design is not None else None,
            "loops": loops_to_dict(self.loops),
            "thrust_levels": self.thrust_levels.to_dict(),
        })
