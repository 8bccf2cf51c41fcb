"""What a fault tool actually delivered, frame by frame: what the vehicle was last told and in
which order the vehicle's samples reached the companion.

Kept by the TCP fault proxy and the UDP relay at the moment a frame leaves them (after every fault,
delay and rate cap), so a case can check the vehicle's commands by what it *received* rather than by
what the companion sent: the last RC override value per channel (:meth:`DeliveryLog.held_overrides`),
the last parameters of every COMMAND_LONG (:attr:`DeliveryLog.commands`) and the order they came in
(:attr:`DeliveryLog.command_history`), the COMMAND_ACKs that reached the companion
(:attr:`DeliveryLog.acks`), and for the vehicle's ATTITUDE samples how many reached the
companion out of vehicle-time order (a companion that drops an older sample loses it).
"""
from __future__ import annotations

import collections
import time
from dataclasses import dataclass

from harness.fault_schedule import TO_COMPANION, TO_VEHICLE
from harness.mavlink_frames import RC_IGNORE_LOW, RC_RELEASE_HIGH, RC_RELEASE_LOW, Frame

__all__ = ["CommandDelivery", "DeliveryLog"]

HISTORY_MAX = 2000  # COMMAND_LONG deliveries kept (bounded)


@dataclass(frozen=True)
class CommandDelivery:
    """One COMMAND_LONG as the vehicle received it."""

    wall_s: float  # time.monotonic() at delivery
    command: int
    params: tuple[float, ...]
    confirmation: int


#: the messages a delivery record reads
_READ = frozenset({"RC_CHANNELS_OVERRIDE", "COMMAND_LONG", "COMMAND_ACK", "ATTITUDE"})


class DeliveryLog:
    """Frames delivered, per direction (module docstring). Not thread-safe: the owner's lock."""

    def __init__(self) -> None:
        self.commands: dict[int, tuple[float, ...]] = {}  # COMMAND_LONG id -> params last delivered
        self.command_history: collections.deque[CommandDelivery] = collections.deque(maxlen=HISTORY_MAX)
        self.frames = {TO_VEHICLE: 0, TO_COMPANION: 0}
        self.acks: collections.deque[tuple[float, int, int]] = collections.deque(maxlen=HISTORY_MAX)  # (wall, command, result)
        self.attitude_delivered = 0
        self.attitude_out_of_order = 0  # ATTITUDE delivered with a time_boot_ms not after the latest one
        self.latest_attitude_ms: int | None = None
        self._overrides: dict[int, int] = {}  # channel -> last delivered value (a release removes it)

    def note(self, frame: Frame, direction: str, wall_s: float | None = None) -> None:
        """``frame`` was delivered travelling ``direction`` (one whose checksum fails is discarded by
        its receiver: counted, not read)."""
        self.frames[direction] += 1
        name = frame.name
        if name in _READ and not frame.crc_ok():  # checked only where a frame is read (the hot path)
            return
        if direction == TO_VEHICLE:
            if name == "RC_CHANNELS_OVERRIDE":
                self._note_override(frame)
            elif name == "COMMAND_LONG":
                command, params = frame.command(), frame.command_params()
                self.commands[command] = params
                self.command_history.append(CommandDelivery(time.monotonic() if wall_s is None else wall_s, command,
                                                            params, frame.payload()[32]))
        elif name == "COMMAND_ACK":
            payload = frame.payload() + bytes(3)
            self.acks.append((time.monotonic() if wall_s is None else wall_s, int.from_bytes(payload[:2], "little"),
                              payload[2]))
        elif name == "ATTITUDE":
            self.attitude_delivered += 1
            stamp = frame.time_boot_ms()
            if self.latest_attitude_ms is not None and stamp <= self.latest_attitude_ms:
                self.attitude_out_of_order += 1
            else:
                self.latest_attitude_ms = stamp

    def held_overrides(self) -> dict[int, int]:
        """Channels whose last RC override delivered to the vehicle holds a value (not a release)."""
        return dict(self._overrides)

    def history(self, command: int) -> list[CommandDelivery]:
        """The deliveries of one COMMAND_LONG ``command``, in the order the vehicle received them."""
        return [d for d in self.command_history if d.command == command]

    def _note_override(self, frame: Frame) -> None:
        for channel, value in enumerate(frame.rc_channels() or [], start=1):
            ignore = value == RC_IGNORE_LOW if channel <= 8 else value in (0, RC_IGNORE_LOW)
            release = value == RC_RELEASE_LOW if channel <= 8 else value == RC_RELEASE_HIGH
            if release:
                self._overrides.pop(channel, None)
            elif not ignore:
                self._overrides[channel] = value
