"""Mode changes and arming, each verified by what the autopilot's HEARTBEAT then shows (SPEC C1).

A mode is named neutrally ("manual", "hold", "guided"; ``custom_<n>`` for one a profile does not
name) and turned into the autopilot's numbers by its profile. A change is trusted only when a
HEARTBEAT *after* the request shows it; a refusal (COMMAND_ACK other than ACCEPTED) ends the tries.
The mode the companion switched to last is remembered (``commanded``), so a procedure can tell its
own mode changes from a pilot's.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable

from companion.link.clock import VehicleClock
from companion.link.commands import MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS, CommandChannel
from companion.link.errors import CommandFailed, ModeChangeFailed, ProfileError
from companion.link.vehicle_state import VehicleAnnouncements

if TYPE_CHECKING:
    from companion.link.profile import AutopilotProfile

MAV_CMD_DO_SET_MODE = 176

#: neutral modes in which a pilot drives the vehicle by hand: a procedure that starts in one takes the
#: vehicle from the pilot (and says so)
HAND_FLOWN_MODES = frozenset({"manual", "acro", "steering", "stabilize", "poshold"})
MAV_CMD_COMPONENT_ARM_DISARM = 400


class ModeControl:
    """Switch mode and arm, verified (module docstring)."""

    def __init__(self, commands: CommandChannel, announcements: VehicleAnnouncements, clock: VehicleClock) -> None:
        self.commands = commands
        self.announcements = announcements
        self.clock = clock
        self.profile: AutopilotProfile | None = None  # the autopilot profile, once known
        self._commanded: str | None = None  # the last mode the companion itself switched to
        self._confirmed_at_s: float = float("nan")  # vehicle time the heartbeat confirmed it
        self._confirmed_boot = 0  # the boot it was confirmed on (``clock.reboots`` then)
        self._listeners: list[Callable[[str], None]] = []
        self._request_listeners: list[Callable[[str], None]] = []
        self._accepted_listeners: list[Callable[[str], None]] = []
        self._before: list[Callable[[str], None]] = []

    def before_change(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(neutral)`` before every mode change the companion asks for (an autopilot
        that accepts a mode only while set-points already stream, PX4's OFFBOARD, starts them there)."""
        self._before.append(listener)

    @property
    def commanded(self) -> str | None:
        """The last mode the companion switched to (None after it is forgotten, or after a reboot)."""
        return self._commanded if self._confirmed_boot == self.clock.reboots else None

    @commanded.setter
    def commanded(self, value: str | None) -> None:
        """Forget (None) or set the mode the companion switched to; its confirmation time is forgotten."""
        self._commanded = value
        self._confirmed_at_s = float("nan")
        self._confirmed_boot = self.clock.reboots

    @property
    def commanded_at_s(self) -> float:
        """Vehicle time the heartbeat confirmed the companion's last mode change, on this boot (NaN
        when forgotten, or when the vehicle rebooted since: its clock started again)."""
        return self._confirmed_at_s if self._confirmed_boot == self.clock.reboots else float("nan")

    def on_change(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(neutral)`` after every verified mode change the companion made."""
        self._listeners.append(listener)

    def on_accepted(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(neutral)`` as soon as the autopilot acknowledges a mode change (ACCEPTED),
        before a HEARTBEAT verifies it: for what a new mode needs at once (ArduRover's GUIDED loiters
        until it gets a target)."""
        self._accepted_listeners.append(listener)

    def on_request(self, listener: Callable[[str], None]) -> Callable[[], None]:
        """Call ``listener(neutral)`` before the companion asks for a mode (a crash trail records
        it, whoever asked); returns the unsubscribe call."""
        self._request_listeners.append(listener)
        return lambda: self._request_listeners.remove(listener) if listener in self._request_listeners else None

    def _profile(self) -> AutopilotProfile:
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
        since_text = self.announcements.statustext_count
        for listener in list(self._request_listeners):
            listener(neutral)
        for _attempt in range(tries):
            since_hb = self.announcements.heartbeat_count
            since_ack = self.commands.send(MAV_CMD_DO_SET_MODE, params)

            def refused() -> int | None:
                answer = self.commands.answered_since(MAV_CMD_DO_SET_MODE, since_ack)
                return answer[0] if answer is not None and answer[0] not in (
                    MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS) else None

            def shown() -> bool:
                return self.announcements.heartbeat_count > since_hb and self.announcements.custom_mode == target

            told = {"accepted": False}

            def settled() -> bool:
                if not told["accepted"] and self._accepted_listeners:
                    answer = self.commands.answered_since(MAV_CMD_DO_SET_MODE, since_ack)
                    if answer is not None and answer[0] == MAV_RESULT_ACCEPTED:
                        told["accepted"] = True
                        for listener in self._accepted_listeners:
                            listener(neutral)
                return refused() is not None or shown()

            self.clock.wait_until(settled, timeouts.command_s)
            result = refused()
            if result is not None:
                said = self.announcements.warnings_since(since_text)
                raise ModeChangeFailed(f"the vehicle refused mode {neutral!r} ({target}, MAV_RESULT {result})"
                                       + (f": it said {said!r}" if said else ""))
            if shown():
                self.commanded = neutral
                self._confirmed_at_s = self.clock.vehicle_time_s
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
