"""DeviceNet fragmentation: acknowledged explicit fragments and unacknowledged I/O fragments.

Fragmentation byte: bits 7-6 type (00 first, 01 middle, 10 last, 11 ack), bits 5-0 a
rolling count (0 for the first fragment). Explicit fragments carry 6 payload bytes after
``[hdr|0x80][frag]``; I/O fragments carry 7 after ``[frag]`` (seed-003 §2.4/§2.5).
"""

from __future__ import annotations

FIRST, MIDDLE, LAST, ACK = 0x00, 0x40, 0x80, 0xC0
EXPLICIT_CHUNK = 6
IO_CHUNK = 7
ACK_OK = 0x00
ACK_TOO_MUCH = 0x01


def split(payload: bytes, chunk: int) -> list[tuple[int, bytes]]:
    """``[(fragment byte, data), ...]`` for a payload that does not fit one frame."""
    pieces = [payload[i : i + chunk] for i in range(0, len(payload), chunk)] or [b""]
    out = []
    for count, piece in enumerate(pieces):
        kind = FIRST if count == 0 else LAST if count == len(pieces) - 1 else MIDDLE
        out.append((kind | (count & 0x3F), piece))
    return out


def io_frames(payload: bytes) -> list[bytes]:
    """I/O message data: one frame up to 8 bytes, else fragments of 7 after a fragment byte."""
    if len(payload) <= 8:
        return [payload]
    return [bytes([frag]) + data for frag, data in split(payload, IO_CHUNK)]


class Reassembler:
    """Receiving side for one connection. ``feed`` returns ``(ack status or None, complete payload or None)``.

    Explicit fragments are acknowledged (``ack`` not None); I/O fragments are not.
    Duplicates of the previous count are re-acknowledged without being appended; a count
    out of sequence or a middle/last fragment without a first resets reassembly (dropped).
    """

    def __init__(self, limit: int):
        self.limit = limit
        self.buffer: bytearray | None = None
        self.count = 0
        self.errors = 0

    def reset(self) -> None:
        self.buffer = None

    def feed(self, frag: int, data: bytes) -> tuple[str, bytes | None]:
        """Returns ``(outcome, payload)``; outcome is ``ok``, ``duplicate``, ``overflow`` or ``dropped``."""
        kind, count = frag & 0xC0, frag & 0x3F
        if kind == FIRST:
            self.buffer, self.count = bytearray(), 0
        elif self.buffer is None or kind == ACK:
            self.errors += 1
            return "dropped", None
        elif count == self.count:
            return "duplicate", None
        elif count != (self.count + 1) & 0x3F:
            self.errors += 1
            self.buffer = None
            return "dropped", None
        self.count = count
        self.buffer += data
        if len(self.buffer) > self.limit:
            self.errors += 1
            self.buffer = None
            return "overflow", None
        if kind == LAST:
            payload, self.buffer = bytes(self.buffer), None
            return "ok", payload
        return "ok", None
