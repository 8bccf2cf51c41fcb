"""Hold still and record: settle periods and open-loop baselines (e.g. roll with the mass centred).

Sends ``commands`` once at the start, then records the named telemetry fields for ``duration_s`` of
vehicle time. A pure step function of telemetry, like every behaviour.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from behaviors.base import Behaviour, Status
from behaviors.json_form import finite_floats
from behaviors.sequence import footprint_of_commands
from companion.checks import require_non_negative
from companion.interface import Command, Telemetry


@dataclass(frozen=True)
class ObserveResult:
    """What was recorded: the label, how long it was to record (s of vehicle time), whether it was
    aborted, and the named telemetry fields sample by sample beside ``time``."""

    label: str
    duration_s: float
    aborted: bool
    series: dict[str, list[float]]

    def __post_init__(self) -> None:
        require_non_negative(self, "duration_s")
        if len({len(values) for values in self.series.values()}) > 1:
            raise ValueError("ObserveResult.series must hold one value per sample in every field, not "
                             f"{ {name: len(values) for name, values in self.series.items()} }")

    def std_deg(self, name: str) -> float:
        """The standard deviation in degrees of a field recorded in radians, over its finite values
        (NaN without any)."""
        values = np.asarray(self.series[name], dtype=float)
        values = values[np.isfinite(values)]
        return float(np.degrees(np.std(values))) if len(values) else math.nan

    def to_dict(self) -> dict:
        return {"label": self.label, "duration_s": self.duration_s, "aborted": self.aborted,
                "series": {name: finite_floats(values) for name, values in self.series.items()}}


class Observe(Behaviour):
    def __init__(self, duration_s: float, fields: Sequence[str] = ("roll",), commands: Sequence[Command] = (),
                 label: str = "observe") -> None:
        super().__init__(label)
        self.duration_s = duration_s
        self.fields = tuple(fields)
        self.commands = list(commands)
        self.label = label
        self.footprint = footprint_of_commands(self.commands)
        self.series: dict[str, list[float]] = {"time": [], **{name: [] for name in self.fields}}

    @property
    def aborted(self) -> bool:
        return self.status is Status.ABORTED

    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        return list(self.commands)

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        self.series["time"].append(telemetry.time_s)
        for name in self.fields:
            self.series[name].append(getattr(telemetry, name))
        if telemetry.time_s - self.started_s >= self.duration_s:
            self.finish(Status.SUCCESS)
        return []

    def result(self) -> ObserveResult:
        return ObserveResult(self.label, self.duration_s, self.aborted,
                             {name: list(values) for name, values in self.series.items()})
