"""The one lifecycle every behaviour follows (SPEC §5, layer 3).

A behaviour is a step function of vehicle time and telemetry. Its lifecycle is the one of
py_trees' ``behaviour.py``, written out once here so no behaviour repeats it:

    tick(telemetry):   first tick  -> initialise(telemetry)   (status becomes RUNNING)
                       every tick  -> update(telemetry)        (may call finish(...))
                       on finish   -> terminate(status)        (release what it holds)
    stop(reason):      terminate(ABORTED), once, whatever the state

Each hook returns the :class:`~companion.interface.Command` objects to send now. A behaviour also
declares its :class:`Footprint`: the parameters (product-neutral names) and set-points it may
change. The procedure runner derives the restore point from these declarations, so what a
behaviour touches is put back on abort without a hard-coded list anywhere else.

``step`` / ``abort`` / ``done`` keep the older protocol of :class:`companion.interface.Behavior`,
so the runner and the sequence need nothing else.

``result()`` gives what the behaviour found as a :class:`BehaviourResult`: a frozen record read by
attribute, validated where it is made, whose ``to_dict()`` is its strict JSON (the store's and the
printed form, taken only there). A behaviour that finds nothing but how it ended gives a
:class:`LifecycleResult`; docs/store.md lists every result type and its JSON keys.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Iterable, Protocol, Sequence

from companion.checks import require_instance
from companion.interface import Command, Telemetry


class Status(enum.Enum):
    """Where a behaviour is in its lifecycle (py_trees' Status, plus ABORTED for a stop)."""

    INVALID = "invalid"  # not started yet
    RUNNING = "running"
    SUCCESS = "success"  # reached its goal
    FAILURE = "failure"  # ended without reaching its goal (e.g. no model passed validation)
    ABORTED = "aborted"  # stopped from outside (signal, pilot, link loss, safety limit)

    @property
    def finished(self) -> bool:
        return self in (Status.SUCCESS, Status.FAILURE, Status.ABORTED)


class BehaviourResult(Protocol):
    """What a behaviour found (module docstring): read by attribute; ``to_dict`` is its strict JSON."""

    def to_dict(self) -> dict: ...


@dataclass(frozen=True)
class LifecycleResult:
    """How a behaviour that finds nothing else ended: its name, its lifecycle status and why it failed
    or was aborted."""

    name: str
    status: Status
    reason: str | None = None

    def __post_init__(self) -> None:
        require_instance(self, "status", Status)

    def to_dict(self) -> dict:
        return {"name": self.name, "status": self.status.value, "reason": self.reason}


#: set-points a behaviour may change; a restore point records each one it can read back
SETPOINTS = frozenset({"mode", "thrust", "heading", "depth", "rolling_mass", "rudder", "elevator"})


@dataclass(frozen=True)
class Footprint:
    """What a behaviour may change on the vehicle: neutral parameter names and set-points.

    ``parameters`` are profile-neutral names (``heading_p``, ``pitch_i``, ``roll_disturbance`` ...);
    ``setpoints`` are members of :data:`SETPOINTS` (overridden actuators count as set-points)."""

    parameters: frozenset[str] = frozenset()
    setpoints: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        unknown = set(self.setpoints) - SETPOINTS
        if unknown:
            raise ValueError(f"unknown set-points {sorted(unknown)} (known: {sorted(SETPOINTS)})")

    @classmethod
    def of(cls, parameters: Iterable[str] = (), setpoints: Iterable[str] = ()) -> "Footprint":
        return cls(frozenset(parameters), frozenset(setpoints))

    def __or__(self, other: "Footprint") -> "Footprint":
        return Footprint(self.parameters | other.parameters, self.setpoints | other.setpoints)

    @staticmethod
    def union(footprints: Iterable["Footprint"]) -> "Footprint":
        total = Footprint()
        for footprint in footprints:
            total = total | footprint
        return total


class Behaviour:
    """Base class: subclasses implement ``update`` (and, where needed, ``initialise``,
    ``terminate`` and ``result``) and declare ``footprint``."""

    #: what the behaviour may change (class default; an instance may set its own)
    footprint: Footprint = Footprint()

    def __init__(self, name: str | None = None) -> None:
        self.name = name or type(self).__name__
        self.status = Status.INVALID
        self.reason: str | None = None  # why it failed or was aborted
        self.start_time_s: float | None = None  # vehicle time of the first tick

    # ------------------------------------------------------------------ hooks
    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        """Called on the first tick, before the first ``update``."""
        return []

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        """One step of the behaviour; call :meth:`finish` to end it."""
        raise NotImplementedError

    def terminate(self, status: Status) -> Sequence[Command]:
        """Called once when the behaviour ends (any status): release what it holds."""
        return []

    def result(self) -> BehaviourResult:
        """What the behaviour found (module docstring); here only how it ended."""
        return LifecycleResult(self.name, self.status, self.reason)

    # ------------------------------------------------------------------ lifecycle (final)
    def finish(self, status: Status = Status.SUCCESS, reason: str | None = None) -> None:
        """End the behaviour from inside ``initialise``/``update``; ``terminate`` follows."""
        if not status.finished:
            raise ValueError(f"finish needs a final status, not {status}")
        self.status = status
        if reason is not None:
            self.reason = reason

    def tick(self, telemetry: Telemetry) -> list[Command]:
        if self.status.finished:
            return []
        commands: list[Command] = []
        if self.status is Status.INVALID:
            self.status = Status.RUNNING
            self.start_time_s = telemetry.time_s
            commands += self.initialise(telemetry)
        if self.status is Status.RUNNING:
            commands += self.update(telemetry)
        if self.status.finished:
            commands += self.terminate(self.status)
        return commands

    def stop(self, reason: str) -> list[Command]:
        """Abort from outside: ``terminate(ABORTED)`` once; nothing if already finished."""
        if self.status.finished:
            return []
        self.status = Status.ABORTED
        self.reason = reason
        return list(self.terminate(Status.ABORTED))

    @property
    def done(self) -> bool:
        return self.status.finished

    @property
    def started_s(self) -> float:
        """Vehicle time of the first tick (``start_time_s``); RuntimeError before it."""
        if self.start_time_s is None:
            raise RuntimeError(f"{self.name} has not started (no tick yet)")
        return self.start_time_s

    # the runner's protocol (companion.interface.Behavior)
    def step(self, telemetry: Telemetry) -> list[Command]:
        return self.tick(telemetry)

    def abort(self, reason: str) -> list[Command]:
        return self.stop(reason)


def footprint_of(item: object) -> Footprint:
    """The declared footprint of a behaviour (or of a deferred step), empty when none is declared."""
    footprint = getattr(item, "footprint", None)
    return footprint if isinstance(footprint, Footprint) else Footprint()
