"""In-process closed loop for behaviours: simulator physics + simulated autopilot, no MAVLink.

Tests and bench scripts may import both sides; the companion and the behaviours never import sim.
The harness builds :class:`sim.vehicle.Vehicle` and :class:`sim.autopilot.Autopilot` (the same
control laws and parameter table the MAVLink simulator uses), steps the physics at ``physics_hz``
(100 Hz), and every ``1/telemetry_hz`` (20 Hz) turns the vehicle's noisy measurements into a
:class:`companion.interface.Telemetry`, steps the behaviour and applies its commands the way the
MAVLink link would (thrust set-point; rolling mass through DO_SET_SERVO with its PWM rounding).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from companion.numerics.roll import settle_time  # noqa: F401 - re-exported for the tests
from companion.interface import (
    Behavior,
    Command,
    NamedValue,
    SetDepth,
    SetHeading,
    SetRollingMass,
    SetThrust,
    StatusText,
    Telemetry,
)
from sim.autopilot import MODE_ALT_HOLD, Autopilot, pwm_from_fin
from sim.params import ParamTable
from sim.preset import load_preset
from sim.vehicle import Vehicle


def telemetry_from(measurements, mode: str = "hold", armed: bool = True) -> Telemetry:
    """A Telemetry snapshot from :meth:`sim.vehicle.Vehicle.measure` output."""
    m = measurements
    return Telemetry(
        time_s=round(m.time_s * 1000.0) / 1000.0,  # time_boot_ms resolution
        roll=m.roll, pitch=m.pitch, yaw=m.yaw,
        roll_rate=m.roll_rate, pitch_rate=m.pitch_rate, yaw_rate=m.yaw_rate,
        depth=m.depth, north=m.north, east=m.east, down=m.depth,
        vel_north=m.vel_north, vel_east=m.vel_east, vel_down=m.vel_down,
        speed_water=m.speed_water, speed_ground=m.speed_ground,
        rudder=m.rudder, elevator=m.elevator, thrust_ratio=m.thrust_ratio, mass_angle=m.mass_angle,
        mode=mode, armed=armed,
    )


@dataclass
class ClosedLoop:
    """A vehicle in the heading-and-depth holding mode, ready to run behaviours."""

    preset_name: str = "starfish"
    seed: int = 0
    depth: float = 2.0
    speed: float | None = None  # None: the cruise-thrust trim speed; 0: at rest
    thrust: float | None = None  # initial thrust set-point (default CRUISE_THR)
    physics_hz: float = 100.0
    telemetry_hz: float = 20.0
    params: dict[str, float] = field(default_factory=dict)
    log: list[Command] = field(default_factory=list)

    def __post_init__(self) -> None:
        preset = load_preset(self.preset_name)
        self.vehicle = Vehicle(preset, seed=self.seed, depth=self.depth, speed=self.speed)
        self.autopilot = Autopilot(self.vehicle, ParamTable.for_preset(preset))
        for name, value in self.params.items():
            self.set_param(name, value)
        self.autopilot.arm(True)
        self.autopilot.set_mode(MODE_ALT_HOLD)
        if self.thrust is not None:
            self.autopilot.set_thrust(self.thrust)
        self._substeps = max(1, round(self.physics_hz / self.telemetry_hz))
        self._dt = 1.0 / self.physics_hz

    # ------------------------------------------------------------------ plumbing
    def param(self, name: str) -> float:
        return self.autopilot.params[name]

    def set_param(self, name: str, value: float) -> None:
        result = self.autopilot.set_param(name, value)
        assert result.accepted, (name, value)

    def apply(self, commands) -> None:
        ap = self.autopilot
        for command in commands:
            self.log.append(command)
            if isinstance(command, SetThrust):
                ap.set_thrust(command.thrust_ratio)
            elif isinstance(command, SetRollingMass):
                ap.set_servo(int(ap.params["MASS_SERVO"]), pwm_from_fin(command.angle))
            elif isinstance(command, SetDepth):
                ap.set_depth(command.depth)
            elif isinstance(command, SetHeading):
                ap.set_heading(command.heading)
            elif isinstance(command, (StatusText, NamedValue)):
                pass
            else:
                raise NotImplementedError(f"harness cannot apply {command!r}")

    def telemetry(self) -> Telemetry:
        return telemetry_from(self.vehicle.measure())

    def advance(self, seconds: float) -> None:
        """Physics and autopilot only (no behaviour)."""
        for _ in range(max(0, round(seconds * self.physics_hz))):
            self.autopilot.step(self._dt)

    def run(self, behavior: Behavior | None, seconds: float,
            on_sample: Callable[[Telemetry], None] | None = None) -> None:
        """Run ``seconds`` of vehicle time, stepping ``behavior`` at the telemetry rate."""
        ticks = max(0, round(seconds * self.telemetry_hz))
        for _ in range(ticks):
            sample = self.telemetry()
            if on_sample is not None:
                on_sample(sample)
            if behavior is not None and not behavior.done:
                self.apply(behavior.step(sample))
            for _ in range(self._substeps):
                self.autopilot.step(self._dt)

    @property
    def time_s(self) -> float:
        return self.vehicle.time_s
