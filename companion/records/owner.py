"""Which process owns a trail, told apart from a later process that got the same PID.

A trail is interrupted when the process that opened it is gone. A PID alone cannot say that: after
the computer restarts (a companion computer power-cycled with its boat) or after enough processes,
another program runs under the dead companion's PID, and its trail would never be followed. So the
owner is stored as (host, kernel boot id, PID, the process's start time in clock ticks since boot),
read from ``/proc`` (Linux); a process is the owner only if all four still match. Where ``/proc``
is missing (another system) the boot id and start time are empty and the PID decides, as before.
"""
from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from pathlib import Path

BOOT_ID_FILE = Path("/proc/sys/kernel/random/boot_id")


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="ascii", errors="replace").strip()
    except OSError:
        return ""


def _start_ticks(pid: int) -> str:
    """Field 22 of ``/proc/<pid>/stat`` (start time after boot, clock ticks); empty if unreadable.
    The command name (field 2) may hold spaces and parentheses, so fields are counted after its ')'."""
    stat = _read(Path(f"/proc/{pid}/stat"))
    if ")" not in stat:
        return ""
    fields = stat.rsplit(")", 1)[1].split()
    return fields[19] if len(fields) > 19 else ""


@dataclass(frozen=True)
class ProcessOwner:
    """A process, as a trail stores it (module docstring)."""

    pid: int | None
    host: str
    boot_id: str = ""
    started: str = ""

    @classmethod
    def current(cls) -> "ProcessOwner":
        pid = os.getpid()
        return cls(pid, socket.gethostname(), _read(BOOT_ID_FILE), _start_ticks(pid))

    def alive(self) -> bool:
        """The owning process still runs: same host, same boot, the PID exists and started when the
        owner did. Another user's live process (no permission to signal it) counts as alive."""
        if self.pid is None or self.host != socket.gethostname():
            return False
        if self.boot_id and _read(BOOT_ID_FILE) not in ("", self.boot_id):
            return False  # the computer restarted since: every process of then is gone
        try:
            os.kill(int(self.pid), 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            pass
        if self.started:
            now = _start_ticks(int(self.pid))
            return not now or now == self.started  # another program under a reused PID is not the owner
        return True

    def describe(self) -> str:
        return f"pid {self.pid} on {self.host}"
