"""The typed port between the procedures and the vehicle: what a procedure, the restore, the crash
trail and the status page may use of a link, and nothing else.

Two links implement it: :class:`companion.link.vehicle.VehicleLink` (MAVLink) and the test harness's
in-process link (``harness.inprocess.InProcessLink``, the simulator's autopilot without MAVLink).
Both are checked against it by the type checker (``tests/test_type_check.py``); the procedures read
its members directly, never by probing (``getattr(link, "…", None)``), so a member one link lacks is
a type error, not a silent ``None``.

Where the two links differ in what can happen, the port says so by a value, not by a missing member:

* ``clock.lockstep`` — the vehicle's time advances only as the companion reads it, and every
  message sent before is applied before the clock moves: nothing sent earlier can land later (true
  in process, and on a lockstep simulator link);
* ``commands.answers_late`` — a set-point's acknowledgement may arrive after the procedure gave up
  on it (a MAVLink link; never in process, where every command is applied at once);
* ``autopilot`` — the autopilot's *strategy* (release, targets refreshed, set-points it keeps), on
  both links. The in-process link's simulated autopilot itself is ``InProcessLink.simulated``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Iterable, Mapping, Protocol, Sequence

from companion.interface import Command, Telemetry

if TYPE_CHECKING:
    from companion.link.ground_station import Report
    from companion.link.parameters import ForeignChange
    from companion.link.profile import AutopilotProfile

__all__ = ["AnnouncementPort", "ClockPort", "CommandPort", "GroundPort", "ModePort", "OverridePort",
           "ParameterPort", "StrategyPort", "TelemetryPort", "TransportPort", "VehiclePort"]


class ParameterPort(Protocol):
    """The parameter channel: the watched parameters, what someone else changed among them since the
    watch began (``foreign``), which values our own writes asked for, and the values last read."""

    @property
    def foreign(self) -> Mapping[str, ForeignChange]: ...

    @property
    def cache(self) -> Mapping[str, float]: ...

    def watch(self, names: Iterable[str]) -> None: ...

    def ours(self, name: str, value: float) -> bool: ...

    def on_write(self, listener: Callable[[str, float], None]) -> Callable[[], None]: ...


class ClockPort(Protocol):
    """The vehicle's clock as the link keeps it: how often the vehicle rebooted since we connected,
    and whether it runs in lockstep with the companion (module docstring)."""

    @property
    def reboots(self) -> int: ...

    @property
    def lockstep(self) -> bool: ...

    @property
    def vehicle_time_s(self) -> float: ...


class CommandPort(Protocol):
    """The command channel: how many of each MAVLink command were sent and answered, the set-points
    abandoned by a restore and their late answers, and the longest round trip seen (wall clock)."""

    @property
    def answers_late(self) -> bool: ...

    @property
    def sends_of(self) -> Mapping[int, int]: ...

    @property
    def max_round_trip_s(self) -> float: ...

    @property
    def abandon_generation(self) -> int: ...

    @property
    def abandoned(self) -> tuple[int, ...]: ...

    @property
    def period_s(self) -> float: ...

    def abandon(self) -> list[int]: ...

    def forget_abandoned(self) -> None: ...

    def late_answers(self, command: int) -> int: ...

    def last_setpoint(self, command: int) -> tuple[float, ...] | None: ...

    def send(self, command: int, params: Sequence[float], *, confirmation: int = 0) -> int: ...


class StrategyPort(Protocol):
    """The autopilot's strategy as the restore and the trail use it
    (``companion.link.autopilots.base.AutopilotStrategy``)."""

    @property
    def persistent_setpoints(self) -> tuple[str, ...]: ...

    @property
    def streams(self) -> Mapping[int, float]: ...

    def release(self, actuator: str | None) -> None: ...

    def forget_targets(self) -> None: ...

    def forget_excitation(self) -> None: ...

    def release_after_crash(self, actuators: list[str]) -> None: ...

    def not_ready(self, telemetry: Telemetry) -> str | None: ...


class TransportPort(Protocol):
    """Who we talk to and how much was heard."""

    @property
    def system_id(self) -> int: ...

    @property
    def component(self) -> int: ...

    @property
    def autopilot_component(self) -> int: ...

    @property
    def endpoint(self) -> str | None: ...

    @property
    def bytes_received(self) -> int: ...


class AnnouncementPort(Protocol):
    """What the vehicle announced of itself: its board's id (None when it reports none)."""

    @property
    def hardware_uid(self) -> str | None: ...


