"""Parameter-protocol value handling: float32 rounding, integer encodings, echo matching (SPEC C1).

PARAM_VALUE carries every parameter in a 4-byte float field. ArduPilot **casts** integers to float
(``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST``); PX4 copies the integer's bytes into the float
(``..._PARAM_ENCODE_BYTEWISE``). A write is trusted only when the echo carries the same name and
the same value after both went through that encoding and float32 rounding. Pure functions; struct
is used for the bytewise reinterpretation because that is exactly a C union.
"""
from __future__ import annotations

import math
import struct
from typing import Literal

IntEncoding = Literal["cast", "bytewise"]

# MAV_PARAM_TYPE
UINT8, INT8, UINT16, INT16, UINT32, INT32, UINT64, INT64, REAL32, REAL64 = 1, 2, 3, 4, 5, 6, 7, 8, 9, 10
_INT_FORMATS = {UINT8: "<B", INT8: "<b", UINT16: "<H", INT16: "<h", UINT32: "<I", INT32: "<i"}
_INT_RANGES = {UINT8: (0, 255), INT8: (-128, 127), UINT16: (0, 65535), INT16: (-32768, 32767),
               UINT32: (0, 2**32 - 1), INT32: (-(2**31), 2**31 - 1)}

# MAV_PROTOCOL_CAPABILITY bits
CAPABILITY_PARAM_ENCODE_BYTEWISE = 16
CAPABILITY_PARAM_ENCODE_C_CAST = 131072


def float32(value: float) -> float:
    """``value`` rounded to the nearest IEEE-754 single (what travels in PARAM_SET/PARAM_VALUE)."""
    return struct.unpack("<f", struct.pack("<f", value))[0]


def is_integer_type(param_type: int) -> bool:
    return param_type in _INT_FORMATS


def encoding_from_capabilities(capabilities: int, default: IntEncoding = "cast") -> IntEncoding:
    """Integer encoding announced by AUTOPILOT_VERSION.capabilities (``default`` if it says neither)."""
    if capabilities & CAPABILITY_PARAM_ENCODE_C_CAST:
        return "cast"
    if capabilities & CAPABILITY_PARAM_ENCODE_BYTEWISE:
        return "bytewise"
    return default


def encode_value(value: float, param_type: int, encoding: IntEncoding) -> float:
    """The float to put in PARAM_SET.param_value for ``value`` of ``param_type``.

    Integers are rounded to the nearest integer and must fit the type (ValueError otherwise);
    ``cast`` sends float(int), ``bytewise`` sends the integer's bytes reinterpreted as a float32.
    """
    if not is_integer_type(param_type):
        return float32(value)
    if not math.isfinite(value):
        raise ValueError(f"non-finite value {value!r} for an integer parameter")
    integer = int(round(value))
    low, high = _INT_RANGES[param_type]
    if not low <= integer <= high:
        raise ValueError(f"{integer} does not fit parameter type {param_type} ({low}..{high})")
    if encoding == "cast":
        return float32(float(integer))
    raw = struct.pack(_INT_FORMATS[param_type], integer).ljust(4, b"\x00")  # unused union bytes are zero
    return struct.unpack("<f", raw)[0]


def decode_value(wire_value: float, param_type: int, encoding: IntEncoding) -> float:
    """The parameter's value from PARAM_VALUE.param_value (inverse of :func:`encode_value`)."""
    if not is_integer_type(param_type) or encoding == "cast":
        return float(wire_value)
    raw = struct.pack("<f", wire_value)
    size = struct.calcsize(_INT_FORMATS[param_type])
    return float(struct.unpack(_INT_FORMATS[param_type], raw[:size])[0])


def echo_matches(sent_value: float, echoed_value: float, param_type: int) -> bool:
    """True when the echoed (decoded) value is the value we sent, as the wire can carry it.

    Floats compare after float32 rounding of both sides (bit-exact, NaN never matches); integers
    compare as rounded integers.
    """
    if not (math.isfinite(sent_value) and math.isfinite(echoed_value)):
        return False
    if is_integer_type(param_type):
        return int(round(sent_value)) == int(round(echoed_value))
    return float32(sent_value) == float32(echoed_value)


def param_id_str(param_id: str | bytes) -> str:
    """PARAM_VALUE.param_id as a clean str (bytes, trailing NULs and padding removed)."""
    if isinstance(param_id, bytes):
        param_id = param_id.decode("ascii", errors="replace")
    return param_id.split("\x00", 1)[0].strip()


def validate_param_name(name: str) -> str:
    """A parameter id must be 1..16 printable ASCII characters (MAVLink PARAM_SET.param_id)."""
    if not isinstance(name, str) or not 1 <= len(name) <= 16 or not name.isascii() or not name.isprintable():
        raise ValueError(f"invalid parameter name {name!r} (1..16 printable ASCII characters)")
    return name
