"""Hold still and record: settle periods and open-loop baselines (e.g. roll with the mass centred).

Sends ``commands`` once at the start, then records the named telemetry fields for ``duration_s`` of
vehicle time. A pure step function of telemetry, like every behaviour.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from companion.interface import Command, Telemetry


class Observe:
    def __init__(self, duration_s: float, fields: Sequence[str] = ("roll",), commands: Sequence[Command] = (),
                 label: str = "observe") -> None:
        self.duration_s = duration_s
        self.fields = tuple(fields)
        self.commands = list(commands)
        self.label = label
        self.series: dict[str, list[float]] = {"time": [], **{name: [] for name in self.fields}}
        self._start: float | None = None
        self._done = False
        self.aborted = False

    @property
    def done(self) -> bool:
        return self._done

    def step(self, telemetry: Telemetry) -> Sequence[Command]:
        if self._done:
            return []
        commands: list[Command] = []
        if self._start is None:
            self._start = telemetry.time_s
            commands = list(self.commands)
        self.series["time"].append(telemetry.time_s)
        for name in self.fields:
            self.series[name].append(getattr(telemetry, name))
        if telemetry.time_s - self._start >= self.duration_s:
            self._done = True
        return commands

    def abort(self, reason: str) -> Sequence[Command]:
        self._done = True
        self.aborted = True
        return []

    def std_deg(self, name: str) -> float:
        values = np.asarray(self.series[name], dtype=float)
        values = values[np.isfinite(values)]
        return float(np.degrees(np.std(values))) if len(values) else math.nan

    def result(self) -> dict:
        return {"label": self.label, "duration_s": self.duration_s, "aborted": self.aborted,
                "series": {k: [float(v) if math.isfinite(v) else None for v in vals] for k, vals in self.series.items()}}
