"""The simulated autopilot's control laws (SPEC C2; thesis Table 5.1 and Fig. 5.4).

Errors are set-point minus measurement. With the thesis's negative depth/pitch gains and depth
positive down this is consistent: too shallow (z_d > z) → θ_d < 0 (nose down, which increases
depth, eq. 5.1); nose too high (θ_d < θ) → δs > 0, which pitches the nose down (C_Lδ < 0, eq. 5.13).
Anti-windup is conditional integration: the integrator stops while the output is saturated and the
error would push it further into the limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from sim.vehicle import wrap_angle


def _clamp(value: float, limit: float) -> float:
    return limit if value > limit else (-limit if value < -limit else value)


@dataclass
class HeadingPI:
    """Heading PI with trim feed-forward: δr = trim + kp·e + I, İ = ki·e, |I| ≤ imax, e wrapped."""

    kp: float
    ki: float
    imax: float
    trim: float = 0.0
    output_max: float = math.inf
    integral: float = field(default=0.0, init=False)

    def update(self, dt: float, heading_setpoint: float, heading: float) -> float:
        """Rudder demand (rad) for a heading set-point and measured heading (rad)."""
        error = wrap_angle(heading_setpoint - heading)
        unsaturated = self.trim + self.kp * error + self.integral
        saturated = _clamp(unsaturated, self.output_max)
        pushing_further = saturated != unsaturated and (self.ki * error) * unsaturated > 0.0
        if not pushing_further:
            self.integral = _clamp(self.integral + self.ki * error * dt, self.imax)
        return _clamp(self.trim + self.kp * error + self.integral, self.output_max)

    def reset(self) -> None:
        self.integral = 0.0

    def initialize(self, rudder: float) -> None:
        """Bumpless transfer: preload the integrator so that zero error gives the current rudder."""
        self.integral = _clamp(rudder - self.trim, self.imax)


@dataclass
class DepthPitchCascade:
    """Depth PI → desired pitch (±pitch_max) → pitch PI → elevator (±elevator_max), Table 5.1."""

    depth_kp: float = -0.15
    depth_ki: float = -0.01
    pitch_kp: float = -20.0
    pitch_ki: float = -0.1
    pitch_max: float = 0.35
    elevator_max: float = 0.26
    depth_integral: float = field(default=0.0, init=False)  # rad of pitch
    pitch_integral: float = field(default=0.0, init=False)  # rad of elevator
    pitch_setpoint: float = field(default=0.0, init=False)  # last desired pitch (for θe = θ − θd)

    def update(self, dt: float, depth_setpoint: float, depth: float, pitch: float) -> float:
        """Elevator demand (rad) from the depth set-point, measured depth (m, down) and pitch (rad)."""
        depth_error = depth_setpoint - depth
        raw_pitch = self.depth_kp * depth_error + self.depth_integral
        if abs(raw_pitch) < self.pitch_max or (self.depth_ki * depth_error) * raw_pitch <= 0.0:
            self.depth_integral += self.depth_ki * depth_error * dt
        self.pitch_setpoint = _clamp(self.depth_kp * depth_error + self.depth_integral, self.pitch_max)

        pitch_error = self.pitch_setpoint - pitch
        raw_elevator = self.pitch_kp * pitch_error + self.pitch_integral
        if abs(raw_elevator) < self.elevator_max or (self.pitch_ki * pitch_error) * raw_elevator <= 0.0:
            self.pitch_integral += self.pitch_ki * pitch_error * dt
        return _clamp(self.pitch_kp * pitch_error + self.pitch_integral, self.elevator_max)

    def reset(self) -> None:
        self.depth_integral = 0.0
        self.pitch_integral = 0.0
        self.pitch_setpoint = 0.0

    def initialize(self, pitch: float, elevator: float) -> None:
        """Bumpless transfer: preload both integrators so that, at zero depth error, the desired
        pitch is the current pitch and the elevator stays where it is (no start-up transient)."""
        self.depth_integral = _clamp(pitch, self.pitch_max)
        self.pitch_integral = _clamp(elevator, self.elevator_max)
        self.pitch_setpoint = self.depth_integral
