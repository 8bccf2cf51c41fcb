"""Whole MAVLink frames in a byte stream or a datagram, with the few header and payload fields the
fault-injection tools read (``harness.fault_proxy`` over TCP, ``harness.udp_relay`` over UDP).

A frame is found from its magic byte (v2 0xFD, v1 0xFE), its length byte and the signature flag;
nothing is fully decoded on the hot path. Only the messages named in :data:`MESSAGE_IDS` are looked
into (common dialect numbers).
"""
from __future__ import annotations

import random
import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as dialect
from pymavlink.mavutil import x25crc

__all__ = ["MESSAGE_IDS", "MESSAGE_NAMES", "Frame", "split_datagram", "split_frames"]

MAGIC_V2, MAGIC_V1 = 0xFD, 0xFE
V2_OVERHEAD, V1_OVERHEAD, SIGNATURE_LEN = 12, 8, 13
INCOMPAT_SIGNED = 0x01

#: message ids the proxy looks into (common dialect numbers)
MESSAGE_IDS = {"HEARTBEAT": 0, "SYSTEM_TIME": 2, "SET_MODE": 11, "PARAM_REQUEST_READ": 20, "PARAM_VALUE": 22,
               "PARAM_SET": 23, "ATTITUDE": 30, "SERVO_OUTPUT_RAW": 36, "RC_CHANNELS_OVERRIDE": 70,
               "COMMAND_LONG": 76, "COMMAND_ACK": 77, "SET_ATTITUDE_TARGET": 82, "STATUSTEXT": 253}
MESSAGE_NAMES = {number: name for name, number in MESSAGE_IDS.items()}
#: full (untruncated) payload lengths of the messages whose fields are read
PAYLOAD_LENGTHS = {"COMMAND_LONG": 33, "PARAM_SET": 23, "RC_CHANNELS_OVERRIDE": 38, "STATUSTEXT": 54,
                   "ATTITUDE": 28, "SYSTEM_TIME": 12}
RC_RELEASE_LOW, RC_IGNORE_LOW, RC_RELEASE_HIGH = 0, 65535, 65534


@dataclass(frozen=True)
class Frame:
    """One whole MAVLink frame as it travels, with the few header fields the fault tools need."""

    raw: bytes
    msgid: int
    header_len: int  # bytes before the payload
    payload_len: int

    @property
    def name(self) -> str:
        return MESSAGE_NAMES.get(self.msgid, f"MSG_{self.msgid}")

    def payload(self) -> bytes:
        """The payload, zero-padded to its full length (MAVLink 2 truncates trailing zeros)."""
        body = self.raw[self.header_len:self.header_len + self.payload_len]
        full = PAYLOAD_LENGTHS.get(self.name, len(body))
        return body + bytes(max(0, full - len(body)))

    def command(self) -> int | None:
        """COMMAND_LONG's command id (None for other messages)."""
        return struct.unpack_from("<H", self.payload(), 28)[0] if self.name == "COMMAND_LONG" else None

    def command_params(self) -> tuple[float, ...] | None:
        """COMMAND_LONG's seven parameters (None for other messages)."""
        return struct.unpack_from("<7f", self.payload(), 0) if self.name == "COMMAND_LONG" else None

    def param_id(self) -> str | None:
        """PARAM_SET's parameter name (None for other messages)."""
        if self.name != "PARAM_SET":
            return None
        return self.payload()[6:22].split(b"\x00", 1)[0].decode("ascii", "replace")

    def text(self) -> str | None:
        """STATUSTEXT's text (None for other messages)."""
        if self.name != "STATUSTEXT":
            return None
        return self.payload()[1:51].split(b"\x00", 1)[0].decode("ascii", "replace")

    def time_boot_ms(self) -> int | None:
        """The vehicle time of an ATTITUDE or SYSTEM_TIME frame (None for others)."""
        if self.name == "ATTITUDE":
            return struct.unpack_from("<I", self.payload(), 0)[0]
        if self.name == "SYSTEM_TIME":
            return struct.unpack_from("<I", self.payload(), 8)[0]
        return None

    def rc_channels(self) -> list[int] | None:
        """RC_CHANNELS_OVERRIDE's 18 channel values, channel 1 first (None for other messages)."""
        if self.name != "RC_CHANNELS_OVERRIDE":
            return None
        values = struct.unpack("<8HBB10H", self.payload())
        return list(values[:8]) + list(values[10:])

    def signature(self) -> tuple[str, object, bytes] | None:
        """What makes a PARAM_SET or COMMAND_LONG the same request again (a retry): its name or
        command and its values (a COMMAND_LONG's confirmation counter left out); None for others."""
        if self.name == "PARAM_SET":
            return self.name, self.param_id(), self.payload()
        if self.name == "COMMAND_LONG":
            return self.name, self.command(), self.payload()[:30]
        return None

    def crc_ok(self) -> bool:
        """The frame's checksum matches (X.25 over header and payload with the message's CRC_EXTRA,
        pymavlink's tables): what a receiver keeps. False for a message this dialect does not know."""
        entry = dialect.mavlink_map.get(self.msgid)
        if entry is None:
            return False
        end = self.header_len + self.payload_len
        crc = x25crc(self.raw[1:end])
        crc.accumulate(bytes([entry.crc_extra]))
        return crc.crc == int.from_bytes(self.raw[end:end + 2], "little")

    def corrupted(self, rng: random.Random) -> bytes:
        """The frame with one payload (or checksum) byte flipped: its CRC no longer matches."""
        raw = bytearray(self.raw)
        end = self.header_len + self.payload_len + 2  # payload and checksum, never the header
        raw[rng.randrange(self.header_len, end)] ^= 0xFF
        return bytes(raw)


