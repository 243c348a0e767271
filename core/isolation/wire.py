"""Framing of the channel between the fieldbus process and a child (sans-I/O).

A frame is a 4-byte big-endian length and that many bytes. The fieldbus process sends
pickles (:func:`down`); a child sends JSON objects (:func:`up`), which the fieldbus process
reads with a size limit and checks before it acts on them (:func:`read_up`): it never
unpickles what a child sends.
"""

from __future__ import annotations

import json
import pickle
import struct
from typing import Any

HEADER = struct.Struct(">I")
MAX_DOWN = 64 * 1024 * 1024  # a snapshot of a very large image still fits
MAX_UP = 4 * 1024 * 1024  # a child's status with every metric sample


class WireError(Exception):
    """The peer broke the framing (a frame over the limit, a frame that is not what it must
    be); the channel is closed."""


# the first byte of a frame to a child: the kind of message, readable without unpickling, so
# a child that fell behind skips the changes it will get again in a snapshot, cheaply
KINDS = {
    "init": 0,
    "chg": 1,
    "health": 2,
    "master": 3,
    "port": 4,
    "event": 5,
    "snap": 6,
    "ping": 7,
    "ack": 8,
    "gw": 9,
    "stop": 10,
    "ts": 11,
}
DATA_KINDS = frozenset(KINDS[k] for k in ("chg", "health", "master", "port", "event", "ts"))


def down(message: Any) -> bytes:
    """A message from the fieldbus process to a child (a tuple whose first item names its
    kind, or the ``init`` dict), framed: kind byte, then the pickle."""
    kind = KINDS["init"] if isinstance(message, dict) else KINDS[message[0]]
    body = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    return HEADER.pack(len(body) + 1) + bytes((kind,)) + body


def read_down(body: bytes) -> Any:
    """A frame's message, as :func:`down` made it (the child's side)."""
    return pickle.loads(body[1:])


def up(message: dict[str, Any]) -> bytes:
    """A message from a child to the fieldbus process, framed (JSON)."""
    body = json.dumps(message, separators=(",", ":"), allow_nan=False, default=str).encode()
    if len(body) > MAX_UP:
        raise WireError(f"message of {len(body)} bytes over the {MAX_UP}-byte limit")
    return HEADER.pack(len(body)) + body


def read_up(body: bytes) -> dict[str, Any]:
    """A child's message: a JSON object with a string ``t`` (WireError otherwise)."""
    try:
        message = json.loads(body)
    except (UnicodeDecodeError, ValueError) as exc:
        raise WireError(f"not JSON: {exc}") from None
    if not isinstance(message, dict) or not isinstance(message.get("t"), str):
        raise WireError("not a JSON object with a string 't'")
    return message


class FrameReader:
    """Bytes in, whole frames out; refuses a frame over ``limit`` from its header alone,
    before buffering its body."""

    def __init__(self, limit: int):
        self.limit = limit
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[bytes]:
        buffer = self._buffer
        buffer += data
        frames: list[bytes] = []
        start = 0
        while len(buffer) - start >= HEADER.size:
            (size,) = HEADER.unpack_from(buffer, start)
            if size > self.limit:
                raise WireError(f"frame of {size} bytes over the {self.limit}-byte limit")
            end = start + HEADER.size + size
            if len(buffer) < end:
                break
            frames.append(bytes(buffer[start + HEADER.size : end]))
            start = end
        if start:
            del buffer[:start]
        return frames

    @property
    def buffered(self) -> int:
        return len(self._buffer)
