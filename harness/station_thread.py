"""What the harness's ground stations share: a pymavlink connection of their own, COMMAND_LONG to
the autopilot, and a watcher thread whose failure is said when the station stops (never lost)."""
from __future__ import annotations

import threading


class StationThread:
    """Subclasses implement ``_run`` (the thread's loop, until ``_stop`` is set) and name ``what``."""

    what = "ground station"

    def __init__(self) -> None:
        self.conn = None
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def command(self, command: int, *params: float) -> None:
        """A COMMAND_LONG to the autopilot (system 1, component 1), unused parameters 0."""
        values = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(1, 1, command, 0, *values)

    def _start_thread(self) -> None:
        self._thread = threading.Thread(target=self._guarded, name=self.what, daemon=True)
        self._thread.start()

    def _guarded(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # noqa: BLE001 - said by stop(), never lost in the thread
            self.error = exc

    def _run(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self.conn is not None:
            self.conn.close()
        if self.error is not None:
            raise RuntimeError(f"the {self.what} failed: {self.error}") from self.error
