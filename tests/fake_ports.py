"""The link's parts as an autopilot strategy sees them (``LinkPorts``), faked for strategy unit tests.

Overrides go through the real ``OverrideChannels`` (what is held, refreshed and released is the
product's own bookkeeping); everything else records what the strategy asked for. ``snapshot`` does
what the telemetry feed does per snapshot: advance vehicle time, let the strategy complete the
snapshot, then refresh the held overrides.
"""
from __future__ import annotations

from collections import defaultdict
from types import SimpleNamespace

from companion.interface import Telemetry
from companion.link.autopilots.base import LinkPorts
from companion.link.overrides import OverrideChannels


class RecordingMav:
    """pymavlink's encoder, recording ``<message>_send`` calls as (name, args)."""

    def __init__(self) -> None:
        self.sent: list[tuple] = []

    def __getattr__(self, name):
        return lambda *args: self.sent.append((name, *args))


class FakeTransport:
    system_id, autopilot_component, component = 1, 1, 191

    def __init__(self) -> None:
        from companion.link.frame_loss import FrameLoss

        self.mav = RecordingMav()
        self.frame_loss = FrameLoss()
        self.heard_time_ms = None
        self.handlers = defaultdict(list)
        self.sent_as: list[tuple[int, int]] = []

    def on(self, message_type, handler) -> None:
        self.handlers[message_type].append(handler)

    def emit(self, message_type: str, **fields) -> None:
        """A message of the vehicle's, dispatched to the registered handlers."""
        msg = SimpleNamespace(**fields)
        for handler in self.handlers[message_type]:
            handler(msg)

    def from_vehicle(self, msg) -> bool:
        return True

    def from_autopilot(self, msg) -> bool:
        return True

    def send_as(self, system_id, component, send) -> None:
        self.sent_as.append((system_id, component))
        send(self.mav)


class FakeAnnouncements:
    def __init__(self, profile) -> None:
        self.profile = profile
        self.custom_mode = None
        self.armed = True

    @property
    def mode(self) -> str:
        return self.profile.mode_name(self.custom_mode) if self.custom_mode is not None else ""


class FakeModes:
    def __init__(self, announcements) -> None:
        self.announcements = announcements
        self.changes: list[str] = []
        self.strategy = None
        self.commanded: str | None = None

    def set_mode(self, neutral: str) -> None:
        before = getattr(self.strategy, "before_mode_change", None)
        if before is not None:
            before(neutral)
        self.changes.append(neutral)
        self.commanded = neutral
        self.announcements.custom_mode = self.announcements.profile.mode_number(neutral)
        self.strategy.mode_changed(neutral)


class FakeParameters:
    def __init__(self, params: dict) -> None:
        self.params = dict(params)

    def get_param(self, name: str, retries: int = 3) -> float:
        return self.params[name]


class FakeTelemetry:
    def __init__(self) -> None:
        self.latest: Telemetry | None = None
        self.pwm: list[float] = []

    def servo_pwm(self) -> list[float]:
        return list(self.pwm)


class FakeCommands:
    def __init__(self) -> None:
        self.setpoints: list[tuple] = []
        self.servos: list[tuple] = []

    def send_setpoint(self, command, params) -> None:
        self.setpoints.append((command, tuple(params)))

    def set_servo(self, output, pwm, *, wait=False) -> None:
        self.servos.append((output, pwm))


class FakePorts(LinkPorts):
    """``LinkPorts`` over fakes, with the strategy built on them and a per-snapshot step."""

    def __init__(self, profile, strategy_class, *, mode: str = "hold", params: dict | None = None,
                 time_s: float = 100.0) -> None:
        announcements = FakeAnnouncements(profile)
        announcements.custom_mode = profile.modes[mode]
        overrides = OverrideChannels()
        overrides.profile = profile
        self.override_values: list[list[int]] = []
        overrides.send = lambda values: self.override_values.append(list(values))
        super().__init__(transport=FakeTransport(), clock=SimpleNamespace(vehicle_time_s=time_s),
                         announcements=announcements, commands=FakeCommands(), modes=FakeModes(announcements),
                         parameters=FakeParameters(params or {}), overrides=overrides, telemetry=FakeTelemetry(),
                         ground=SimpleNamespace(gcs_sysid=255), profile=profile)
        self.strategy = strategy_class(self)
        self.modes.strategy = self.strategy

    @property
    def attitude_targets(self) -> list[tuple]:
        return [entry for entry in self.transport.mav.sent if entry[0] == "set_attitude_target_send"]

    def snapshot(self, dt: float = 0.02, **fields) -> Telemetry:
        """One snapshot ``dt`` later (fields as reported), as the strategy completes it."""
        self.clock.vehicle_time_s += dt
        telemetry = self.strategy.on_snapshot(Telemetry(time_s=self.clock.vehicle_time_s, **fields))
        self.overrides.refresh()
        return telemetry
