"""A computation that takes wall-clock seconds, run beside the control loop instead of inside it.

On a vehicle that does not wait for the companion (real firmware, ArduPilot SITL), a step that computes
for two seconds inside the loop stops the loop for two seconds: no snapshot is read, no set-point is
refreshed, and ArduRover's GUIDED stops the boat after 3 s without one (measured at 10× on SITL: a
design by prediction took 2 s of wall time, 20 s of vehicle time, and the next heading step began
with the boat at 0.25 m/s). :class:`BackgroundStep` runs the computation in a thread and keeps
ticking — nothing to command, so the link keeps refreshing what the vehicle holds — until the result
is there, then hands it to ``then``, whose commands it returns. The result is the same function of
the same inputs; only when, in vehicle time, it arrives depends on the machine. Where the vehicle
waits for the companion (our simulator in lockstep, the in-process vehicle) the caller computes in
the loop instead, so a run stays a function of its seed.
"""
from __future__ import annotations

import logging
import threading
from typing import Callable, Generic, Sequence, TypeVar

from behaviors.base import Behaviour, Status
from companion.interface import Command, Telemetry

log = logging.getLogger(__name__)

T = TypeVar("T")


class BackgroundStep(Behaviour, Generic[T]):
    """``work()`` in a daemon thread from the first tick; once it returned, ``then(result)``'s
    commands and SUCCESS. An exception in ``work`` ends the step with FAILURE and its message."""

    def __init__(self, work: Callable[[], T], then: Callable[[T], Sequence[Command]], *, name: str = "background") -> None:
        super().__init__(name)
        self._work, self._then = work, then
        self._thread: threading.Thread | None = None
        self._done = threading.Event()
        self._result: T | None = None
        self._error: BaseException | None = None

    def _run(self) -> None:
        try:
            self._result = self._work()
        except Exception as exc:  # noqa: BLE001 - said as the step's failure, never lost in a thread
            self._error = exc
        finally:
            self._done.set()

    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()
        return []

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        if not self._done.is_set():
            return []
        if self._error is not None:
            log.error("%s failed: %s", self.name, self._error)
            self.finish(Status.FAILURE, f"{self.name}: {type(self._error).__name__}: {self._error}")
            return []
        commands = list(self._then(self._result))  # type: ignore[arg-type]
        self.finish(Status.SUCCESS)
        return commands

    def terminate(self, status: Status) -> Sequence[Command]:
        return []  # the thread computes only: left to finish on its own, its result unused
