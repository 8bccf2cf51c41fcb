"""The strict-JSON form of a value: what every JSON the product stores or prints is made of.

NaN and infinities become None (strict JSON holds neither), numpy arrays and scalars plain lists
and numbers, tuples lists, mapping keys strings, and a dataclass record its fields under a
``"type"`` tag naming its class. A behaviour's result builds its ``to_dict`` from this, so a result's
JSON is the one the store writes; ``companion.records.serialise`` (the one serialiser at the store
boundary) is this form plus its register of the record types it reads back.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Iterable

#: called with a record's class before it is written (the serialiser's: refuse one it cannot read back)
RecordCheck = Callable[[type], None]


def json_form(value: Any, check: RecordCheck | None = None) -> Any:
    """``value`` as strict-JSON-ready Python (module docstring); ``check`` sees every record's class."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return tagged(value, check)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_form(v, check) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_form(v, check) for v in value]
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return json_form(value.tolist(), check)
    return value


def tagged(record: Any, check: RecordCheck | None = None) -> dict:
    """A dataclass record as ``{"type": its class name, field: json_form(value), ...}``."""
    if check is not None:
        check(type(record))
    out: dict[str, Any] = {"type": type(record).__name__}
    for f in dataclasses.fields(record):
        out[f.name] = json_form(getattr(record, f.name), check)
    return out


def finite_floats(values: Iterable[float]) -> list[float | None]:
    """A recorded series as stored: each value a float, None where it is not finite."""
    return [float(v) if math.isfinite(v) else None for v in values]

