"""Behaviours one after another, as one behaviour; and the one-shot :class:`Instant`.

A procedure is a :class:`SequenceBehavior` run by one runner under one restore point
(``companion.procedures.runner``). Items are behaviours or :class:`Deferred` steps: a factory that
builds the next behaviour when its turn comes (so a later step can use what earlier steps found,
e.g. gains designed from accepted models), with the footprint it declares in advance (the restore
point is taken before the factory runs). A factory may return None to skip its step.

A child that ends in FAILURE does not stop the sequence unless ``stop_on_failure`` is set (a
campaign goes on to the next thrust when one thrust yields no model); ``stop`` aborts the running
child only.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Sequence, Union

from behaviors.base import Behaviour, BehaviourResult, Footprint, Status, footprint_of
from companion.checks import require_instance
from companion.interface import (
    Command,
    OverrideActuator,
    SetDepth,
    SetHeading,
    SetMode,
    SetParameters,
    SetRollingMass,
    SetThrust,
    Telemetry,
)


def footprint_of_commands(commands: Iterable[Command]) -> Footprint:
    """The parameters and set-points a list of commands changes."""
    parameters: set[str] = set()
    setpoints: set[str] = set()
    for command in commands:
        if isinstance(command, SetParameters):
            parameters |= set(command.values)
        elif isinstance(command, SetMode):
            setpoints.add("mode")
        elif isinstance(command, SetThrust):
            setpoints.add("thrust")
        elif isinstance(command, SetHeading):
            setpoints.add("heading")
        elif isinstance(command, SetDepth):
            setpoints.add("depth")
        elif isinstance(command, SetRollingMass):
            setpoints.add("rolling_mass")
        elif isinstance(command, OverrideActuator):
            setpoints.add(command.actuator)
    return Footprint.of(parameters, setpoints)


class Instant(Behaviour):
    """Sends some commands once and is done (mode, set-points, parameters).

    ``make``, if given, builds further commands from the snapshot it is ticked with (e.g. gains for
    the speed measured at that moment); what those may touch is declared with ``touches``."""

    def __init__(self, *commands: Command, name: str = "instant",
                 make: Callable[[Telemetry], Sequence[Command]] | None = None,
                 touches: Footprint = Footprint()) -> None:
        super().__init__(name)
        self.commands = list(commands)
        self.make = make
        self.footprint = footprint_of_commands(self.commands) | touches

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        self.finish(Status.SUCCESS)
        return self.commands + (list(self.make(telemetry)) if self.make is not None else [])


@dataclass(frozen=True)
class Deferred:
    """A step built when its turn comes; ``footprint`` declares what the built behaviour may touch."""

    factory: Callable[[], "Behaviour | None"]
    footprint: Footprint = Footprint()


Item = Union[Behaviour, Deferred]


@dataclass(frozen=True)
class SequenceResult:
    """How a sequence ended and what each of its finished steps found, in order."""

    name: str
    status: Status
    reason: str | None
    steps: tuple[BehaviourResult, ...]

    def __post_init__(self) -> None:
        require_instance(self, "status", Status)

    def to_dict(self) -> dict:
        return {"name": self.name, "status": self.status.value, "reason": self.reason,
                "steps": [step.to_dict() for step in self.steps]}


class SequenceBehavior(Behaviour):
    """Behaviours in order; ``on_complete(behaviour)`` is called as each one finishes."""

    def __init__(self, items: Iterable[Item], on_complete: Callable[[Behaviour], None] | None = None, *,
                 name: str = "sequence", stop_on_failure: bool = False) -> None:
        super().__init__(name)
        self._items = list(items)
        for item in self._items:
            if not isinstance(item, (Behaviour, Deferred)):
                raise TypeError(f"a sequence holds behaviours or Deferred steps, not {type(item).__name__}")
        self.footprint = Footprint.union(footprint_of(item) for item in self._items)
        self._index = -1
        self._current: Behaviour | None = None
        self._on_complete = on_complete
        self.stop_on_failure = stop_on_failure
        self.completed: list[Behaviour] = []

    @property
    def current(self) -> Behaviour | None:
        return self._current

    def _advance(self) -> None:
        while self._current is None and self._index < len(self._items) - 1:
            self._index += 1
            item = self._items[self._index]
            self._current = item.factory() if isinstance(item, Deferred) else item

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        commands: list[Command] = []
        self._advance()
        while self._current is not None:
            commands += self._current.tick(telemetry)
            if not self._current.done:
                break
            finished, self._current = self._current, None
            self.completed.append(finished)
            if self._on_complete is not None:
                self._on_complete(finished)
            if self.stop_on_failure and finished.status is not Status.SUCCESS:
                self.finish(Status.FAILURE, f"{finished.name}: {finished.reason or finished.status.value}")
                return commands
            self._advance()
            if self._current is not None and not isinstance(self._current, Instant):
                break  # a real behaviour starts on the next snapshot
        if self._current is None and self._index >= len(self._items) - 1:
            self.finish(Status.SUCCESS)
        return commands

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is Status.ABORTED and self._current is not None:
            current, self._current = self._current, None
            return current.stop(self.reason or "aborted")
        return []

    def result(self) -> BehaviourResult:  # a procedure built on a sequence gives its ProcedureResult
        return SequenceResult(self.name, self.status, self.reason, tuple(b.result() for b in self.completed))


class ParallelBehavior(Behaviour):
    """Children stepped on the same telemetry, their commands concatenated (the quick procedure: the yaw and
    pitch identifications at one thrust run together — the axes are decoupled in the model and
    their doublets are staggered, so each estimator sees an input the other does not drive).

    Done when every child is; SUCCESS only if every child succeeded, otherwise FAILURE with the
    first child's reason. An abort stops every child still running."""

    def __init__(self, children: Sequence[Behaviour], name: str | None = None) -> None:
        super().__init__(name or "parallel")
        self.children = list(children)
        footprint = Footprint()
        for child in self.children:
            footprint = footprint | footprint_of(child)
        self.footprint = footprint

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        commands: list[Command] = []
        for child in self.children:
            commands += child.tick(telemetry)
        if all(child.done for child in self.children):
            failed = [child for child in self.children if child.status is not Status.SUCCESS]
            if failed:
                self.finish(Status.FAILURE, failed[0].reason)
            else:
                self.finish(Status.SUCCESS)
        return commands

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is not Status.ABORTED:
            return []
        commands: list[Command] = []
        for child in self.children:
            commands += child.stop(self.reason or "aborted")
        return commands
