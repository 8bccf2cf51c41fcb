"""Active roll stabilisation with the internal rolling mass (SPEC C6; thesis 002, §4.4–4.5).

Steps on telemetry.roll at the telemetry rate (vehicle time) and emits SetRollingMass with the PI
law of :mod:`companion.numerics.roll` (default: restoring angle + roll-rate feedback with the
seed's integral zero at 0.01 and anti-windup clamp at the ±20° mass limit; the seed's own law,
``seed_gains``, can be passed in the config). A new command is sent only when it differs from the last
one by at least ``command_quantum`` (one microsecond of PWM on a ±30° channel ≈ 0.001 rad), so the
DO_SET_SERVO traffic stays at most the telemetry rate. ``abort()`` centres the mass.

Records roll and mass-angle series; ``result()`` gives mean and standard deviation of roll (the
figures of Table 4.3, whose closed-loop mean of 0.04° shows a steady state: the statistics skip the
first ``stats_after_s`` seconds after switch-on) and of the mass angle, and the fraction of time the command was at its limit.
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np

from companion.checks import require_count, require_measured, require_non_negative, require_positive, require_range
from behaviors.base import Behaviour, Footprint, Status
from behaviors.json_form import finite_floats, json_form
from companion.interface import Command, SetRollingMass, StatusText, Telemetry
from companion.numerics.roll import RollPI, RollPIGains, RollVehicle, linearise, rate_feedback_gains


def default_gains() -> RollPIGains:
    """The rate-feedback design on the Table 4.1 vehicle (kp ≈ 6.5, kd ≈ 13, zero at 0.01)."""
    return rate_feedback_gains(linearise(RollVehicle()))


@dataclass(frozen=True)
class RollStabilisationConfig:
    gains: RollPIGains = field(default_factory=default_gains)
    command_quantum: float = 0.001  # rad
    duration_s: float | None = None  # None: until aborted
    record_stride: int = 1  # keep every n-th sample in the series
    stats_after_s: float = 10.0  # roll/mass statistics skip the switch-on transient (steady state, Table 4.3)

    def __post_init__(self) -> None:
        require_positive(self, "command_quantum")
        require_non_negative(self, "stats_after_s")
        require_range(self, "duration_s", 1e-3, 1e6, optional=True)
        if not (isinstance(self.record_stride, int) and self.record_stride >= 1):
            raise ValueError(f"RollStabilisationConfig.record_stride must be an integer ≥ 1, not {self.record_stride!r}")


@dataclass(frozen=True)
class RollStabilisationResult:
    """The roll loop as run (module docstring): whether it was aborted and why, the samples in the
    statistics, the mean and standard deviation of roll and of the mass angle (deg; None without a
    sample), the fraction of them with the mass command at its limit, the gains, and the recorded
    series (``time`` from the first sample, ``roll``, ``mass_command``, ``mass_angle``)."""

    aborted: bool
    abort_reason: str
    samples: int
    roll_mean_deg: float | None
    roll_std_deg: float | None
    mass_mean_deg: float | None
    mass_std_deg: float | None
    mass_saturated_fraction: float | None
    gains: RollPIGains
    series: dict[str, list[float]]

    def __post_init__(self) -> None:
        require_count(self, "samples")
        require_measured(self, "roll_std_deg", "mass_std_deg")
        require_range(self, "mass_saturated_fraction", 0.0, 1.0, optional=True)

    def to_dict(self) -> dict:
        return json_form({"behavior": "roll_stabilisation", "aborted": self.aborted, "abort_reason": self.abort_reason,
                          "samples": self.samples, "roll_mean_deg": self.roll_mean_deg,
                          "roll_std_deg": self.roll_std_deg, "mass_mean_deg": self.mass_mean_deg,
                          "mass_std_deg": self.mass_std_deg, "mass_saturated_fraction": self.mass_saturated_fraction,
                          "gains": asdict(self.gains),
                          "series": {name: finite_floats(values) for name, values in self.series.items()}})


class RollStabilisation(Behaviour):
    """Roll PI on the rolling mass."""

    footprint = Footprint.of(setpoints=("rolling_mass",))

    def __init__(self, config: RollStabilisationConfig = RollStabilisationConfig()) -> None:
        super().__init__("roll stabilisation")
        self.config = config
        self.controller = RollPI(config.gains)
        self._start: float | None = None
        self._last_sent = math.nan
        self._samples = 0
        self.series: dict[str, list[float]] = {"time": [], "roll": [], "mass_command": [], "mass_angle": []}
        self._roll_all: list[float] = []
        self._command_all: list[float] = []

    @property
    def first_sample_time_s(self) -> float | None:
        """Vehicle time of the first sample with a roll angle (the series' times are relative to it)."""
        return self._start

    @property
    def aborted(self) -> bool:
        return self.status is Status.ABORTED

    def terminate(self, status: Status) -> Sequence[Command]:
        """An abort centres the mass (a completed run leaves it to the next step)."""
        if status is not Status.ABORTED:
            return []
        logging.getLogger(__name__).info("roll stabilisation aborted: %s", self.reason)
        self._last_sent = 0.0
        return [SetRollingMass(0.0), StatusText(f"roll stab aborted: {self.reason}"[:50], 4)]

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        if not telemetry.finite("roll"):
            return []
        now = telemetry.time_s
        commands: list[Command] = []
        if self._start is None:
            self._start = now
            commands.append(StatusText("roll stabilisation on"))
        elapsed = now - self._start
        command = self.controller.update(now, telemetry.roll, telemetry.roll_rate)
        if not math.isfinite(self._last_sent) or abs(command - self._last_sent) >= self.config.command_quantum:
            commands.append(SetRollingMass(command))
            self._last_sent = command
        skip = self.config.stats_after_s
        if self.config.duration_s is not None:
            skip = min(skip, 0.5 * self.config.duration_s)  # short runs keep at least their second half
        if elapsed >= skip:
            self._roll_all.append(telemetry.roll)
            self._command_all.append(command)
        if self._samples % max(1, self.config.record_stride) == 0:
            s = self.series
            s["time"].append(elapsed)
            s["roll"].append(telemetry.roll)
            s["mass_command"].append(command)
            s["mass_angle"].append(telemetry.mass_angle)
        self._samples += 1
        if self.config.duration_s is not None and elapsed >= self.config.duration_s:
            self.finish(Status.SUCCESS)
        return commands

    def result(self) -> RollStabilisationResult:
        roll = np.asarray(self._roll_all, dtype=float)
        command = np.asarray(self._command_all, dtype=float)
        limit = self.config.gains.limit
        deg = math.degrees

        def stat(values: np.ndarray, fn) -> float | None:
            return float(deg(fn(values))) if len(values) else None

        return RollStabilisationResult(
            aborted=self.aborted, abort_reason=self.reason or "", samples=int(len(roll)),
            roll_mean_deg=stat(roll, np.mean), roll_std_deg=stat(roll, np.std),
            mass_mean_deg=stat(command, np.mean), mass_std_deg=stat(command, np.std),
            mass_saturated_fraction=float(np.mean(np.abs(command) >= limit - 1e-9)) if len(command) else None,
            gains=self.config.gains, series={name: list(values) for name, values in self.series.items()})
