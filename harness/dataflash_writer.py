"""A minimal ArduPilot DataFlash (.bin) writer for test fixtures, read back by pymavlink's DFReader.

Every message is ``A3 95 <type>`` and its packed payload (little-endian). FMT (type 128, format
``BBnNZ``: type, length, name[4], format[16], columns[64]) defines each message type; UNIT
(``QbZ``), MULT (``Qbd``) and FMTU (``QBNN``: TimeUS, FmtType, UnitIds[16], MultIds[16]) give the
units the way ArduPilot writes them. Format characters used: Q uint64, B uint8, H uint16, f float,
b int8, d double, c int16 ×0.01, C uint16 ×0.01, n char[4], N char[16], Z char[64].
"""
from __future__ import annotations

import struct
from pathlib import Path

HEAD = b"\xa3\x95"
_CHARS = {"Q": "Q", "B": "B", "H": "H", "f": "f", "b": "b", "d": "d", "c": "h", "C": "H", "n": "4s", "N": "16s", "Z": "64s",
          "i": "i", "I": "I"}


class DataFlashWriter:
    """``define(name, format, columns)`` then ``write(name, *values)``; ``save(path)``."""

    def __init__(self) -> None:
        self._out = bytearray()
        self._types: dict[str, tuple[int, struct.Struct, str]] = {}
        self._next = 64
        self._types["FMT"] = (128, struct.Struct("<BB4s16s64s"), "BBnNZ")
        self._emit(128, self._types["FMT"][1].pack(128, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"))
        self.define("UNIT", "QbZ", "TimeUS,Id,Label")
        self.define("MULT", "Qbd", "TimeUS,Id,Mult")
        self.define("FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds")

    def _emit(self, type_id: int, payload: bytes) -> None:
        self._out += HEAD + bytes([type_id]) + payload

    def define(self, name: str, fmt: str, columns: str, units: str | None = None, mults: str | None = None) -> None:
        type_id = self._next
        self._next += 1
        packer = struct.Struct("<" + "".join(_CHARS[c] for c in fmt))
        self._types[name] = (type_id, packer, fmt)
        self._emit(128, self._types["FMT"][1].pack(type_id, packer.size + 3, name.encode(), fmt.encode(),
                                                   columns.encode()))
        if units is not None:
            self.write("FMTU", 0, type_id, units.encode(), (mults or "-" * len(units)).encode())

    def unit(self, ident: str, label: str) -> None:
        self.write("UNIT", 0, ord(ident), label.encode())

    def mult(self, ident: str, value: float) -> None:
        self.write("MULT", 0, ord(ident), value)

    def write(self, name: str, *values) -> None:
        type_id, packer, fmt = self._types[name]
        packed = []
        for c, v in zip(fmt, values):
            if c in "cC":
                v = int(round(v * 100))
            elif c in "nNZ" and isinstance(v, str):
                v = v.encode()
            packed.append(v)
        self._emit(type_id, packer.pack(*packed))

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_bytes(bytes(self._out))
        return path
