"""A MAVLink frame parser for one TCP client's byte stream that finds its way back after damage.

pymavlink's parser trusts a frame's length byte: a frame damaged on the way (bytes lost on a serial
radio, bridged to our TCP port) makes it wait for bytes that belong to the next frames, and when they
come it discards them all with the damaged one (up to 280 bytes: MAVLink's longest frame). On a live
link more bytes soon complete the false frame; in lockstep nothing more comes — the companion waits
for the sample its swallowed acknowledgement would have released — and vehicle time stops while the
companion's repeated acknowledgements (24 bytes each) fill the false frame.

:class:`ResyncParser` parses the same frames with pymavlink's own decoder (CRC, signing, message
types) but keeps its own buffer and resynchronises the way a radio's receiver must:

* a frame that fails its checks is one bad byte at its start: parsing goes on from the next byte,
  so a good frame inside the false one's length is found;
* an incomplete frame is waited for unless a complete frame that passes every check (a known message,
  CRC, signature) starts after it in the buffer: then the incomplete head was damaged, and is dropped.

What is dropped is returned as pymavlink's BAD_DATA messages, one per run of dropped bytes (the
simulator counts them). On a clean stream the frames and their order are pymavlink's.
"""
from __future__ import annotations

import sys
from typing import Any

__all__ = ["ResyncParser"]

MAGIC_V2, MAGIC_V1 = 0xFD, 0xFE
V2_OVERHEAD, V1_OVERHEAD, SIGNATURE_LEN = 12, 8, 13
INCOMPAT_SIGNED = 0x01


def _frame_length(buffer: bytearray, start: int) -> int | None:
    """Length of the frame whose magic byte is at ``start`` (None until its header has arrived)."""
    if buffer[start] == MAGIC_V2:
        if len(buffer) - start < 3:
            return None
        signed = buffer[start + 2] & INCOMPAT_SIGNED
        return buffer[start + 1] + V2_OVERHEAD + (SIGNATURE_LEN if signed else 0)
    if len(buffer) - start < 2:
        return None
    return buffer[start + 1] + V1_OVERHEAD


def _next_magic(buffer: bytearray, pos: int) -> int:
    candidates = [i for i in (buffer.find(MAGIC_V2, pos), buffer.find(MAGIC_V1, pos)) if i >= 0]
    return min(candidates) if candidates else -1


class ResyncParser:
    """Frames from a byte stream (module docstring). ``mav`` is a pymavlink ``MAVLink`` object: its
    decoder, signing state and message classes are used, its own buffer is not."""

    def __init__(self, mav: Any) -> None:
        self.mav = mav
        self._dialect = sys.modules[type(mav).__module__]  # its MAVError and BAD_DATA classes
        self._buffer = bytearray()
        self.discarded_bytes = 0

    def parse_buffer(self, data: bytes) -> list:
        """The messages completed by ``data`` (BAD_DATA for each run of bytes dropped), in order."""
        buffer = self._buffer
        buffer += data
        out: list = []
        junk_start: int | None = None  # start of the run of bytes being dropped
        pos = 0
        while pos < len(buffer):
            start = _next_magic(buffer, pos)
            if start < 0:
                junk_start = pos if junk_start is None else junk_start
                pos = len(buffer)
                break
            if start > pos and junk_start is None:
                junk_start = pos
            length = _frame_length(buffer, start)
            if length is None or start + length > len(buffer):
                found = self._complete_frame_after(buffer, start)
                if found is None:
                    pos = start
                    break  # wait for the rest
                after, after_length, msg = found
                junk_start = start if junk_start is None else junk_start
                self._flush_junk(out, buffer, junk_start, after)
                junk_start = None
                out.append(msg)
                pos = after + after_length
                continue
            msg = self._decode(buffer[start:start + length])
            if msg is None:  # damaged: one bad byte, go on from the next
                junk_start = start if junk_start is None else junk_start
                pos = start + 1
                continue
            if junk_start is not None:
                self._flush_junk(out, buffer, junk_start, start)
                junk_start = None
            out.append(msg)
            pos = start + length
        if junk_start is not None:
            self._flush_junk(out, buffer, junk_start, pos)
        del buffer[:pos]
        return out

    def _decode(self, frame: bytearray) -> Any | None:
        """The message of one whole frame, or None when it fails a check (or is of an unknown type:
        without its CRC_EXTRA a frame cannot be checked)."""
        incompat = frame[2] if frame[0] == MAGIC_V2 else 0
        if incompat & ~INCOMPAT_SIGNED:
            return None
        try:
            msg = self.mav.decode(bytearray(frame))
        except self._dialect.MAVError:
            return None
        if msg.get_type().startswith("UNKNOWN"):
            return None
        return msg

    def _complete_frame_after(self, buffer: bytearray, start: int) -> tuple[int, int, Any] | None:
        """The first complete frame passing every check that starts after ``start``: (its start,
        its length, its message)."""
        pos = start + 1
        while True:
            candidate = _next_magic(buffer, pos)
            if candidate < 0:
                return None
            length = _frame_length(buffer, candidate)
            if length is not None and candidate + length <= len(buffer):
                msg = self._decode(buffer[candidate:candidate + length])
                if msg is not None:
                    return candidate, length, msg
            pos = candidate + 1

    def _flush_junk(self, out: list, buffer: bytearray, start: int, end: int) -> None:
        if end <= start:
            return
        self.discarded_bytes += end - start
        out.append(self._dialect.MAVLink_bad_data(bytes(buffer[start:end]), "damaged frame dropped (resynchronised)"))
