"""What a campaign costs at sea: its vehicle time by phase (``IdentificationCampaign.result()``'s
``vehicle_time_by_phase``), and the identification stages' times summed over manoeuvres.

The phase is what the vehicle is doing, read from the step that runs: ``settle`` (waiting to be
steady before a record), ``excitation`` (the training records), ``validation`` (the fresh records
that accept a model), ``verification`` (the short campaign's decisive steps, their settles
included), ``heading_steps`` (the thesis comparison), ``speed_steps`` (the speed loop's tuning) and
``design_writes`` (designs, parameter writes and mode changes). With yaw and pitch together the yaw
manoeuvre's stage names the time.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from behaviors.base import Behaviour
from behaviors.heading_steps import HeadingStepTest
from behaviors.identification import TRAIN, VALIDATE, IdentificationManoeuvre
from behaviors.sequence import ParallelBehavior
from behaviors.speed_tuning import SpeedTuning
from behaviors.verification import VerificationStep

#: the campaign's phases of vehicle time, in the order they are flown (:func:`phase_of`)
PHASES = ("settle", "excitation", "validation", "verification", "heading_steps", "speed_steps", "design_writes")

#: what the vehicle is doing in each stage of an identification manoeuvre
_STAGE_PHASES = {TRAIN: "excitation", VALIDATE: "validation"}
#: the phase of every other step the campaign flies (anything else: ``design_writes``)
_STEP_PHASES: tuple[tuple[type[Behaviour], str], ...] = (
    (VerificationStep, "verification"), (HeadingStepTest, "heading_steps"), (SpeedTuning, "speed_steps"))


def phase_of(current: Behaviour | None) -> str:
    """The campaign phase a running step counts to."""
    if isinstance(current, ParallelBehavior):  # the yaw manoeuvre's stage, or the pitch one's once yaw is done
        manoeuvres = [c for c in current.children if isinstance(c, IdentificationManoeuvre)]
        running = sorted((c for c in manoeuvres if not c.done), key=lambda c: c.config.axis != "yaw")
        current = running[0] if running else (manoeuvres[0] if manoeuvres else None)
    if isinstance(current, IdentificationManoeuvre):
        return _STAGE_PHASES.get(current.stage, "settle")
    return next((phase for kind, phase in _STEP_PHASES if isinstance(current, kind)), "design_writes")


@dataclass
class PhaseClock:
    """Vehicle seconds per phase: the time from one sample to the next counts to the phase the
    earlier sample was in."""

    seconds: dict[str, float] = field(default_factory=dict)
    _last: tuple[float, str] | None = None  # the previous sample's vehicle time and phase

    def count(self, now: float, phase: str) -> None:
        """A sample at vehicle time ``now`` while the campaign is in ``phase``."""
        last = self._last
        if last is not None and now > last[0]:
            self.seconds[last[1]] = self.seconds.get(last[1], 0.0) + (now - last[0])
        self._last = (now, phase)

    def in_order(self) -> dict[str, float]:
        """The seconds in the order a campaign flies the phases (:data:`PHASES`), then any other."""
        order = {name: index for index, name in enumerate(PHASES)}
        return dict(sorted(self.seconds.items(), key=lambda item: order.get(item[0], len(order))))


def add_times(total: dict[str, float], more: dict[str, float]) -> dict[str, float]:
    """Vehicle seconds per identification stage, summed over manoeuvres (run together, a parallel
    pair's stages overlap: their sum is the axes' time, not the campaign's)."""
    out = dict(total)
    for stage, seconds in more.items():
        out[stage] = out.get(stage, 0.0) + seconds
    return out
