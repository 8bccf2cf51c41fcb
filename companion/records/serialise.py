"""The one serialiser at the store boundary: typed records <-> JSON (SPEC C10).

Every record the product stores (models, identification attempts, speed schedules with their
trend, gain designs, surge models and speed-loop designs) is a dataclass. :func:`to_json` writes it with a ``"type"`` tag so
:func:`from_json` gives back the same type with the same numbers; NaN and infinities become
``null`` (strict JSON), and come back as NaN for float fields. Nothing else in the product packs or
unpacks these records by hand.

A record type is known by being listed in :data:`RECORD_TYPES` (:func:`register` adds one); the
tag is the class name. A type whose invariant is newer than some of its stored records names the
looser type those records are read back as (:data:`READ_BROKEN_AS`): a ``"YawModel"`` stored before
models validated at construction (a rejected attempt's unstable or inverted estimate) is read back
as a ``YawEstimate`` (``companion.numerics.identification``), which is stored under its own tag.
The JSON form itself (tags, nulls, numpy) is :mod:`behaviors.json_form`, which a behaviour's
result is written with too; this module adds the register, so only records it can read back are
stored.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import typing
from typing import Any

from behaviors.json_form import json_form, tagged

log = logging.getLogger(__name__)

RECORD_TYPES: dict[str, type] = {}
#: tag → the looser type a stored record is read back as when its numbers break the tagged type's
#: invariant (the record was stored before the invariant existed); the looser type has the same fields
READ_BROKEN_AS: dict[str, type] = {}


def register(cls: type, read_broken_as: type | None = None) -> type:
    """Make a dataclass storable (usable as a decorator); ``read_broken_as``: the type a stored record
    of ``cls`` whose numbers ``cls`` refuses (ValueError) is read back as."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls.__name__} is not a dataclass")
    RECORD_TYPES[cls.__name__] = cls
    if read_broken_as is not None:
        READ_BROKEN_AS[cls.__name__] = read_broken_as
    return cls


def _registered(cls: type) -> None:
    """TypeError for a record class :func:`from_json` could not give back."""
    if RECORD_TYPES.get(cls.__name__) is not cls:
        raise TypeError(f"{cls.__name__} is not a registered record type")


def json_ready(value: Any) -> Any:
    """``value`` as strict-JSON-ready Python: records tagged, NaN/inf as None, numpy as lists/floats
    (:func:`behaviors.json_form.json_form`, every record registered)."""
    return json_form(value, _registered)


def null_reasons(value: Any, reason: str, prefix: str = "") -> dict[str, str]:
    """``{dotted.path: reason}`` for every NaN or infinity in ``value`` (dicts, lists, numpy values),
    i.e. every number :func:`json_ready` writes as null: output that says *why* a number is null."""
    out: dict[str, str] = {}
    if isinstance(value, dict):
        for key, item in value.items():
            out.update(null_reasons(item, reason, f"{prefix}.{key}" if prefix else str(key)))
    elif isinstance(value, (list, tuple)):
        for index, item in enumerate(value):
            out.update(null_reasons(item, reason, f"{prefix}[{index}]"))
    elif hasattr(value, "tolist") and not isinstance(value, float):  # numpy arrays and scalars
        out.update(null_reasons(value.tolist(), reason, prefix))
    elif isinstance(value, float) and not math.isfinite(value):
        out[prefix or "value"] = reason
    return out


def to_json(record: Any) -> dict:
    """A registered dataclass as a JSON-ready dict with its ``"type"`` tag."""
    return tagged(record, _registered)


def _restore(value: Any, hint: Any) -> Any:
    if isinstance(value, dict) and value.get("type") in RECORD_TYPES:
        return from_json(value)
    if value is None and hint in (float, "float"):
        return math.nan
    origin = typing.get_origin(hint)
    if origin is tuple and isinstance(value, list):
        return tuple(value)
    if value is None and origin is typing.Union and float in typing.get_args(hint) and type(None) not in typing.get_args(hint):
        return math.nan
    if isinstance(value, list):
        return [_restore(v, None) for v in value]
    return value


def from_json(data: dict) -> Any:
    """The record :func:`to_json` wrote (ValueError for an unknown or missing tag)."""
    tag = data.get("type") if isinstance(data, dict) else None
    cls = RECORD_TYPES.get(tag) if tag is not None else None
    if cls is None:
        raise ValueError(f"not a stored record (type {tag!r}; known: {sorted(RECORD_TYPES)})")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in data and f.init:
            kwargs[f.name] = _restore(data[f.name], hints.get(f.name))
    try:
        return cls(**kwargs)
    except ValueError as exc:
        looser = READ_BROKEN_AS.get(cls.__name__)
        if looser is None:
            raise
        # stored before the invariant: read back as the looser record it is
        log.info("a stored %s is read back as a %s: %s", tag, looser.__name__, exc)
        return looser(**kwargs)


def _register_product_records() -> None:
    """The product's storable records (imported here, not in the numerics: they stay pure)."""
    from behaviors.gain_scheduling import DesignPoint, GainDesign
    from behaviors.identification import IdentificationAttempt
    from companion.numerics.cascade_gains import CascadeRules
    from companion.numerics.gains import GainBounds
    from companion.numerics.identification import PitchModel, YawEstimate, YawModel
    from companion.numerics.pitch_gains import PitchGainBounds, PitchSchedule
    from companion.numerics.schedule import YawSchedule
    from companion.numerics.speed_gains import SpeedDesign, SpeedLoopGains
    from companion.numerics.surge import SurgeModel

    for cls in (YawEstimate, PitchModel, YawSchedule, PitchSchedule, DesignPoint, GainDesign, IdentificationAttempt,
                SurgeModel, SpeedLoopGains, SpeedDesign, GainBounds, CascadeRules, PitchGainBounds):
        register(cls)
    register(YawModel, read_broken_as=YawEstimate)


_register_product_records()
