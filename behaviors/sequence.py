"""Run behaviours one after another, as one behaviour (the campaign is built from these).

Items are behaviours or zero-argument factories that build the next behaviour when its turn comes
(so a later step can use what earlier steps found, e.g. gains designed from accepted models).
A factory may return None to skip its step. ``abort`` aborts the running item only.
"""
from __future__ import annotations

from typing import Callable, Iterable, Sequence, Union

from companion.interface import Behavior, Command, Telemetry

Item = Union[Behavior, Callable[[], "Behavior | None"]]


class Instant:
    """A behaviour that sends some commands once and is done (mode, set-points, parameters).

    ``make``, if given, builds further commands from the snapshot it is stepped with (e.g. gains
    for the speed measured at that moment)."""

    def __init__(self, *commands: Command, name: str = "instant",
                 make: Callable[[Telemetry], Sequence[Command]] | None = None) -> None:
        self.commands = list(commands)
        self.name = name
        self.make = make
        self._done = False

    @property
    def done(self) -> bool:
        return self._done

    def step(self, telemetry: Telemetry) -> Sequence[Command]:
        self._done = True
        return self.commands + (list(self.make(telemetry)) if self.make is not None else [])

    def abort(self, reason: str) -> Sequence[Command]:
        self._done = True
        return []

    def result(self) -> dict:
        return {"name": self.name}


class SequenceBehavior:
    """Behaviours in order; ``on_complete(behavior)`` is called as each one finishes."""

    def __init__(self, items: Iterable[Item], on_complete: Callable[[Behavior], None] | None = None) -> None:
        self._items = list(items)
        self._index = -1
        self._current: Behavior | None = None
        self._on_complete = on_complete
        self.completed: list[Behavior] = []
        self.aborted = False

    @property
    def done(self) -> bool:
        return self.aborted or (self._current is None and self._index >= len(self._items) - 1)

    @property
    def current(self) -> Behavior | None:
        return self._current

    def _advance(self) -> None:
        while self._current is None and self._index < len(self._items) - 1:
            self._index += 1
            item = self._items[self._index]
            behavior = item if hasattr(item, "step") else item()
            self._current = behavior

    def step(self, telemetry: Telemetry) -> Sequence[Command]:
        commands: list[Command] = []
        self._advance()
        while self._current is not None:
            commands += self._current.step(telemetry)
            if not self._current.done:
                break
            finished, self._current = self._current, None
            self.completed.append(finished)
            if self._on_complete is not None:
                self._on_complete(finished)
            self._advance()
            if self._current is not None and not isinstance(self._current, Instant):
                break  # a real behaviour starts on the next snapshot
        return commands

    def abort(self, reason: str) -> Sequence[Command]:
        self.aborted = True
        commands = list(self._current.abort(reason)) if self._current is not None else []
        self._current = None
        return commands

    def result(self) -> dict:
        return {"steps": [b.result() for b in self.completed], "aborted": self.aborted}
