"""The runner's Link protocol over the simulator's autopilot and physics in-process (no MAVLink).

For fast, exactly reproducible tests of behaviours, the campaign state machine and the abort
paths. Tests may import both the simulator and the companion; the product never does. The
end-to-end tests over MAVLink live elsewhere (test_e2e_*.py).

Fault injection: ``refuse`` (native parameter names whose writes are refused), ``lose_link_at_s``
(next_telemetry raises after that vehicle time), ``nan_from_s`` (attitude turns NaN from then on).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

from companion.interface import (
    Command,
    NamedValue,
    OverrideActuator,
    ReleaseActuator,
    SetDepth,
    SetHeading,
    SetMode,
    SetParameters,
    SetRollingMass,
    SetThrust,
    StatusText,
    Telemetry,
)
from companion.link.profiles import SIM as PROFILE
from sim.autopilot import Autopilot, pwm_from_fin
from sim.params import ParamTable
from sim.preset import load_preset
from sim.vehicle import Vehicle


class LinkLost(RuntimeError):
    pass


class ParamRefused(RuntimeError):
    pass


@dataclass
class InProcessLink:
    preset: str = "starfish"
    seed: int = 1
    telemetry_hz: float = 20.0
    physics_dt: float = 0.01
    depth: float = 2.0
    refuse: set[str] = field(default_factory=set)
    lose_link_at_s: float | None = None
    nan_from_s: float | None = None
    gcs_sysid: int = 255

    def __post_init__(self) -> None:
        preset = load_preset(self.preset)
        self.vehicle = Vehicle(preset, seed=self.seed, depth=self.depth)
        self.autopilot = Autopilot(self.vehicle, ParamTable.for_preset(preset))
        self.profile = PROFILE
        self.system_id = 1
        self.overrides: dict[str, float] = {}
        self.status_texts: list[str] = []
        self.named_values: list[tuple[str, float]] = []
        self.param_writes: list[tuple[str, float]] = []
        self.mode_changes: list[str] = []
        self.autopilot.arm(True)
        self.autopilot.set_mode(2)  # ALT_HOLD, as a vehicle waiting for its mission would be
        self._steps_per_sample = max(1, round(1.0 / (self.telemetry_hz * self.physics_dt)))
        self._user_callback = None
        self._user_queue: list[tuple[float, int, tuple]] = []
        self.acks: list[tuple[int, int, int]] = []

    # ------------------------------------------------------------------ state
    @property
    def vehicle_time_s(self) -> float:
        return self.vehicle.time_s

    @property
    def mode(self) -> str:
        return {19: "manual", 2: "hold", 4: "guided"}[self.autopilot.mode]

    def param(self, neutral: str) -> float:
        return self.autopilot.params[self.profile.native_param(neutral)]

    # ------------------------------------------------------------------ Link protocol
    def next_telemetry(self, timeout_s: float = 5.0) -> Telemetry:
        for _ in range(self._steps_per_sample):
            self._refresh_overrides()
            self.autopilot.step(self.physics_dt)
        now = self.vehicle.time_s
        if self.lose_link_at_s is not None and now >= self.lose_link_at_s:
            raise LinkLost(f"no message for {timeout_s} s")
        due = [item for item in self._user_queue if item[0] <= now]
        for item in due:
            self._user_queue.remove(item)
            if self._user_callback is not None:
                self._user_callback(item[1], item[2])
        m = self.vehicle.measure()
        attitude_nan = self.nan_from_s is not None and now >= self.nan_from_s
        nan = math.nan
        return Telemetry(
            time_s=round(now * 1000) / 1000.0,
            roll=nan if attitude_nan else m.roll, pitch=nan if attitude_nan else m.pitch,
            yaw=nan if attitude_nan else math.atan2(math.sin(m.yaw), math.cos(m.yaw)),
            roll_rate=m.roll_rate, pitch_rate=m.pitch_rate, yaw_rate=m.yaw_rate,
            depth=m.depth, north=m.north, east=m.east, down=m.depth,
            vel_north=m.vel_north, vel_east=m.vel_east, vel_down=m.vel_down,
            speed_water=m.speed_water, speed_ground=m.speed_ground,
            rudder=m.rudder, elevator=m.elevator, thrust_ratio=m.thrust_ratio, mass_angle=m.mass_angle,
            mode=self.mode, armed=self.autopilot.armed,
        )

    def _refresh_overrides(self) -> None:
        if not self.overrides:
            return
        channels = [65535] * 8
        for actuator, value in self.overrides.items():
            channels[self.profile.channel(actuator) - 1] = self.profile.actuator_to_pwm(actuator, value)
        self.autopilot.rc_override(self.gcs_sysid, channels)

    def execute(self, commands: Sequence[Command]) -> None:
        for command in commands:
            if isinstance(command, OverrideActuator):
                self.overrides[command.actuator] = command.value
            elif isinstance(command, ReleaseActuator):
                self.release(command.actuator)
            elif isinstance(command, SetHeading):
                self.autopilot.set_heading(command.heading)
            elif isinstance(command, SetDepth):
                self.autopilot.set_depth(command.depth)
            elif isinstance(command, SetThrust):
                self.autopilot.set_thrust(command.thrust_ratio)
            elif isinstance(command, SetRollingMass):
                self.autopilot.set_servo(int(self.autopilot.params["MASS_SERVO"]), pwm_from_fin(command.angle))
            elif isinstance(command, SetMode):
                self.set_mode(command.mode)
            elif isinstance(command, SetParameters):
                self.set_params(command.values)
            elif isinstance(command, StatusText):
                self.status_texts.append(command.text)
            elif isinstance(command, NamedValue):
                self.named_values.append((command.name, command.value))
            else:
                raise TypeError(f"unknown command {command!r}")

    def get_params(self, neutral_names) -> dict:
        return {name: self.param(name) for name in neutral_names}

    def set_params(self, neutral_values: dict) -> dict:
        echoed = {}
        for name, value in neutral_values.items():
            native = self.profile.native_param(name)
            if native in self.refuse:
                raise ParamRefused(f"{native} refused")
            result = self.autopilot.set_param(native, float(value))
            if not result.accepted:
                raise ParamRefused(f"{native} = {value} refused")
            self.param_writes.append((name, float(value)))
            echoed[name] = self.autopilot.params[native]
        return echoed

    def get_param(self, native: str) -> float:
        if native not in self.autopilot.params:
            raise ParamRefused(f"no parameter {native}")
        return self.autopilot.params[native]

    def set_param(self, native: str, value: float) -> float:
        if native in self.refuse:
            raise ParamRefused(f"{native} refused")
        result = self.autopilot.set_param(native, float(value))
        if not result.accepted:
            raise ParamRefused(f"{native} = {value} refused")
        return self.autopilot.params[native]

    def set_mode(self, neutral: str) -> None:
        self.mode_changes.append(neutral)
        self.autopilot.set_mode(self.profile.mode_number(neutral))

    def release(self, actuator: str | None = None) -> None:
        names = list(self.overrides) if actuator is None else [actuator]
        channels = [65535] * 8
        for name in names:
            self.overrides.pop(name, None)
            channels[self.profile.channel(name) - 1] = 0
        self.autopilot.rc_override(self.gcs_sysid, channels)

    def status_text(self, text: str, severity: int = 6) -> None:
        self.status_texts.append(text)

    # ------------------------------------------------------------------ ground station
    def on_user_command(self, callback) -> None:
        self._user_callback = callback

    def inject_user_command(self, command: int, at_s: float, params: tuple = (0.0,) * 7) -> None:
        """A COMMAND_LONG from a ground station, delivered at vehicle time ``at_s``."""
        self._user_queue.append((at_s, command, params))

    def send_command_ack(self, command: int, result: int, progress: int = 0, *_targets) -> None:
        self.acks.append((command, result, progress))
