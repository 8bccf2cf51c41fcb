"""RC override bookkeeping: which channels are held, which are being released (SPEC §4).

ArduPilot semantics (docs/PROTOCOL.md "Override values"): on channels 1–8, 0 releases a channel
and 65535 (UINT16_MAX) leaves it alone; on the MAVLink 2 extension channels 9–18, 0 and 65535 are
"ignore" and 65534 releases. An override expires ``RC_OVERRIDE_TIME`` after the last message that
set it, so active overrides are re-sent (refreshed) with every telemetry snapshot until released.
A released channel is sent as "release" in the next ``release_repeats`` messages (UDP may drop one).
Pure bookkeeping, no I/O.
"""
from __future__ import annotations

from dataclasses import dataclass, field

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
