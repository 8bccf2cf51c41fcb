"""The records learning during missions shares between its loops (``companion run --learn``): the
phases of a learner and one gain write. The heading learner (``behaviors.mission_learning``, eq.
L.1–L.3) and the speed learner (``behaviors.mission_speed``, eq. L.4) both use them, so a write is
recorded, announced and stored the same way whichever loop made it."""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from companion.checks import require_choice

#: the loops learning writes gains of
LOOPS = ("heading", "speed")


class Phase(enum.Enum):
    LEARNING = "learning"
    WAITING_TO_WRITE = "waiting to write"
    VERIFYING = "verifying"
    KEPT = "kept"
    WAITING_TO_REVERT = "waiting to revert"
    REVERTED = "reverted"
    OVERRIDDEN = "overridden"  # someone else changed a learned gain: theirs stands, learning stops


@dataclass(frozen=True)
class GainWrite:
    """One write: when, why (``design``, ``schedule``, ``revert``), at what speed, which gains (neutral
    names), and of which loop (``heading``: eq. L.1–L.3, ``speed``: eq. L.4)."""

    time_s: float
    why: str
    speed: float
    gains: dict[str, float]
    loop: str = "heading"

    def __post_init__(self) -> None:
        require_choice(self, "loop", LOOPS)

    def to_dict(self) -> dict:
        return {"time_s": self.time_s, "why": self.why, "speed": self.speed if math.isfinite(self.speed) else None,
                "gains": dict(self.gains), "loop": self.loop}
