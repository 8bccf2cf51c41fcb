"""A vehicle port with nothing behind it, for unit tests that fake one corner of a link.

:class:`PortStub` implements every member of :class:`companion.link.port.VehiclePort` the way a link
that applies commands at once and has nothing to say would (the in-process link's parts:
``harness.inprocess``); a test subclasses it and overrides what it looks at. It is checked against
the port by the type checker (``tests/test_type_check.py``), so a fake never silently lacks a member
a procedure reads.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable, Iterable, Sequence

from companion.interface import Command, Telemetry
from companion.link.port import VehiclePort
from companion.link.profile import AutopilotProfile
from companion.link.profiles import SIM
from harness.inprocess import (InProcessAnnouncements, InProcessCommands, InProcessModes, InProcessOverrides,
                               InProcessStrategy, InProcessTelemetry, InProcessTransport, NothingInFlight)

if TYPE_CHECKING:
    from companion.link.vehicle import VehicleLink
    from harness.inprocess import InProcessLink

__all__ = ["PortStub", "StrategyStub", "StubClock", "StubParameters"]


class StubClock:
    """A clock in lockstep that never reboots; its time is whatever the test sets."""

    def __init__(self, vehicle_time_s: float = math.nan, lockstep: bool = True, reboots: int = 0) -> None:
        self.vehicle_time_s = vehicle_time_s
        self.lockstep = lockstep
        self.reboots = reboots


class StubParameters:
    """A parameter channel that watches nothing and remembers no write."""

    def __init__(self) -> None:
        self.foreign: dict = {}
        self.cache: dict[str, float] = {}
        self.watched: set[str] = set()

    def watch(self, names: Iterable[str]) -> None:
        self.watched, self.foreign = set(names), {}

    def ours(self, name: str, value: float) -> bool:
        return False

    def on_write(self, listener: Callable[[str, float], None]) -> Callable[[], None]:
        return lambda: None


class _Releases:
    """What a stub strategy's releases reach: a list of them."""

    def __init__(self) -> None:
        self.released: list[str | None] = []

    def release(self, actuator: str | None = None) -> None:
        self.released.append(actuator)


class StrategyStub(InProcessStrategy):
    """An autopilot strategy that keeps the given set-points and records what it releases
    (``released``), the in-process link's otherwise."""

    def __init__(self, persistent_setpoints: tuple[str, ...] = ()) -> None:
        self._releases = _Releases()
        super().__init__(self._releases, persistent_setpoints)

    @property
    def released(self) -> list[str | None]:
        return self._releases.released


class PortStub(NothingInFlight):
    """Every member of ``VehiclePort``, doing nothing (module docstring)."""

    waits_for_companion = True

    def __init__(self, profile: AutopilotProfile = SIM) -> None:
        self.profile = profile
        self.clock = StubClock()
        self.parameters = StubParameters()
        self.commands = InProcessCommands()
        self.autopilot = StrategyStub()
        self.transport = InProcessTransport()
        self.announcements = InProcessAnnouncements()
        self.telemetry = InProcessTelemetry()
        self.modes = InProcessModes()
        self.overrides = InProcessOverrides()
        self.mode = "hold"
        self.armed = True
        self.commanded_mode: str | None = None
        self.statustexts: list[tuple[float, int, str]] = []
        self.latest_telemetry: Telemetry | None = None
        self.acks: list[tuple[int, int, int]] = []

    @property
    def vehicle_time_s(self) -> float:
        return self.clock.vehicle_time_s

    @property
    def ground(self) -> "PortStub":
        return self

    def next_telemetry(self, timeout_s: float = 5.0) -> Telemetry:
        raise NotImplementedError("this stub has no telemetry: a test that reads it overrides next_telemetry")

    def execute(self, commands: Sequence[Command]) -> None:
        return None

    def get_params(self, neutral_names: Iterable[str]) -> dict[str, float]:
        return {name: self.get_param(self.profile.native_param(name)) for name in neutral_names}

    def set_params(self, neutral_values: dict[str, float]) -> dict[str, float]:
        return {name: self.set_param(self.profile.native_param(name), value) for name, value in neutral_values.items()}

    def get_param(self, name: str) -> float:
        raise KeyError(name)

    def set_param(self, name: str, value: float) -> float:
        return value

    def set_mode(self, neutral: str) -> None:
        self.mode = neutral

    def release(self, actuator: str | None = None) -> None:
        return None

    def status_text(self, text: str, severity: int = 6) -> None:
        return None

    # the ground station's side (``GroundPort``)
    def send_command_ack(self, command: int, result: int, progress: int = 0, target_system: int = 0,
                         target_component: int = 0) -> None:
        self.acks.append((command, result, progress))

    def on_user_command(self, callback: Callable[[int, tuple[float, ...]], None] | None) -> None:
        return None

    def on_report(self, listener: Callable) -> None:
        return None


def _conforms(vehicle: "VehicleLink", in_process: "InProcessLink", stub: PortStub) -> list[VehiclePort]:
    """Never called: the type checker proves here that both links and the stub implement the port."""
    return [vehicle, in_process, stub]
