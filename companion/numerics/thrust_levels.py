"""Thrust levels that give distinct speeds: detecting a level that gives a speed already flown, and
re-spacing the levels still to fly within the thrusts that reach distinct speeds.

A boat at its top speed, or an autopilot asked for more than the boat can do (ArduRover's thrust
levels are fractions of WP_SPEED; measured: WP_SPEED 5 on a boat whose top speed is 3 m/s flew 60,
80 and 100 % all at 3.0 m/s), gives the same speed at several thrust levels. Each costs a settle and
a manoeuvre and adds nothing to a speed schedule. So, when a level settles at the speed of a lower
level (within ``SAME_SPEED_FRACTION``), the levels not yet flown — this one included — are replaced
by as many levels spread over the range of thrusts that gave distinct speeds: the largest gaps of
that range are halved in turn, and where the lowest level already gave the top speed the range is
extended down to half of it.

Pure: numbers in, numbers out.
"""
from __future__ import annotations

from typing import Mapping

#: two levels whose settled speeds differ by less than this fraction give "the same speed"
SAME_SPEED_FRACTION = 0.03
#: levels closer than this are not worth flying apart (thrust fraction)
MIN_LEVEL_GAP = 0.02


def same_speed_as(flown: Mapping[float, float], thrust: float, speed: float,
                  fraction: float = SAME_SPEED_FRACTION) -> float | None:
    """The lower flown thrust whose speed ``speed`` repeats (within ``fraction``), None if none."""
    for other, other_speed in sorted(flown.items()):
        if other < thrust and other_speed > 0 and abs(speed - other_speed) <= fraction * other_speed:
            return other
    return None


def respaced(flown: Mapping[float, float], count: int, fraction: float = SAME_SPEED_FRACTION) -> list[float]:
    """``count`` new thrust levels within the thrusts that reach distinct speeds (module docstring),
    highest first (nearest the thrust the vehicle is at); fewer when the range has no room left.

    ``flown``: thrust → settled speed of every level flown so far (the repeating one included)."""
    if count <= 0 or not flown:
        return []
    top_speed = max(flown.values())
    top = min(t for t, u in flown.items() if u >= (1.0 - fraction) * top_speed)  # the least thrust at the top
    distinct = sorted(t for t in flown if t <= top)
    low = distinct[0] if distinct[0] < top else top / 2.0
    points = sorted(set(distinct) | {low})
    new: list[float] = [] if low in flown else [low]
    points = sorted(set(points))
    while len(new) < count:
        gaps = [(b - a, a, b) for a, b in zip(points, points[1:])]
        if not gaps:
            break
        width, a, b = max(gaps)
        if width < 2 * MIN_LEVEL_GAP:
            break
        middle = round((a + b) / 2.0, 4)
        new.append(middle)
        points = sorted(points + [middle])
    return sorted(new[:count], reverse=True)