class TelemetryPort(Protocol):
    """Listeners called after each snapshot the companion reads."""

    def after_snapshot(self, listener: Callable[[], None]) -> None: ...

    def stop_calling(self, listener: Callable[[], None]) -> None: ...


class GroundPort(Protocol):
    """The ground station's side: acknowledgements to its commands, its user commands, reports."""

    def send_command_ack(self, command: int, result: int, progress: int = 0, target_system: int = 0,
                         target_component: int = 0) -> None: ...

    def on_user_command(self, callback: Callable[[int, tuple[float, ...]], None] | None) -> None: ...

    def on_report(self, listener: Callable[[Report], None]) -> None: ...


class ModePort(Protocol):
    """When the vehicle confirmed the mode the companion last switched to (vehicle time; NaN: not
    yet), and listeners told of each mode the companion asks for before it is sent (a crash trail)."""

    @property
    def commanded_at_s(self) -> float: ...

    def on_request(self, listener: Callable[[str], None]) -> Callable[[], None]: ...


class OverridePort(Protocol):
    """The RC channels the companion holds: listeners told before a channel not held so far is held."""

    def on_hold(self, listener: Callable[[int], None]) -> Callable[[], None]: ...


class VehiclePort(Protocol):
    """Everything a procedure uses of the vehicle (module docstring)."""

    @property
    def profile(self) -> AutopilotProfile: ...

    @property
    def clock(self) -> ClockPort: ...

    @property
    def parameters(self) -> ParameterPort: ...

    @property
    def commands(self) -> CommandPort: ...

    @property
    def autopilot(self) -> StrategyPort: ...

    @property
    def transport(self) -> TransportPort: ...

    @property
    def announcements(self) -> AnnouncementPort: ...

    @property
    def telemetry(self) -> TelemetryPort: ...

    @property
    def ground(self) -> GroundPort: ...

    @property
    def modes(self) -> ModePort: ...

    @property
    def overrides(self) -> OverridePort: ...

    @property
    def vehicle_time_s(self) -> float: ...

    @property
    def latest_telemetry(self) -> Telemetry | None: ...

    @property
    def mode(self) -> str: ...

    @property
    def armed(self) -> bool: ...

    #: the mode the companion itself last switched to (the runner clears it when a procedure starts)
    commanded_mode: str | None

    @property
    def statustexts(self) -> Sequence[tuple[float, int, str]]: ...

    @property
    def waits_for_companion(self) -> bool: ...

    def next_telemetry(self, timeout_s: float = ...) -> Telemetry: ...

    def execute(self, commands: Sequence[Command]) -> None: ...

    def get_params(self, neutral_names: Iterable[str]) -> dict[str, float]: ...

    def set_params(self, neutral_values: dict[str, float]) -> dict[str, float]: ...

    def get_param(self, name: str) -> float: ...

    def set_param(self, name: str, value: float) -> float: ...

    def set_mode(self, neutral: str) -> None: ...

    def release(self, actuator: str | None = None) -> None: ...

    def status_text(self, text: str, severity: int = 6) -> None: ...

    def await_setpoints(self) -> None: ...

    def skip_to_now(self) -> int: ...

    def other_companion(self) -> str | None: ...

    def reconnect(self, timeout_s: float | None = None) -> bool: ...
