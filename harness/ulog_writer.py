"""A minimal PX4 ULog writer for test fixtures (format: PX4 docs, "ULog File Format").

File header: magic ``ULog`` 0x01 0x12 0x35, version byte 1, uint64 timestamp (µs). Then messages,
each ``uint16 msg_size, uint8 msg_type, payload``: FLAG_BITS 'B' (8 compat + 8 incompat flag bytes,
3 uint64 appended offsets), one FORMAT 'F' per topic (``name:type field;type field;…``), then in the
data section ADD_LOGGED_MSG 'A' (uint8 multi_id, uint16 msg_id, name) and DATA 'D' (uint16 msg_id,
the fields packed little-endian, no padding). Only the field types used here: uint64_t, float, float[N].
"""
from __future__ import annotations

import struct
from pathlib import Path
from typing import Sequence

ULOG_MAGIC = b"ULog\x01\x12\x35"
_TYPES = {"uint64_t": "Q", "float": "f", "int32_t": "i", "uint16_t": "H", "uint8_t": "B"}


def _message(kind: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def _struct(fields: Sequence[tuple[str, str]]) -> str:
    out = "<"
    for ftype, _ in fields:
        base, _, count = ftype.partition("[")
        out += (count.rstrip("]") if count else "") + _TYPES[base]
    return out


def write_ulog(path: str | Path, topics: dict[str, tuple[Sequence[tuple[str, str]], Sequence[Sequence[float]]]],
               start_us: int = 0) -> Path:
    """Write ``topics`` = {name: (fields [(type, name)], rows)} (the first field must be
    ``uint64_t timestamp``; a ``float[N]`` field takes N values in the row) as a ULog file."""
    path = Path(path)
    out = bytearray(ULOG_MAGIC + bytes([1]) + struct.pack("<Q", start_us))
    out += _message("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    for name, (fields, _) in topics.items():
        out += _message("F", f"{name}:{''.join(f'{t} {n};' for t, n in fields)}".encode())
    records = []
    for msg_id, (name, (fields, rows)) in enumerate(topics.items()):
        out += _message("A", struct.pack("<BH", 0, msg_id) + name.encode())
        packer = struct.Struct(_struct(fields))
        records += [(int(row[0]), msg_id, packer.pack(*([int(row[0])] + list(row[1:])))) for row in rows]
    for _, msg_id, data in sorted(records, key=lambda r: (r[0], r[1])):
        out += _message("D", struct.pack("<H", msg_id) + data)
    path.write_bytes(bytes(out))
    return path
