"""RC override bookkeeping: which channels are held, which are being released (SPEC §4).

ArduPilot semantics (docs/PROTOCOL.md "Override values"): on channels 1–8, 0 releases a channel
and 65535 (UINT16_MAX) leaves it alone; on the MAVLink 2 extension channels 9–18, 0 and 65535 are
"ignore" and 65534 releases. An override expires ``RC_OVERRIDE_TIME`` after the last message that
set it, so active overrides are re-sent (refreshed) with every telemetry snapshot until released.
A released channel is sent as "release" in the next ``release_repeats`` messages (UDP may drop one).
The table is pure bookkeeping; :class:`OverrideChannels` sends it through the autopilot's sender.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

from companion.link.errors import ProfileError

if TYPE_CHECKING:
    from companion.link.profile import AutopilotProfile

CHANNEL_COUNT = 18
IGNORE_LOW = 65535  # channels 1..8
RELEASE_LOW = 0
IGNORE_HIGH = 0  # channels 9..18 (65535 also ignores)
RELEASE_HIGH = 65534


@dataclass
class OverrideTable:
    """Active overrides (channel → PWM) and pending releases (channel → repeats left)."""

    release_repeats: int = 3
    active: dict[int, int] = field(default_factory=dict)
    releasing: dict[int, int] = field(default_factory=dict)

    def hold(self, channel: int, pwm: int) -> None:
        _check_channel(channel)
        self.active[channel] = int(pwm)
        self.releasing.pop(channel, None)

    def release(self, channel: int) -> None:
        _check_channel(channel)
        self.active.pop(channel, None)
        self.releasing[channel] = self.release_repeats

    def release_all(self) -> None:
        for channel in list(self.active):
            self.release(channel)

    @property
    def pending(self) -> bool:
        """True when a message must go out (something held or still being released)."""
        return bool(self.active or self.releasing)

    def channel_values(self, consume: bool = True) -> list[int]:
        """The 18 ``chanN_raw`` values of the next RC_CHANNELS_OVERRIDE; ``consume`` counts a
        release repetition down."""
        values = [IGNORE_LOW if ch <= 8 else IGNORE_HIGH for ch in range(1, CHANNEL_COUNT + 1)]
        for channel, repeats in list(self.releasing.items()):
            values[channel - 1] = RELEASE_LOW if channel <= 8 else RELEASE_HIGH
            if consume:
                if repeats <= 1:
                    del self.releasing[channel]
                else:
                    self.releasing[channel] = repeats - 1
        for channel, pwm in self.active.items():
            values[channel - 1] = pwm
        return values


def single_shot(channel: int, pwm: int) -> list[int]:
    """Channel values overriding one channel once (not refreshed: it expires on the vehicle)."""
    _check_channel(channel)
    values = [IGNORE_LOW if ch <= 8 else IGNORE_HIGH for ch in range(1, CHANNEL_COUNT + 1)]
    values[channel - 1] = int(pwm)
    return values


def _check_channel(channel: int) -> None:
    if not 1 <= channel <= CHANNEL_COUNT:
        raise ValueError(f"RC channel {channel} outside 1..{CHANNEL_COUNT}")


class OverrideChannels:
    """The actuators the companion holds through RC overrides, refreshed with every snapshot.

    Actuators are named neutrally ("rudder", "thrust", ...) and converted to channels and PWM by the
    autopilot profile; how the values reach the vehicle is the autopilot's (``send``, given by its
    strategy: ArduPilot takes RC_CHANNELS_OVERRIDE only from the ground station's system id)."""

    def __init__(self, send: Callable[[list[int]], None] | None = None, table: OverrideTable | None = None) -> None:
        self.table = table or OverrideTable()
        self.send = send
        self.profile: AutopilotProfile | None = None  # the autopilot profile, once known
        self._hold_listeners: list[Callable[[int], None]] = []

    def on_hold(self, listener: Callable[[int], None]) -> Callable[[], None]:
        """Call ``listener(channel)`` before a channel not held so far is held (a crash trail records
        it, whoever asked: a behaviour or the autopilot's strategy); returns the unsubscribe call."""
        self._hold_listeners.append(listener)
        return lambda: self._hold_listeners.remove(listener) if listener in self._hold_listeners else None

    @property
    def active(self) -> dict[int, int]:
        """Channel → PWM held now."""
        return self.table.active

    @property
    def pending(self) -> bool:
        return self.table.pending

    def _profile(self) -> AutopilotProfile:
        if self.profile is None:
            raise ProfileError("no profile yet (still connecting)")
        return self.profile

    def _send_values(self, values: list[int]) -> None:
        if self.send is None:
            raise RuntimeError("no override sender yet (still connecting)")
        self.send(values)

    def refresh(self) -> None:
        """Send what is held or still being released (once per snapshot: overrides expire)."""
        if self.table.pending:
            self._send_values(self.table.channel_values())

    def override(self, actuator: str, value: float, *, keep_alive: bool = True) -> None:
        """Drive ``actuator`` (rad for fins, ratio for thrust). With ``keep_alive`` it is refreshed
        at every snapshot until released; without, it is sent once and expires on the vehicle."""
        profile = self._profile()
        channel = profile.channel(actuator)
        pwm = profile.actuator_to_pwm(actuator, value)
        if keep_alive:
            self.hold(channel, pwm)
        else:
            self.table.active.pop(channel, None)
            self._send_values(single_shot(channel, pwm))

    def override_raw(self, channel_name: str, pwm: int) -> None:
        """Hold a raw PWM on the profile's channel ``channel_name`` (kept alive like an override)."""
        self.hold(self._profile().channel(channel_name), int(pwm))

    def hold(self, channel: int, pwm: int) -> None:
        if channel not in self.table.active:
            for listener in list(self._hold_listeners):
                listener(channel)
        changed = self.table.active.get(channel) != pwm
        self.table.hold(channel, pwm)
        if changed:  # unchanged values go out with the per-snapshot refresh only
            self.refresh()

    def release(self, actuator: str | None = None) -> None:
        """Give ``actuator`` (None = every overridden one) back to the autopilot."""
        if actuator is None:
            self.table.release_all()
        else:
            self.table.release(self._profile().channel(actuator))
        self.refresh()

    def holds(self, actuator: str) -> bool:
        """True while ``actuator``'s channel is held."""
        return self._profile().channel(actuator) in self.table.active

    def held_pwm(self, actuator: str) -> int | None:
        return self.table.active.get(self._profile().channel(actuator))

    def no_change(self) -> None:
        """An override that changes no channel (every value "ignore"): pilot presence, nothing moves."""
        self._send_values(OverrideTable().channel_values())
