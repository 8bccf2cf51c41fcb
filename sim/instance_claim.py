"""A simulator instance reserved for this process, for any firmware that numbers its instances
(ArduPilot SITL's ``-I``, PX4's ``-i``).

Free ports alone are not a reservation: the firmware binds them only after it has started, so two
simulators started together (parallel tests) both saw instance 0 free and the second one's firmware
exited. A claim holds an exclusive ``flock`` on the instance's lock file of this project, which the
operating system releases with the process, so a killed run leaves no stale claim; the caller's
``free`` predicate also checks what others hold (ports, the firmware's own lock).
"""
from __future__ import annotations

import fcntl
import tempfile
from pathlib import Path
from typing import Callable


class InstanceClaim:
    """The first instance below ``limit`` that no process of ours has claimed and ``free(instance)``
    says is free, held until :meth:`release` (or this process's death)."""

    def __init__(self, kind: str, free: Callable[[int], bool], limit: int = 50) -> None:
        self._handle = None
        pattern = str(Path(tempfile.gettempdir()) / f"marine-companion-{kind}-{{instance}}.lock")
        for instance in range(limit):
            handle = open(pattern.format(instance=instance), "a")  # noqa: SIM115 - held while claimed
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                handle.close()
                continue
            if not free(instance):  # e.g. a simulator this project did not start
                handle.close()  # closing releases the lock
                continue
            self.instance, self._handle = instance, handle
            return
        raise RuntimeError(f"no free {kind} instance among the first {limit}")

    def release(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None
