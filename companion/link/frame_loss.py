"""Frames the link lost or spoiled, counted from MAVLink sequence numbers and parse failures.

Every MAVLink frame carries a sequence number (0–255) that its sender steps by one per frame. A
**gap** in one sender's numbers is frames that never arrived intact: dropped whole (a radio's full
buffer, a lost datagram) or damaged and discarded by the parser. A link that loses bytes (a serial
radio) spoils the frame they belonged to and can spoil the next one too, which pymavlink's parser
consumes while it looks for the damaged frame's end; the gap counts both.

Numbers are read modulo 256, so a jump cannot tell a gap from a frame that is late or repeated:

* a small jump ahead (fewer than :data:`REORDER_WINDOW` numbers) is a gap, counted at once;
* a frame that fills a gap counted within the last :data:`REORDER_WINDOW` numbers is late
  (reordered): it is taken back from the lost frames; one repeating the newest is a duplicate;
* any other jump is judged by the next frame of its sender: if the numbering goes on from it, the
  frames jumped over were lost (a dropout); if not, it was a stray (a very late or repeated frame) and
  is counted as a duplicate. So a single frame arriving half a second late is not 200 frames lost.

A dropout of more than 255 consecutive frames of one sender is undercounted (modulo 256), and a
sender that starts again (a reconnection) is forgotten (:meth:`FrameLoss.forget_senders`) so its new
numbering is no gap.

What the parser discarded (pymavlink's BAD_DATA: a failed CRC, a wrong length, bytes that start no
frame) is counted apart, with its bytes: ``corrupt`` says the link damaged frames, ``lost`` how many
of the sender's frames are missing. Pure bookkeeping, no I/O; :func:`next_whole_frame` finds where a
stream damaged inside a frame goes on (``Transport.resynchronise``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

__all__ = ["REORDER_WINDOW", "FrameLoss", "frame_check", "next_whole_frame"]

#: a jump ahead by fewer numbers is a gap at once; a gap this recent may still be filled by a late frame
REORDER_WINDOW = 64
SEQUENCE_MODULO = 256
MAGIC_V2, MAGIC_V1 = 0xFD, 0xFE
V2_OVERHEAD, V1_OVERHEAD, SIGNATURE_LEN, INCOMPAT_SIGNED = 12, 8, 13, 0x01


@dataclass
class _Sender:
    """One sender's numbering: the newest number placed, unwrapped, the recent numbers missing, and a
    large jump waiting for the next frame to say whether it was a dropout."""

    newest: int  # unwrapped sequence number of the newest frame placed
    missing: set[int] = field(default_factory=set)  # unwrapped numbers of recent gaps
    jump: tuple[int, int] | None = None  # (wrapped number, numbers skipped) of a large jump, not yet judged

    @property
    def wrapped(self) -> int:
        return self.newest % SEQUENCE_MODULO

    def skipped_to(self, seq: int) -> int:
        """Numbers skipped between the newest frame and ``seq`` (255: ``seq`` is the newest)."""
        return (seq - self.wrapped - 1) % SEQUENCE_MODULO


class FrameLoss:
    """Counts of one link's received frames (module docstring), by sender ``(system, component)``."""

    def __init__(self) -> None:
        self._senders: dict[tuple[int, int], _Sender] = {}
        self.received = 0  # frames received intact (from the senders counted)
        self.lost = 0  # frames missing from their sender's numbering (gaps, less those filled late)
        self.late = 0  # frames that arrived after a newer one of their sender and filled a gap
        self.duplicate = 0  # frames repeating a number already seen, or strays (module docstring)
        self.corrupt = 0  # frames (or runs of bytes) the parser discarded
        self.corrupt_bytes = 0  # ... and their bytes

    def frame(self, sender: tuple[int, int], seq: int) -> None:
        """A frame numbered ``seq`` arrived intact from ``sender``."""
        seq = int(seq) % SEQUENCE_MODULO
        self.received += 1
        state = self._senders.get(sender)
        if state is None:
            self._senders[sender] = _Sender(newest=seq)
            return
        if state.jump is not None:  # the frame before jumped far: does the numbering go on from it?
            jumped, skipped = state.jump
            state.jump = None
            if (seq - jumped - 1) % SEQUENCE_MODULO < min(REORDER_WINDOW, state.skipped_to(seq)):
                self._advance(state, skipped)  # it does (closer than from the frame before): a dropout
            else:
                self.duplicate += 1  # it does not: the jump was a stray
        skipped = state.skipped_to(seq)
        if skipped < REORDER_WINDOW:
            self._advance(state, skipped)
            return
        number = state.newest - (SEQUENCE_MODULO - 1 - skipped)  # the unwrapped number if it is behind
        if number in state.missing:  # late: fills a recent gap
            state.missing.discard(number)
            self.lost -= 1
            self.late += 1
        elif skipped == SEQUENCE_MODULO - 1:
            self.duplicate += 1  # the newest again
        else:
            state.jump = (seq, skipped)  # judged by the next frame

    def unchecked_frame(self, sender: tuple[int, int], seq: int) -> None:
        """A frame of a message the dialect does not know arrived: its CRC could not be checked (a
        damaged frame often decodes as one), so it is taken into the numbering only when it is
        exactly the next number of a sender already seen; otherwise it is ignored."""
        state = self._senders.get(sender)
        if state is not None and state.jump is None and state.skipped_to(int(seq) % SEQUENCE_MODULO) == 0:
            self.frame(sender, seq)

    def _advance(self, state: _Sender, skipped: int) -> None:
        """The newest frame is ``skipped`` numbers on from the last (they were lost)."""
        state.missing.update(range(state.newest + 1, state.newest + 1 + skipped))
        self.lost += skipped
        state.newest += skipped + 1
        if state.missing:
            oldest = state.newest - REORDER_WINDOW
            state.missing = {number for number in state.missing if number >= oldest}

    def discarded(self, size: int) -> None:
        """The parser discarded ``size`` bytes (a corrupt frame or bytes that start none)."""
        self.corrupt += 1
        self.corrupt_bytes += max(int(size), 0)

    def forget_senders(self) -> None:
        """Start every sender's numbering afresh (a new connection), keeping the counts."""
        self._senders.clear()

    @property
    def loss_fraction(self) -> float:
        """Frames lost over frames sent (received + lost); 0.0 before any frame."""
        sent = self.received + self.lost
        return self.lost / sent if sent else 0.0

    def counts(self) -> dict[str, int | float]:
        """The counts under the names the link quality reports them by."""
        return {"frames": self.received, "frames_lost": self.lost, "frames_late": self.late,
                "frames_duplicate": self.duplicate, "frames_corrupt": self.corrupt,
                "bytes_corrupt": self.corrupt_bytes, "frame_loss_fraction": self.loss_fraction}


