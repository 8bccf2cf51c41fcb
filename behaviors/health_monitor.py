"""Health monitoring while the vehicle works: passive yaw identification from
ordinary manoeuvres compared with the stored model at the same speed
(:mod:`companion.numerics.drift`: windowed SVF least squares with a HAC covariance, two-sided
CUSUMs of a22 and b2 scaled by it).

A step function of telemetry (SPEC §5) that never commands the vehicle: it only reports. Every
closed window sends NAMED_VALUE_FLOATs ``hm_a22r`` and ``hm_b2r`` (estimate / reference) and
``hm_cusum`` (the larger CUSUM statistic); the first alarm sends a STATUSTEXT warning (severity 4)
naming the parameter, its change and the CUSUM, and queues an ``alarm`` event with the evidence
(the windows that led to it) for the application to store. The alarm latches: one per session.
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from typing import Callable, Sequence

from behaviors.json_form import json_form
from companion.checks import require_choice, require_count, require_interval
from companion.interface import Command, NamedValue, StatusText, Telemetry
from companion.numerics.drift import DriftConfig, DriftDetector, DriftVerdict, PassiveYawEstimator

log = logging.getLogger(__name__)

NAMES = {"a22": "yaw damping a22", "b2": "fin effectiveness b2"}
#: windows of evidence kept with an alarm
EVIDENCE_WINDOWS = 12


def verdict_row(verdict: DriftVerdict) -> dict:
    """One window as stored (and plotted): times, speed, estimates with σ, ratios, z, CUSUMs."""
    w = verdict.window
    return {"t_start": w.t_start, "t_end": w.t_end, "speed": w.speed, "samples": w.samples, "used": verdict.used,
            "heading_span_deg": w.heading_span_deg, "rudder_std": w.rudder_std,
            "reason": verdict.reason, "a22": w.a22, "b2": w.b2, "sigma_a22": w.sigma(0), "sigma_b2": w.sigma(1),
            "reference": dict(verdict.reference), "ratio": dict(verdict.ratio), "z": dict(verdict.z),
            "cusum": dict(verdict.cusum), "alarm": verdict.alarm}


@dataclass(frozen=True)
class HealthAlarm:
    """The alarm: the parameter whose CUSUM reached the threshold (:data:`NAMES`' keys), the vehicle
    time of the window that raised it, the parameter's change from the reference (%) and the CUSUM."""

    parameter: str
    time_s: float
    change_pct: float
    cusum: float

    def __post_init__(self) -> None:
        require_choice(self, "parameter", tuple(NAMES))

    def to_dict(self) -> dict:
        return json_form({"parameter": self.parameter, "time_s": self.time_s, "change_pct": self.change_pct,
                          "cusum": self.cusum})


@dataclass(frozen=True)
class HealthResult:
    """A monitoring session (module docstring): its label, configuration and the reference's speed
    range, every window's verdict (the drift plot's data; stored as :func:`verdict_row`), the alarm
    if one was raised, and how often the passive estimator restarted."""

    label: str
    config: DriftConfig
    speed_range: tuple[float, float]
    verdicts: tuple[DriftVerdict, ...]
    alarm: HealthAlarm | None
    restarts: int

    def __post_init__(self) -> None:
        require_interval(self, "speed_range")
        require_count(self, "restarts")

    def to_dict(self) -> dict:
        return json_form({"label": self.label, "config": asdict(self.config), "speed_range": self.speed_range,
                          "windows": [verdict_row(v) for v in self.verdicts],
                          "alarm": None if self.alarm is None else self.alarm.to_dict(), "restarts": self.restarts})


class HealthMonitor:
    """Passive identification + drift test against ``reference(speed) -> (a22, b2)`` on ``speed_range``."""

    def __init__(self, reference: Callable[[float], tuple[float, float]], speed_range: tuple[float, float],
                 config: DriftConfig = DriftConfig(), *, label: str = "") -> None:
        self.config = config
        self.label = label
        self.estimator = PassiveYawEstimator(config)
        self.detector = DriftDetector(reference, speed_range, config)
        self.verdicts: list[DriftVerdict] = []
        self.alarm: DriftVerdict | None = None
        self.events: list[dict] = []  # {"type": "alarm", "evidence": {...}}, drained by the application

    @classmethod
    def from_schedule(cls, schedule, config: DriftConfig = DriftConfig(), label: str = "") -> "HealthMonitor":
        """Against a stored :class:`companion.numerics.schedule.YawSchedule` (a22(u), b2(u))."""
        def reference(speed: float) -> tuple[float, float]:
            model = schedule.model_at(speed)
            return model.a22, model.b2
        return cls(reference, tuple(schedule.speed_range), config, label=label)

    def step(self, telemetry: Telemetry) -> Sequence[Command]:
        window = self.estimator.add(telemetry.time_s, telemetry.yaw, telemetry.rudder, telemetry.speed_water)
        if window is None:
            return []
        verdict = self.detector.add(window)
        self.verdicts.append(verdict)
        if not verdict.used:
            return []
        commands: list[Command] = [NamedValue("hm_a22r", verdict.ratio["a22"]), NamedValue("hm_b2r", verdict.ratio["b2"]),
                                   NamedValue("hm_cusum", max(verdict.cusum.values()))]
        if verdict.alarm is not None and self.alarm is None:
            self.alarm = verdict
            name = verdict.alarm
            change = 100.0 * (verdict.ratio[name] - 1.0)
            text = f"HEALTH: {NAMES[name]} {change:+.0f}% at {window.speed:.2f} m/s (CUSUM {verdict.cusum[name]:.1f})"
            log.warning("%s (window %.1f–%.1f s)", text, window.t_start, window.t_end)
            self.events.append({"type": "alarm", "evidence": self.evidence()})
            commands.append(StatusText(text[:50], 4))
        return commands

    def evidence(self) -> dict:
        """The alarm and the windows before it, the configuration and the reference's range."""
        alarm = self.alarm
        parameter = alarm.alarm if alarm else None  # an alarm verdict names its parameter
        return {"parameter": parameter,
                "change_pct": 100.0 * (alarm.ratio[parameter] - 1.0) if alarm and parameter is not None else math.nan,
                "time_s": alarm.window.t_end if alarm else math.nan,
                "speed": alarm.window.speed if alarm else math.nan,
                "windows": [verdict_row(v) for v in self.verdicts[-EVIDENCE_WINDOWS:]],
                "speed_range": list(self.detector.speed_range), "config": asdict(self.config), "label": self.label}

    def result(self) -> HealthResult:
        """Every window (the drift plot's data), the alarm if any, the configuration."""
        alarm = self.alarm
        parameter = alarm.alarm if alarm is not None else None  # an alarm verdict names its parameter
        low, high = self.detector.speed_range
        return HealthResult(self.label, self.config, (low, high), tuple(self.verdicts),
                            None if alarm is None or parameter is None else HealthAlarm(
                                parameter, alarm.window.t_end, 100.0 * (alarm.ratio[parameter] - 1.0),
                                alarm.cusum[parameter]),
                            self.estimator.restarts)
