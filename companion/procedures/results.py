"""What a procedure reports, in one type with one status vocabulary (the procedures' leaf module).

A procedure (a behaviour run by ``companion.procedures.runner`` under one restore point) ends in
one :class:`Outcome` (a ``StrEnum``: its members compare equal to, and are stored and printed as,
these words; :data:`STATUSES` lists them):

* ``completed`` — its goal was reached (a model accepted and verified, the roll loop ran ...);
* ``failed`` — it ended without reaching its goal (no model passed validation, the seeker found
  no decision), with the reason;
* ``aborted`` — it was stopped from outside (a signal, the pilot, link loss, a safety limit);
* ``refused`` — it does not apply to this vehicle and never started (a boat has no rolling mass);
* ``not started`` / ``running`` — for records of procedures that never began or are under way.

:func:`status_name` is the only mapping from a behaviour's lifecycle status to these words.
:class:`ProcedureResult` carries the status, the reason, the procedure's figures and what the
runner saw (a pilot's takeover, restore problems); :meth:`ProcedureResult.to_json` is the stored
and printed form. The figures are a typed record of each procedure's own
(:class:`ProcedureFigures`: ``CampaignFigures``, ``RollFigures``, ``MinSpeedFigures``,
``SteadyStateFigures``, each beside its procedure; :data:`NO_FIGURES` for a procedure that never
started), read by attribute; their ``to_dict()`` is taken only where the JSON is written. No I/O here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Any, Generic, Protocol, TypeVar, runtime_checkable

from behaviors.base import Status
from behaviors.json_form import json_form
from companion.checks import require_instance


class Outcome(StrEnum):
    """How a procedure ended (module docstring)."""

    COMPLETED = "completed"
    FAILED = "failed"
    ABORTED = "aborted"
    REFUSED = "refused"
    NOT_STARTED = "not started"
    RUNNING = "running"

    @classmethod
    def of(cls, value: "str | Outcome") -> "Outcome":
        """``value`` as an outcome; ValueError naming the words for anything else."""
        try:
            return cls(value)
        except ValueError:
            raise ValueError(f"an outcome is one of {', '.join(STATUSES)}, not {value!r}") from None


STATUSES = tuple(outcome.value for outcome in Outcome)

_STATUS_NAMES = {Status.SUCCESS: Outcome.COMPLETED, Status.FAILURE: Outcome.FAILED, Status.ABORTED: Outcome.ABORTED,
                 Status.RUNNING: Outcome.RUNNING, Status.INVALID: Outcome.NOT_STARTED}


def status_name(status: Status) -> Outcome:
    """The product's outcome for a behaviour's lifecycle status (module docstring)."""
    return _STATUS_NAMES[status]


def finite_or_none(value: Any) -> float | None:
    """A finite number as a float, anything else None (JSON holds no NaN or Infinity)."""
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) \
        else None


def figures_of(result: dict, keys: tuple[str, ...]) -> dict:
    """The named figures of a result, each finite or None, plus its status (and its reason, when it
    did not complete)."""
    figures = {key: finite_or_none(result.get(key)) for key in keys} | {"status": result.get("status")}
    reason = result.get("abort_reason") or result.get("reason")
    if result.get("status") != "completed" and reason:
        figures["reason"] = reason
    return figures


@runtime_checkable
class ProcedureFigures(Protocol):
    """What a procedure measured (module docstring): a frozen record read by attribute, whose
    ``to_dict`` is its strict JSON (NaN and infinities null), the keys its stored row begins with."""

    def to_dict(self) -> dict: ...


@dataclass(frozen=True)
class NoFigures:
    """The figures of a procedure that measured nothing (refused, or never started): no key."""

    def to_dict(self) -> dict:
        return {}


#: the figures of a procedure that never started
NO_FIGURES = NoFigures()

#: a procedure's own figures type (``IdentificationCampaign.result()`` gives ``ProcedureResult[CampaignFigures]``)
Figures = TypeVar("Figures", bound=ProcedureFigures)


@dataclass(frozen=True)
class ProcedureResult(Generic[Figures]):
    """A procedure's outcome and figures (module docstring)."""

    procedure: str
    status: Outcome
    reason: str | None = None
    figures: Figures = NO_FIGURES  # type: ignore[assignment] # the default: no figures (never started)
    pilot_has_it: bool = False  # aborted because someone else took the vehicle
    restore_problems: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", Outcome.of(self.status))  # a word given is checked and typed
        require_instance(self, "figures", ProcedureFigures)  # a record with to_dict(), never a dict

    @classmethod
    def of(cls, procedure: str, status: Status, reason: str | None, figures: Figures) -> "ProcedureResult[Figures]":
        """The result of a behaviour in lifecycle ``status`` (the reason kept unless it succeeded)."""
        return cls(procedure, status_name(status), None if status is Status.SUCCESS else reason, figures)

    @property
    def completed(self) -> bool:
        return self.status == "completed"

    def with_outcome(self, outcome: Any) -> "ProcedureResult[Figures]":
        """This result as the runner saw it end (``RunOutcome``): an abort or failure it reported
        takes precedence over the procedure's own status; a takeover and restore problems are kept."""
        status, reason = self.status, self.reason
        if outcome.status != "completed":
            status, reason = outcome.status, outcome.reason
        return replace(self, status=status, reason=reason, pilot_has_it=bool(outcome.pilot_has_it),
                       restore_problems=tuple(outcome.restore_problems))

    def to_json(self) -> dict:
        """The stored and printed form: the figures, then ``status``, ``abort_reason`` (when there is
        a reason), ``pilot_has_it`` and ``restore_problems``."""
        out = self.figures.to_dict()
        out["status"] = self.status
        if self.reason:
            out["abort_reason"] = self.reason
        out["pilot_has_it"] = self.pilot_has_it
        out["restore_problems"] = list(self.restore_problems)
        return out

    def to_dict(self) -> dict:
        """:meth:`to_json` in strict JSON (NaN and infinities null): a procedure is a behaviour, and
        this is its result's JSON like any behaviour's."""
        return json_form(self.to_json())