def frame_check(dialect: Any) -> Callable[[bytes], bool]:
    """Whether a whole frame passes the checks its receiver makes before decoding it: a message the
    ``dialect`` module (pymavlink's generated one: ``mavlink_map``, ``x25crc``) knows, no unknown
    incompatibility flag, and its CRC with the message's CRC_EXTRA. The signature is not checked
    (checking it would take the frame's timestamp as seen)."""
    table, x25crc = dialect.mavlink_map, dialect.x25crc

    def check(frame: bytes) -> bool:
        v2 = frame[0] == MAGIC_V2
        if v2 and frame[2] & ~INCOMPAT_SIGNED:
            return False
        message = table.get(int.from_bytes(frame[7:10], "little") if v2 else frame[5])
        if message is None:
            return False
        end = len(frame) - 2 - (SIGNATURE_LEN if v2 and frame[2] & INCOMPAT_SIGNED else 0)
        crc = x25crc(bytearray(frame[1:end]) + bytes([message.crc_extra])).crc
        return crc == int.from_bytes(frame[end:end + 2], "little")

    return check


def next_whole_frame(data: bytes, check: Callable[[bytes], bool]) -> int | None:
    """The offset (> 0) of the first complete frame in ``data`` after its first byte that passes
    ``check`` (:func:`frame_check`); None when there is none."""
    for start in range(1, len(data)):
        magic = data[start]
        if magic not in (MAGIC_V2, MAGIC_V1) or start + 2 >= len(data):
            continue
        if magic == MAGIC_V2:
            length = data[start + 1] + V2_OVERHEAD + (SIGNATURE_LEN if data[start + 2] & INCOMPAT_SIGNED else 0)
        else:
            length = data[start + 1] + V1_OVERHEAD
        if start + length <= len(data) and check(data[start:start + length]):
            return start
    return None
