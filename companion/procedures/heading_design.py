"""The campaign's heading design by prediction (eq. D.1): which rule parameters, or the vehicle's own
gains, a campaign writes.

:func:`choose_heading_design` fits the heading schedule over the accepted yaw models (the same fit the
schedule kind makes), builds one predicted-step case per accepted model — flown on that model, under
the autopilot's controller with the limits read from the vehicle (``HeadingLimits``) — and lets
``companion.numerics.step_design.design_by_prediction`` score the rule's default, its optimum, the
original gains and QuickTune's rule. The result is a :class:`HeadingDesign`: the configuration whose
schedule kind gives the chosen gains (the rule's parameters are configuration, so a stored campaign
rebuilds the same schedule from its stored configuration), or the decision to keep the original gains.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

from behaviors.gain_scheduling import ScheduleKind
from companion.numerics.cascade_gains import CascadeRules
from companion.numerics.gains import GainBounds
from companion.numerics.step_design import (DesignChoice, RuleFamily, StepCase, cascade_family,
                                            design_by_prediction, pi_family, px4_rover_family, px4_uuv_family)
from companion.procedures.verified_design import CONTROLLERS, HeadingLimits, limits_case


@dataclass(frozen=True)
class HeadingDesign:
    """The choice (every candidate scored) and what it means for the campaign: the rules to design
    with (``cascade`` or ``bounds``, the other unchanged), or ``keeps_original``."""

    choice: DesignChoice
    cascade: CascadeRules
    bounds: GainBounds

    @property
    def keeps_original(self) -> bool:
        return self.choice.keeps_original


def optimisable(kind: ScheduleKind | None) -> bool:
    """A heading kind whose controller the predictions model (eq. A.1, A.2, A.4, A.5)."""
    return kind is not None and kind.name in CONTROLLERS


def design_cases(kind: ScheduleKind, attempts: Sequence, limits: HeadingLimits) -> tuple[list[StepCase], list]:
    """One case per accepted yaw model (its own model, the controller's limits at its speed) and the
    schedule's model at the same speed (what the rule designs from); ValueError without a model."""
    usable = [a for a in attempts if a.axis == "yaw" and a.accepted and math.isfinite(a.speed)]
    if not usable:
        raise ValueError("no accepted yaw model with a measured speed")
    schedule = kind.fit([a.speed for a in usable], [a.model for a in usable])
    cases = [step_case(CONTROLLERS[kind.name], a.model, a.speed, limits) for a in usable]
    return cases, [schedule.model_at(a.speed) for a in usable]


def step_case(controller: str, model, speed: float, limits: HeadingLimits) -> StepCase:
    """One predicted-step case under ``controller`` ("pi", eq. A.1; "cascade", eq. A.2; "px4_rover",
    eq. A.4; "px4_uuv", eq. A.5)."""
    return limits_case(controller, model, speed, limits)


#: the rule family of each controller's gains, designed with the cascade's rules (all but the PI)
_CASCADE_FAMILIES = {"cascade": cascade_family, "px4_rover": px4_rover_family, "px4_uuv": px4_uuv_family}


def family_for(controller: str, cascade: CascadeRules, bounds: GainBounds) -> RuleFamily:
    """The rule family a controller's gains are searched in (eq. D.1)."""
    family = _CASCADE_FAMILIES.get(controller)
    return family(cascade) if family is not None else pi_family(bounds)


def choose_heading_design(kind: ScheduleKind, cascade: CascadeRules, bounds: GainBounds, attempts: Sequence,
                          limits: HeadingLimits, objective, original: dict[str, float],
                          quicktune: dict[str, float] | None = None) -> HeadingDesign:
    """eq. D.1 for a campaign (module docstring); ValueError when no case can be built."""
    cases, design_models = design_cases(kind, attempts, limits)
    family = family_for(CONTROLLERS[kind.name], cascade, bounds)
    others = {"quicktune": quicktune} if quicktune else None
    choice = design_by_prediction(family, cases, design_models, objective, original=original or None, others=others)
    rules = choice.chosen.rules
    if isinstance(rules, CascadeRules):
        cascade = rules
    elif isinstance(rules, GainBounds):
        bounds = rules
    return HeadingDesign(choice=choice, cascade=cascade, bounds=bounds)


def with_design(config, design: HeadingDesign):
    """``config`` (a CampaignConfig) designing with the chosen rules."""
    return replace(config, cascade=design.cascade, bounds=design.bounds)
