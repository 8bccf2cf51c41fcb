"""A roll impulse and the response to it (thesis §4.5, Fig. 4.9: a 25° tank impulse).

Writes the one-shot impulse parameter (``roll_kick``, degrees; a simulator hook), then records
roll for ``record_s`` after the impulse, with the rolling mass centred (open loop) or under
:class:`RollStabilisation` (closed loop). The impulse is located in the data, as the first sample
whose roll departs from the level before it by more than half the impulse, so its timing does
not depend on when the parameter echo came back.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from behaviors.base import Behaviour, Footprint, Status
from behaviors.roll_stabilisation import RollStabilisation, RollStabilisationConfig
from companion.checks import require_instance, require_measured
from companion.interface import Command, SetParameters, SetRollingMass, Telemetry
from companion.numerics.roll import settle_time


@dataclass(frozen=True)
class RollKickResult:
    """How the impulse test ended: its name and lifecycle status, the vehicle time the impulse was
    seen (None: never), and the settling time after it (s; None: not seen, or never settled)."""

    name: str
    status: Status
    kicked_at: float | None
    settle_s: float | None

    def __post_init__(self) -> None:
        require_instance(self, "status", Status)
        require_measured(self, "settle_s")
        if self.kicked_at is None and self.settle_s is not None:
            raise ValueError("RollKickResult: no settling time without an impulse seen")

    def to_dict(self) -> dict:
        return {"name": self.name, "status": self.status.value, "kicked_at": self.kicked_at,
                "settle_s": self.settle_s}


class RollKick(Behaviour):
    def __init__(self, kick_deg: float, record_s: float, level: Callable[[], float], *, closed_loop: bool,
                 settle_band_deg: float = 2.5, max_wait_s: float = 10.0) -> None:
        super().__init__(f"roll kick {'closed' if closed_loop else 'open'} loop")
        self.kick_deg = kick_deg
        self.record_s = record_s
        self.level = level
        self.closed_loop = closed_loop
        self.settle_band_deg = settle_band_deg
        self.max_wait_s = max_wait_s
        self.controller = RollStabilisation(RollStabilisationConfig()) if closed_loop else None
        self.footprint = Footprint.of(parameters=("roll_kick",), setpoints=("rolling_mass",))
        self.times: list[float] = []
        self.roll: list[float] = []
        self.kicked_at: float | None = None
        self._level = math.nan

    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        self._level = self.level()
        return [SetParameters({"roll_kick": self.kick_deg})]

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        commands: list[Command] = list(self.controller.tick(telemetry)) if self.controller is not None else []
        if telemetry.finite("roll"):
            self.times.append(telemetry.time_s)
            self.roll.append(telemetry.roll)
            if self.kicked_at is None and abs(telemetry.roll - self._level) > math.radians(0.5 * abs(self.kick_deg)):
                self.kicked_at = telemetry.time_s
        now = telemetry.time_s
        if self.kicked_at is None and now - self.started_s > self.max_wait_s:
            self.finish(Status.FAILURE, "the roll impulse was not seen in the telemetry")
        elif self.kicked_at is not None and now - self.kicked_at >= self.record_s:
            self.finish(Status.SUCCESS)
        return commands

    def terminate(self, status: Status) -> Sequence[Command]:
        if self.controller is not None and not self.controller.done:
            self.controller.stop("roll kick recorded")
        return [SetRollingMass(0.0)] if status is Status.ABORTED else []

    def settle_time_s(self) -> float | None:
        """Settling time (s) within ±band of the level before the impulse, from the impulse."""
        if self.kicked_at is None:
            return None
        times = np.asarray(self.times, dtype=float)
        roll = np.asarray(self.roll, dtype=float) - self._level
        after = times >= self.kicked_at
        if after.sum() < 2:
            return None
        value = settle_time(times[after] - self.kicked_at, roll[after], band=math.radians(self.settle_band_deg))
        return float(value) if value is not None and math.isfinite(value) else None

    def result(self) -> RollKickResult:
        return RollKickResult(self.name, self.status, self.kicked_at, self.settle_time_s())
