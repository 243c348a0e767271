"""Modbus TCP framing and a connection's limits, without I/O: fed bytes and the time.

An MBAP header (Modbus Messaging on TCP/IP Implementation Guide V1.0b, section 3.1.3) is 7
bytes: transaction id, protocol id (0 for Modbus), length (the bytes that follow it: the
unit id and a PDU of 1 to 253 bytes, so 2 to 254), unit id. A header with another protocol
id or a length outside 2-254 leaves no way to find where the next frame starts: the
connection is closed (``MALFORMED``), checked as soon as the header's 7 bytes are in. The
receive buffer is one frame of the largest size (260 bytes), whatever a header says, so a
client can make a connection hold at most that plus ``max_pending`` decoded requests.

:class:`MbapConnection` is one client connection: the adapter (:mod:`.server`) reads into
:meth:`~MbapConnection.buffer`, reports the bytes with :meth:`~MbapConnection.received`,
takes requests with :meth:`~MbapConnection.next_frame`, reports each answer sent with
:meth:`~MbapConnection.served`, and calls :meth:`~MbapConnection.expire` at
:meth:`~MbapConnection.deadline`. :func:`admit` is the admission rule of a server.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

HEADER = 7
MIN_LENGTH, MAX_LENGTH = 2, 254  # unit id + PDU (function code + at most 252 bytes of data)
MAX_FRAME = 6 + MAX_LENGTH

MALFORMED = "malformed"  # reasons a connection is closed (the counters' names)
IDLE = "idle_timeout"
REQUEST_TIMEOUT = "request_timeout"

_HEADER = struct.Struct(">HHHB")


@dataclass(frozen=True)
class Limits:
    """A connection's limits (their defaults are the front's settings, config.py)."""

    idle_timeout: float  # no request for this long: closed
    request_timeout: float  # a frame begun must be complete within this
    max_pending: int  # requests decoded ahead of their answers


@dataclass(frozen=True, slots=True)
class Frame:
    tid: int
    unit: int
    pdu: bytes  # function code first; at least 1 byte


def answer(frame: Frame, pdu: bytes) -> bytes:
    """The MBAP frame that carries ``pdu`` as the answer to ``frame``."""
    return _HEADER.pack(frame.tid, 0, len(pdu) + 1, frame.unit) + pdu


class MbapConnection:
    """The framing state and timers of one connection (module docstring)."""

    def __init__(self, limits: Limits, now: float):
        self.limits = limits
        self._buffer = bytearray(MAX_FRAME)
        self._view = memoryview(self._buffer)
        self._fill = 0
        self._pending: deque[Frame] = deque()
        self.in_progress = 0  # taken by next_frame, not yet served
        self.last_activity = now  # a request received or answered (or the connection made)
        self.frame_started: float | None = None  # the first byte of an incomplete frame
        self.close_reason: str | None = None
        self.requests = 0

    # -- input ---------------------------------------------------------------------------
    def buffer(self) -> memoryview:
        """Where the next bytes go (never empty while reading is wanted)."""
        return self._view[self._fill :]

    def received(self, n: int, now: float) -> None:
        """``n`` bytes were written into :meth:`buffer`."""
        if n <= 0 or self.close_reason is not None:
            return
        if self._fill == 0:
            self.frame_started = now
        self._fill += n
        self._parse(now)

    def _parse(self, now: float) -> None:
        buf, fill, start = self._buffer, self._fill, 0
        room = self.limits.max_pending - len(self._pending) - self.in_progress
        while room > 0 and fill - start >= HEADER:
            tid, protocol, length, unit = _HEADER.unpack_from(buf, start)
            if protocol != 0 or not MIN_LENGTH <= length <= MAX_LENGTH:
                self.close_reason = MALFORMED
                self._fill = 0
                self.frame_started = None
                return
            end = start + 6 + length
            if end > fill:
                break
            self._pending.append(Frame(tid, unit, bytes(buf[start + HEADER : end])))
            self.requests += 1
            self.last_activity = now
            start = end
            room -= 1
        if start:
            rest = fill - start
            buf[:rest] = buf[start:fill]
            self._fill = rest
            self.frame_started = now if rest else None

    @property
    def wants_reading(self) -> bool:
        """False while ``max_pending`` requests wait (the rest stays in the socket)."""
        return (
            self.close_reason is None
            and len(self._pending) + self.in_progress < self.limits.max_pending
        )

    # -- requests ------------------------------------------------------------------------
    def next_frame(self) -> Frame | None:
        if self.close_reason is not None or not self._pending:
            return None
        self.in_progress += 1
        return self._pending.popleft()

    def served(self, now: float) -> None:
        """The answer to a frame taken with :meth:`next_frame` was sent."""
        self.in_progress -= 1
        self.last_activity = now
        self._parse(now)  # a frame that waited for room in the queue

    @property
    def pending(self) -> int:
        return len(self._pending) + self.in_progress

    # -- timers --------------------------------------------------------------------------
    def _incomplete(self) -> bool:
        """Bytes of a frame that has not all arrived (not one that waits for room)."""
        if self._fill == 0:
            return False
        if self._fill < HEADER:
            return True
        length: int = _HEADER.unpack_from(self._buffer)[2]
        return self._fill < 6 + length

    def deadline(self) -> float | None:
        """When :meth:`expire` has something to do; None: no timer (a request is being
        served: the gateway's own time is not the client's fault)."""
        if self.close_reason is not None or self.in_progress:
            return None
        idle = self.last_activity + self.limits.idle_timeout
        if self.frame_started is not None and self._incomplete():
            return min(idle, self.frame_started + self.limits.request_timeout)
        return idle

    def expire(self, now: float) -> str | None:
        """The reason to close the connection now, if a timer ran out."""
        deadline = self.deadline()
        if deadline is None or now < deadline:
            return None
        started = self.frame_started
        timed_out = started is not None and now >= started + self.limits.request_timeout
        self.close_reason = REQUEST_TIMEOUT if timed_out and self._incomplete() else IDLE
        return self.close_reason

    def idle_since(self) -> float | None:
        """For admission: since when it waits for its client, None while a request is served."""
        return None if self.in_progress or self.close_reason else self.last_activity


class Admitted(Protocol):
    """What :func:`admit` needs of an open connection."""

    @property
    def peer(self) -> str: ...

    @property
    def engine(self) -> MbapConnection: ...


C = TypeVar("C", bound=Admitted)


def admit(peer: str, open_now: Sequence[C], max_total: int, max_per_peer: int) -> list[C] | None:
    """The connections to close so that a new one from ``peer`` fits, or None: refuse it.

    Over ``max_per_peer``, that peer's longest-idle connection goes; then over ``max_total``,
    the longest-idle of all. Idle: no request in progress (a silent socket, a half-sent
    frame, a client that does not read its answers), longest since its last request or
    answer. A connection whose request is being served is never closed for another.
    """
    evict: list[C] = []
    mine = [c for c in open_now if c.peer == peer]
    if len(mine) >= max_per_peer:
        victim = _longest_idle(mine)
        if victim is None:
            return None
        evict.append(victim)
    if len(open_now) - len(evict) >= max_total:
        victim = _longest_idle([c for c in open_now if c not in evict])
        if victim is None:
            return None
        evict.append(victim)
    return evict


def _longest_idle(candidates: Sequence[C]) -> C | None:
    best, since = None, 0.0
    for conn in candidates:
        idle = conn.engine.idle_since()
        if idle is not None and (best is None or idle < since):
            best, since = conn, idle
    return best
