"""Mode changes and arming, each verified by what the autopilot's HEARTBEAT then shows (SPEC C1).

A mode is named neutrally ("manual", "hold", "guided"; ``custom_<n>`` for one a profile does not
name) and turned into the autopilot's numbers by its profile. A change is trusted only when a
HEARTBEAT *after* the request shows it; a refusal (COMMAND_ACK other than ACCEPTED) ends the tries.
The mode the companion switched to last is remembered (``commanded``), so a procedure can tell its
own mode changes from a pilot's.
"""
from __future__ import annotations

import math
from typing import Callable

from companion.link.clock import VehicleClock
from companion.link.commands import MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS, CommandChannel
from companion.link.errors import CommandFailed, ModeChangeFailed, ProfileError
from companion.link.vehicle_state import VehicleAnnouncements

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400


class ModeControl:
    """Switch mode and arm, verified (module docstring)."""

    def __init__(self, commands: CommandChannel, announcements: VehicleAnnouncements, clock: VehicleClock) -> None:
        self.commands = commands
        self.announcements = announcements
        self.clock = clock
        self.profile = None  # the autopilot profile, once known
        self.commanded: str | None = None  # the last mode the companion itself switched to
        self._listeners: list[Callable[[str], None]] = []
        self._before: list[Callable[[str], None]] = []

    def before_change(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(neutral)`` before every mode change the companion asks for (an autopilot
        that accepts a mode only while set-points already stream, PX4's OFFBOARD, starts them there)."""
        self._before.append(listener)

    def on_change(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(neutral)`` after every verified mode change the companion made."""
        self._listeners.append(listener)

    def _profile(self):
        if self.profile is None:
            raise ProfileError("no profile yet (still connecting)")
        return self.profile

    def set_mode(self, neutral: str) -> None:
        """Switch mode and wait until the HEARTBEAT shows it (vehicle time, resending each try)."""
        profile = self._profile()
        target = profile.mode_number(neutral)
        params = profile.mode_command_params(target)
        for listener in self._before:
            listener(neutral)
        timeouts = self.clock.timeouts
        tries = max(int(math.ceil(timeouts.mode_s / timeouts.command_s)), 1)
        for _attempt in range(tries):
            since_hb = self.announcements.heartbeat_count
            since_ack = self.commands.send(MAV_CMD_DO_SET_MODE, params)

            def refused() -> int | None:
                answer = self.commands.answered_since(MAV_CMD_DO_SET_MODE, since_ack)
                return answer[0] if answer is not None and answer[0] not in (
                    MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS) else None

            def shown() -> bool:
                return self.announcements.heartbeat_count > since_hb and self.announcements.custom_mode == target

            self.clock.wait_until(lambda: refused() is not None or shown(), timeouts.command_s)
            result = refused()
            if result is not None:
                raise ModeChangeFailed(f"vehicle refused mode {neutral!r} ({target}): result {result}")
            if shown():
                self.commanded = neutral
                for listener in self._listeners:
                    listener(neutral)
                return
        raise ModeChangeFailed(f"heartbeat did not show mode {neutral!r} ({target}) within {timeouts.mode_s:g} s")

    def arm(self, armed: bool = True) -> None:
        """Arm or disarm; verified by the ACK and then the HEARTBEAT's armed flag."""
        result = self.commands.command(MAV_CMD_COMPONENT_ARM_DISARM, (1.0 if armed else 0.0,))
        if result != MAV_RESULT_ACCEPTED:
            raise CommandFailed(f"{'arm' if armed else 'disarm'} refused: result {result}",
                                command=MAV_CMD_COMPONENT_ARM_DISARM, result=result)
        since_hb = self.announcements.heartbeat_count
        if not self.clock.wait_until(lambda: self.announcements.heartbeat_count > since_hb
                                     and self.announcements.armed == armed, self.clock.timeouts.mode_s):
            raise ModeChangeFailed(f"heartbeat did not show armed={armed}")
