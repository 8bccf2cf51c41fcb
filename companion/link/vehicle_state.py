"""What the autopilot announces about itself: HEARTBEAT (mode, armed), STATUSTEXT, AUTOPILOT_VERSION.

:class:`VehicleAnnouncements` keeps the latest of each as the vehicle sends them; the mode is
reported by its neutral name through the autopilot profile once one is known.
"""
from __future__ import annotations

import collections
import logging
from typing import Any, Callable

from companion.link.transport import Transport

log = logging.getLogger(__name__)

#: MAV_MODE_FLAG_SAFETY_ARMED
SAFETY_ARMED = 128
MAV_SEVERITY_WARNING = 4


class VehicleAnnouncements:
    """The autopilot's latest HEARTBEAT, its recent STATUSTEXTs, and its capabilities."""

    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        self.custom_mode: int | None = None
        self.base_mode: int = 0
        self.heartbeat_count = 0
        self.last_heartbeat: Any = None
        self.capabilities: int | None = None
        self.hardware_uid: str | None = None  # AUTOPILOT_VERSION's board id (uid2, else uid), hex; None if 0
        self.statustexts: collections.deque[tuple[float, int, str]] = collections.deque(maxlen=64)
        self.statustext_count = 0
        self.mode_name: Callable[[int], str] | None = None  # the profile's, once known
        self.clock_s: Callable[[], float] = lambda: float("nan")  # vehicle time, for stamping texts
        self._heartbeat_listeners: list[Callable[[Any], None]] = []
        transport.on("HEARTBEAT", self._on_heartbeat)
        transport.on("STATUSTEXT", self._on_statustext)
        transport.on("AUTOPILOT_VERSION", self._on_autopilot_version)

    def on_heartbeat(self, listener: Callable[[Any], None]) -> None:
        """Call ``listener(msg)`` after every autopilot HEARTBEAT was taken in."""
        self._heartbeat_listeners.append(listener)

    @property
    def mode(self) -> str:
        """Neutral name of the mode in the latest autopilot HEARTBEAT ("" before one, or before a profile)."""
        if self.custom_mode is None or self.mode_name is None:
            return ""
        return self.mode_name(self.custom_mode)

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & SAFETY_ARMED)

    def take_heartbeat(self, msg: Any) -> None:
        """Take in an autopilot HEARTBEAT (also the one that answered the connection)."""
        self.custom_mode = msg.custom_mode
        self.base_mode = msg.base_mode
        self.last_heartbeat = msg
        self.heartbeat_count += 1
        for listener in self._heartbeat_listeners:
            listener(msg)

    def _on_heartbeat(self, msg: Any) -> None:
        if self.transport.from_autopilot(msg):
            self.take_heartbeat(msg)

    def _on_statustext(self, msg: Any) -> None:
        if not self.transport.from_vehicle(msg):
            return
        text = msg.text.decode("ascii", "replace") if isinstance(msg.text, bytes) else str(msg.text)
        text = text.split("\x00", 1)[0]
        self.statustexts.append((self.clock_s(), msg.severity, text))
        self.statustext_count += 1
        log.debug("vehicle says [%d] %s", msg.severity, text)

    def _on_autopilot_version(self, msg: Any) -> None:
        if self.transport.from_vehicle(msg):
            self.capabilities = int(msg.capabilities)
            self.hardware_uid = _board_uid(msg) or self.hardware_uid

    def warnings_since(self, since_count: int) -> str:
        """The warnings (or worse) the vehicle sent after ``since_count`` texts, joined ("" if none)."""
        new_count = self.statustext_count - since_count
        if new_count <= 0:
            return ""
        recent = list(self.statustexts)[-min(new_count, len(self.statustexts)):]
        return "; ".join(text for _time, severity, text in recent if severity <= MAV_SEVERITY_WARNING)

    def refusal_naming(self, name: str, since_count: int) -> str | None:
        """The newest STATUSTEXT warning (or worse) received after ``since_count`` texts that names ``name``."""
        new_count = self.statustext_count - since_count
        if new_count <= 0:
            return None
        recent = list(self.statustexts)[-min(new_count, len(self.statustexts)):]
        for _time, severity, text in reversed(recent):
            if severity <= MAV_SEVERITY_WARNING and name in text:
                return text
        return None


def _board_uid(msg: Any) -> str | None:
    """The flight controller's own id from AUTOPILOT_VERSION (``uid2``'s 18 bytes, else ``uid``), as
    hex; None when the autopilot sends zeros (a simulator, a board without one)."""
    uid2 = getattr(msg, "uid2", None)
    try:
        raw = bytes(int(b) & 0xFF for b in uid2) if uid2 is not None else b""
    except (TypeError, ValueError):
        raw = b""
    if any(raw):
        return raw.hex()
    uid = getattr(msg, "uid", 0)
    return f"{int(uid):016x}" if isinstance(uid, int) and uid else None
