"""Checks that configuration values are usable, run where the value is made (SPEC §5, floor 0).

A configuration dataclass calls these from ``__post_init__``, so a bad value fails where it is
constructed, with one sentence naming the field, the value and what is allowed. The command line
shows the same sentence (``ValueError`` becomes its error message), so a user and a library caller
read the same words. Pure functions, no I/O.

Thrust levels have one unit across the product: a fraction 0..1 of the vehicle's full forward
demand (what it means on each autopilot is its profile's ``thrust_meaning``). Percent is accepted
only from a user, as a whole list, and converted here, once (:func:`parse_thrust_levels`).
"""
from __future__ import annotations

import math
from typing import Any, Iterable, Sequence

#: the most thrust levels a campaign flies (each costs a settle and a manoeuvre at sea)
MAX_THRUST_LEVELS = 12
#: the least thrust level a campaign flies: 5 % of full ahead. Below it a vehicle barely moves (it is
#: never "steady" at rest), and a level like 1e-9, or "1.5" read as 1.5 %, is a typo, not a plan
MIN_THRUST_LEVEL = 0.05


def _value(obj: Any, name: str) -> Any:
    return getattr(obj, name)


def _label(obj: Any, name: str) -> str:
    return f"{type(obj).__name__}.{name}"


def is_number(value: Any) -> bool:
    """A finite real number (bools are not numbers here)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def require_finite(obj: Any, *names: str) -> None:
    """Each named field is a finite number."""
    for name in names:
        value = _value(obj, name)
        if not is_number(value):
            raise ValueError(f"{_label(obj, name)} must be a finite number, not {value!r}")


def require_positive(obj: Any, *names: str) -> None:
    """Each named field is a finite number > 0."""
    for name in names:
        value = _value(obj, name)
        if not (is_number(value) and value > 0.0):
            raise ValueError(f"{_label(obj, name)} must be a finite number > 0, not {value!r}")


def require_non_negative(obj: Any, *names: str) -> None:
    """Each named field is a finite number ≥ 0."""
    for name in names:
        value = _value(obj, name)
        if not (is_number(value) and value >= 0.0):
            raise ValueError(f"{_label(obj, name)} must be a finite number ≥ 0, not {value!r}")


def require_measured(obj: Any, *names: str) -> None:
    """Each named field is a number ≥ 0 (infinity included: a step that never settled), or NaN or
    None where nothing was measured: a result's durations, errors and fractions."""
    for name in names:
        value = _value(obj, name)
        if value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)
                             and (math.isnan(value) or value >= 0.0)):
            continue
        raise ValueError(f"{_label(obj, name)} must be a number ≥ 0, NaN or None (not measured), not {value!r}")


def require_instance(obj: Any, name: str, kind: type) -> None:
    """The named field is a ``kind`` (e.g. a behaviour's lifecycle ``Status``)."""
    value = _value(obj, name)
    if not isinstance(value, kind):
        raise ValueError(f"{_label(obj, name)} must be a {kind.__name__}, not {value!r}")


def require_count(obj: Any, *names: str) -> None:
    """Each named field is an integer ≥ 0 (bools are not counts)."""
    for name in names:
        value = _value(obj, name)
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
            raise ValueError(f"{_label(obj, name)} must be an integer ≥ 0, not {value!r}")


def require_range(obj: Any, name: str, low: float, high: float, *, optional: bool = False) -> None:
    """The named field is a finite number in [low, high] (None allowed with ``optional``)."""
    value = _value(obj, name)
    if optional and value is None:
        return
    if not (is_number(value) and low <= value <= high):
        raise ValueError(f"{_label(obj, name)} must be a finite number in [{low:g}, {high:g}], not {value!r}")


def require_choice(obj: Any, name: str, choices: Iterable[Any]) -> None:
    """The named field is one of ``choices``."""
    value = _value(obj, name)
    allowed = tuple(choices)
    if value not in allowed:
        raise ValueError(f"{_label(obj, name)} must be one of {', '.join(map(str, allowed))}, not {value!r}")


def require_interval(obj: Any, name: str) -> None:
    """The named field is a pair (low, high) of finite numbers with low ≤ high."""
    value = _value(obj, name)
    ok = isinstance(value, (tuple, list)) and len(value) == 2 and all(is_number(v) for v in value) \
        and value[0] <= value[1]
    if not ok:
        raise ValueError(f"{_label(obj, name)} must be a pair (low, high) of finite numbers, low ≤ high, not {value!r}")


def check_thrust_levels(levels: Sequence[float], what: str = "thrusts") -> tuple[float, ...]:
    """``levels`` as a tuple of thrust levels: 1..:data:`MAX_THRUST_LEVELS` distinct fractions in
    [:data:`MIN_THRUST_LEVEL`, 1]. ValueError with one sentence otherwise."""
    values = tuple(levels)
    if not values:
        raise ValueError(f"{what}: no thrust level given")
    if len(values) > MAX_THRUST_LEVELS:
        raise ValueError(f"{what}: {len(values)} thrust levels; at most {MAX_THRUST_LEVELS} "
                         "(each costs a settle and a manoeuvre at sea)")
    for value in values:
        if not (is_number(value) and 0.0 < value <= 1.0):
            raise ValueError(f"{what}: {value!r} is not a thrust level in (0, 1] "
                             "(a fraction of full ahead: 60 % is 0.6)")
        if value < MIN_THRUST_LEVEL:
            raise ValueError(f"{what}: {value:g} of full ahead is below the least thrust level a campaign flies, "
                             f"{MIN_THRUST_LEVEL:g} ({MIN_THRUST_LEVEL * 100:g} %): the vehicle would barely move "
                             "(a fraction of full ahead: 60 % is 0.6)")
    if len(set(values)) != len(values):
        raise ValueError(f"{what}: {', '.join(f'{v:g}' for v in values)} repeats a thrust level")
    return values


def parse_thrust_levels(text: str) -> tuple[float, ...]:
    """A user's list of thrust levels, '0.6,0.8,1' or '60,80,100' (percent), in one unit.

    A list that mixes the units ('0.6,0.8,10': was 10 meant as 10 % or a typo of 1.0?) is refused,
    as are empty items ('0.6,,0.8') and anything :func:`check_thrust_levels` refuses."""
    items = [item.strip() for item in text.split(",")]
    if any(not item for item in items):
        raise ValueError(f"thrusts {text!r}: an empty item (write e.g. 0.6,0.8,1.0)")
    try:
        values = [float(item) for item in items]
    except ValueError:
        raise ValueError(f"thrusts {text!r}: not a list of numbers") from None
    if all(is_number(v) and v > 1.0 for v in values):
        values = [v / 100.0 for v in values]  # percent: the whole list
    elif any(is_number(v) and v > 1.0 for v in values):
        raise ValueError(f"thrusts {text!r} mixes fractions and percent: write all as fractions (0.6,0.8,1.0) "
                         "or all as percent (60,80,100)")
    return check_thrust_levels(values, f"thrusts {text!r}")
