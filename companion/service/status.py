"""The state the status page shows: a small thread-safe board of JSON-ready sections.

The resident loop's thread writes (:class:`companion.service.feed.StatusFeed`), the HTTP thread
reads (:mod:`companion.service.http`). A section is replaced as a whole, never changed in place,
so a reader copies the top-level mapping under the lock and serialises outside it. Values are made
JSON-ready when written: NaN and infinities become ``null`` (the JSON has none), tuples lists,
mapping keys strings. Times in the sections are vehicle times (``time_boot_ms``); the one wall-clock
figure, ``vehicle.telemetry_age_s`` (how long ago the last snapshot arrived), is for the reader's
eyes only and computed when the page asks.
"""
from __future__ import annotations

import json
import math
import threading
import time
from typing import Any

#: the sections, in the order the JSON lists them (``None``: nothing known yet)
SECTIONS = ("companion", "connection", "vehicle", "procedure", "estimates", "models", "schedule", "gains",
            "health", "learning", "alarms", "messages", "report", "history")


def json_ready(value: Any) -> Any:
    """``value`` as strict JSON can hold it (non-finite numbers → None, numpy scalars → Python)."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    item = getattr(value, "item", None)  # numpy scalar
    if callable(item):
        return json_ready(item())
    return str(value)


class StatusBoard:
    """Thread-safe sections (module docstring); :meth:`set` from one thread, :meth:`snapshot` from any."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._sections: dict[str, Any] = dict.fromkeys(SECTIONS)
        self._telemetry_mark: float | None = None  # time.monotonic() of the last vehicle snapshot

    def set(self, section: str, value: Any) -> None:
        """Replace one section (``value`` is converted by :func:`json_ready` before the lock)."""
        if section not in self._sections:
            raise KeyError(f"unknown status section {section!r} (known: {', '.join(SECTIONS)})")
        ready = json_ready(value)
        with self._lock:
            self._sections[section] = ready
            if section == "vehicle":
                self._telemetry_mark = time.monotonic()

    def get(self, section: str) -> Any:
        with self._lock:
            return self._sections[section]

    def snapshot(self) -> dict[str, Any]:
        """A consistent copy of every section, plus the age of the last vehicle snapshot."""
        with self._lock:
            out = dict(self._sections)
            mark = self._telemetry_mark
        if isinstance(out.get("vehicle"), dict):
            out["vehicle"] = {**out["vehicle"],
                              "telemetry_age_s": None if mark is None else round(time.monotonic() - mark, 3)}
        return out

    def to_json(self) -> bytes:
        """The snapshot as strict JSON (``allow_nan=False``: a non-finite number is a bug, not output)."""
        return json.dumps(self.snapshot(), allow_nan=False, separators=(",", ":")).encode("utf-8")
