"""Settle only as long as needed (the quick procedure): is the vehicle steady enough to start a record?

The thesis settles a fixed 40 s before each manoeuvre (and 15 s between records). Most of that time
the vehicle is already steady — always so for the second axis at the same thrust. This detector
ends a settle once, over the last ``window_s`` of vehicle time:

* the speed no longer drifts: the least-squares slope of the water speed is below
  ``speed_slope`` (m/s²) — a drift that would change b2 ∝ u² by well under 1 % over a record;
* the axis is at rest: the mean rate (yaw rate, or pitch rate) is below ``rate`` and, for yaw,
  the heading is within ``heading`` of the course the autopilot holds;
* the throttle the autopilot outputs no longer drifts (slope below ``throttle_slope`` per second):
  an autopilot that holds the speed with its own loop (ArduRover) may pass an overshoot's peak with
  a flat speed while its throttle is still far from the steady one, and an open-loop record that
  holds that throttle then drifts in speed (measured on the skid boat's first level, reached from
  rest: a22 −0.80 and b2 −34 % against −1.02/1.12; our simulator's thrust is a set-point, constant).

* the vehicle moves: its mean water speed is at least ``min_speed`` — a vehicle at rest is perfectly
  "steady", and measured on ArduRover SITL's skid boat six seconds at rest, unarmed, counted as a
  settle and the campaign went on to refuse the doublet as "fly faster".

It never ends a settle before ``min_s`` nor lets it run past the configured maximum (the caller's
fixed settle). Pure: fed telemetry, no clock of its own.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from companion.checks import require_positive
from companion.numerics.angles import wrap_pi


@dataclass(frozen=True)
class SteadinessRule:
    window_s: float = 6.0
    min_s: float = 4.0
    speed_slope: float = 0.0015  # m/s² (noise of the slope over 6 s at 20 Hz and 0.01 m/s: ~0.0005)
    rate: float = math.radians(0.3)  # rad/s, mean over the last 2 s
    heading: float = math.radians(1.0)  # rad from the held course (yaw)
    rate_window_s: float = 2.0
    throttle_slope: float = 0.001  # 1/s: 1.5 % of throttle over a 15 s record
    min_speed: float = 0.1  # m/s: below it the vehicle is not moving, never "steady"

    def __post_init__(self) -> None:
        require_positive(self, "window_s", "min_s", "speed_slope", "rate", "heading", "rate_window_s",
                         "throttle_slope", "min_speed")


class SteadinessDetector:
    """Feed every snapshot of a settle (``add``); ``steady(now)`` says whether it may end."""

    def __init__(self, rule: SteadinessRule, axis: str, course: float = math.nan) -> None:
        self.rule = rule
        self.axis = axis
        self.course = course
        self._start: float | None = None
        # (t, speed, rate, heading error, throttle)
        self._samples: deque[tuple[float, float, float, float, float]] = deque()

    def add(self, time_s: float, speed: float, yaw_rate: float, pitch_rate: float, heading: float,
            throttle: float = math.nan) -> None:
        if self._start is None:
            self._start = time_s
        rate = yaw_rate if self.axis == "yaw" else pitch_rate
        error = wrap_pi(heading - self.course) if math.isfinite(self.course) and math.isfinite(heading) else 0.0
        self._samples.append((time_s, speed, rate, error, throttle))
        while self._samples and self._samples[0][0] < time_s - self.rule.window_s:
            self._samples.popleft()

    def steady(self, time_s: float) -> bool:
        rule = self.rule
        if self._start is None or time_s - self._start < max(rule.min_s, rule.window_s):
            return False
        data = np.array(self._samples, dtype=float)
        if data.shape[0] < 10 or not np.all(np.isfinite(data[:, :4])):
            return False
        t = data[:, 0] - data[-1, 0]
        slope = np.polyfit(t, data[:, 1], 1)[0]
        recent = data[t >= -rule.rate_window_s]
        rate = abs(float(np.mean(recent[:, 2])))
        heading = abs(float(recent[-1, 3])) if self.axis == "yaw" else 0.0
        throttle = data[:, 4]
        drift = abs(np.polyfit(t, throttle, 1)[0]) if np.all(np.isfinite(throttle)) else 0.0
        moving = float(np.mean(data[:, 1])) >= rule.min_speed
        return moving and abs(slope) < rule.speed_slope and rate < rule.rate and heading < rule.heading \
            and drift < rule.throttle_slope
