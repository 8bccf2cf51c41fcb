"""Errors raised by the vehicle interface (SPEC C1).

Every failure of the link is a :class:`LinkError`, so a caller can catch the family; the
subclasses say what went wrong precisely enough to act on it (retry, abort, reconnect).
"""
from __future__ import annotations

from typing import TypeVar

T = TypeVar("T")


class LinkError(RuntimeError):
    """Base class of every vehicle-interface failure."""


class HeartbeatTimeout(LinkError):
    """No autopilot HEARTBEAT arrived within the wall-clock limit while connecting."""


class LinkLost(LinkError):
    """The link was silent (no telemetry) for longer than the wall-clock watchdog allows."""


class VehicleRebooted(LinkError):
    """The autopilot's time_boot_ms jumped backwards: it rebooted, all vehicle state is stale."""


class ProfileError(LinkError):
    """The autopilot profile is unknown, or a neutral name has no mapping in it."""


class ParamError(LinkError):
    """A parameter read or write failed."""

    def __init__(self, message: str, *, name: str = "", value: float | None = None) -> None:
        super().__init__(message)
        self.name = name
        self.value = value


class ParamTimeout(ParamError):
    """No PARAM_VALUE echo for the parameter after all retries."""


class ParamRefused(ParamError):
    """The autopilot answered but did not take the value (other value echoed, or a STATUSTEXT
    refusal), or the value was refused locally before sending (non-finite)."""

    def __init__(self, message: str, *, name: str = "", value: float | None = None,
                 echoed: float | None = None) -> None:
        super().__init__(message, name=name, value=value)
        self.echoed = echoed


class CommandFailed(LinkError):
    """A COMMAND_LONG was answered with a result other than ACCEPTED, or never answered."""

    def __init__(self, message: str, *, command: int = 0, result: int | None = None) -> None:
        super().__init__(message)
        self.command = command
        self.result = result


class ModeChangeFailed(LinkError):
    """The HEARTBEAT did not show the requested mode (or armed state) in time."""


class EndpointError(LinkError):
    """The connection string could not be opened (refused, no such device, bad address)."""


def known_once_set_up(value: T | None, what: str) -> T:
    """``value``, which the link knows once its handshake ran; ProfileError before that."""
    if value is None:
        raise ProfileError(f"the link is not set up yet: its {what} is not known")
    return value