def split_frames(buffer: bytearray) -> tuple[list[Frame | bytes], bytearray]:
    """Whole frames (and runs of bytes that start no frame) from ``buffer``, and what is left (an
    incomplete frame). Garbage between frames is passed on as bytes, untouched."""
    out: list[Frame | bytes] = []
    pos = 0
    size = len(buffer)
    while pos < size:
        start = _next_magic(buffer, pos)
        if start < 0:
            out.append(bytes(buffer[pos:]))
            return out, bytearray()
        if start > pos:
            out.append(bytes(buffer[pos:start]))
        frame_len = _frame_length(buffer, start)
        if frame_len is None or start + frame_len > size:
            return out, bytearray(buffer[start:])
        header = 10 if buffer[start] == MAGIC_V2 else 6
        msgid = (int.from_bytes(buffer[start + 7:start + 10], "little") if buffer[start] == MAGIC_V2
                 else buffer[start + 5])
        out.append(Frame(bytes(buffer[start:start + frame_len]), msgid, header, buffer[start + 1]))
        pos = start + frame_len
    return out, bytearray()


def split_datagram(data: bytes) -> list[Frame | bytes]:
    """The frames of one datagram (a frame never spans datagrams): an incomplete tail is passed on
    as bytes, like garbage between frames."""
    items, rest = split_frames(bytearray(data))
    if rest:
        items.append(bytes(rest))
    return items


def _next_magic(buffer: bytearray, pos: int) -> int:
    v2, v1 = buffer.find(MAGIC_V2, pos), buffer.find(MAGIC_V1, pos)
    candidates = [i for i in (v2, v1) if i >= 0]
    return min(candidates) if candidates else -1


def _frame_length(buffer: bytearray, start: int) -> int | None:
    """Length of the frame starting at ``start`` (None until enough of its header arrived)."""
    if buffer[start] == MAGIC_V2:
        if len(buffer) - start < 3:
            return None
        signed = buffer[start + 2] & INCOMPAT_SIGNED
        return V2_OVERHEAD + buffer[start + 1] + (SIGNATURE_LEN if signed else 0)
    if len(buffer) - start < 2:
        return None
    return V1_OVERHEAD + buffer[start + 1]
