"""Reading vehicle parameter sets from a preset's JSON dict (the simulator's data files, read as data)."""
from __future__ import annotations

from dataclasses import fields
from typing import Any, Mapping


def section_numbers(data: Mapping[str, Any], cls: type, sections: tuple[str, ...],
                    aliases: Mapping[str, str]) -> dict[str, float]:
    """The numeric fields of dataclass ``cls`` found in the first of ``sections`` present in ``data``
    (else at top level), by field name or alias, case-insensitively."""
    lowered = {str(k).lower(): v for k, v in data.items()}
    section: Mapping[str, Any] = next((lowered[name] for name in sections if isinstance(lowered.get(name), Mapping)),
                                      data)
    known = {f.name for f in fields(cls)}
    values: dict[str, float] = {}
    for key, value in section.items():
        name = str(key).lower()
        name = name if name in known else aliases.get(name, "")
        if name in known and isinstance(value, (int, float)) and not isinstance(value, bool):
            values[name] = float(value)
    return values


def actuator_limit(data: Mapping[str, Any], name: str) -> float | None:
    """``data["actuators"][name]`` when present (e.g. ``elevator_max``, ``mass_max``)."""
    actuators = {str(k).lower(): v for k, v in data.items()}.get("actuators")
    if isinstance(actuators, Mapping) and name in actuators:
        return float(actuators[name])
    return None
