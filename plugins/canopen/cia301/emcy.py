"""EMCY producer: 0x1001 error register, 0x1003 history, 0x1014 COB-ID, 0x1015 inhibit.

API for every other part of the front (PDO engine, CiA 401, module health)::

    node.emcy.raise_error(0x8210, 0x11, b"\\x09")   # one EMCY per *new* error
    node.emcy.clear_error(0x8210)                  # error reset EMCY when the last clears
    node.emcy.clear_errors([(0x8130, b"\\x07"), (0x8140, b"\\x08")])  # several at once: one EMCY

An error is identified by its code and manufacturer bytes (two module failures with
code 0xFF00 are two errors). Raising an active error again sends nothing. When an
error clears and others remain, an EMCY 0x0000 carrying the remaining error register
is sent; when the last clears, the all-zero reset; errors cleared together by
``clear_errors`` give one such EMCY. Every EMCY produced is recorded in
0x1003 (newest at sub 1; the value is the code plus manufacturer bytes 3-4 in bits
16-31, as the I-7232D stores it), including resets (value 0). Writing 0 to 0x1003:0
clears the history, any other write aborts 0609 0030.

0x1015 inhibit time is in units of 100 us (CiA 301): EMCYs produced within the
inhibit time are queued (at most ``queue_limit``, 16 by default, 20 in the NA-9161
style) and sent when it elapses. A full queue drops its oldest EMCY and calls
``on_overflow(now)``: the front's CAN health reports a software Tx overrun with an EMCY
sent at once, ahead of the queue (``raise_error(..., urgent=True)``; the NA-9161's "an
overflow EMCY is sent at once"). EMCYs are sent only in pre-operational and operational
(CiA 301); 0x1014 bit 31 set disables them. Errors and history are kept in every state.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from functools import partial
from typing import Any

from canopen.objectdictionary import datatypes as dt

from fieldgate.can.frame import Frame

from . import abort
from .abort import SdoAbort
from .cobid import check_cob_id
from .nmt import NmtState
from .service import ALL_STATES, COMMUNICATING, NodeHost, Service

GENERIC = 0x01
COMMUNICATION = 0x10
MANUFACTURER = 0x80
QUEUE_LIMIT = 16
COB_ID_INVALID = 1 << 31


def history_value(code: int, manufacturer: bytes) -> int:
    m = manufacturer.ljust(2, b"\x00")
    return (code & 0xFFFF) | (m[0] << 16) | (m[1] << 24)


class EmcyProducer(Service):
    name = "emcy"
    is_emcy_producer = True
    active_states = ALL_STATES

    def __init__(self, history_depth: int = 5, queue_limit: int = QUEUE_LIMIT):
        super().__init__()
        if history_depth < 1 or history_depth > 254:
            raise ValueError("EMCY history depth must be 1..254")
        if queue_limit < 1:
            raise ValueError("the EMCY queue holds at least one EMCY")
        self.depth = history_depth
        self.queue_limit = queue_limit
        self.on_overflow: Callable[[float], None] | None = None  # the queue dropped an EMCY
        self.active: dict[tuple[int, bytes], int] = {}  # (code, manufacturer) -> register bits
        self.history: deque[int] = deque(maxlen=history_depth)
        self._queue: deque[Frame] = deque()
        self._last_sent: float | None = None
        self.on_sent: Callable[[Frame], None] | None = None  # the front publishes an event

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        od = node.od
        od.add_variable(0x1001, "Error register", dt.UNSIGNED8, "ro", 0)
        od.bind(0x1001, 0, getter=lambda: self.register, thread_safe=True)
        od.add_array(
            0x1003,
            "Pre-defined error field",
            [
                (i, f"Standard error field {i}", dt.UNSIGNED32, "ro", 0)
                for i in range(1, self.depth + 1)
            ],
        )
        od.variable(0x1003, 0).access_type = "rw"
        od.bind(
            0x1003,
            0,
            getter=lambda: len(self.history),
            setter=self._write_history_count,
            thread_safe=True,
        )
        od.add_validator(0x1003, self._check_history_write)
        for sub in range(1, self.depth + 1):
            od.bind(0x1003, sub, getter=partial(self._history_entry, sub), thread_safe=True)
        od.add_variable(0x1014, "COB-ID EMCY", dt.UNSIGNED32, "rw", 0x80, relative=True)
        od.add_validator(0x1014, self._check_cob_id)
        od.add_variable(0x1015, "Inhibit time EMCY", dt.UNSIGNED16, "rw", 0)

    # -- API ---------------------------------------------------------------------------
    @property
    def register(self) -> int:
        active = tuple(self.active.values())  # one snapshot: the receive thread reads 0x1001 too
        bits = 0
        for b in active:
            bits |= b
        return (bits | GENERIC) if active else 0

    def raise_error(
        self,
        code: int,
        register_bits: int = GENERIC,
        manufacturer: bytes = b"",
        now: float | None = None,
        *,
        urgent: bool = False,
    ) -> bool:
        """Record a new error and send its EMCY. False (and no frame) if already active.
        ``urgent``: sent at once, ahead of the queue and the inhibit time (an overflow report)."""
        manufacturer = bytes(manufacturer[:5])
        key = (code & 0xFFFF, manufacturer)
        if key in self.active:
            self.counters["repeated"] += 1
            return False
        self.active[key] = register_bits & 0xFF
        self._produce(code, manufacturer, now, urgent=urgent)
        return True

    def clear_error(
        self, code: int, manufacturer: bytes | None = None, now: float | None = None
    ) -> bool:
        """Clear an active error (every error with ``code`` if ``manufacturer`` is None)."""
        keys = [
            k
            for k in self.active
            if k[0] == code and (manufacturer is None or k[1] == bytes(manufacturer[:5]))
        ]
        return self._clear(keys, now) > 0

    def clear_errors(self, errors: Iterable[tuple[int, bytes]], now: float | None = None) -> int:
        """Clear several errors that end together (``(code, manufacturer)`` pairs; inactive
        ones are skipped) with *one* error-reset EMCY. Returns how many were active."""
        keys = [
            k
            for k in dict.fromkeys((code & 0xFFFF, bytes(m[:5])) for code, m in errors)
            if k in self.active
        ]
        return self._clear(keys, now)

    def _clear(self, keys: list[tuple[int, bytes]], now: float | None) -> int:
        for k in keys:
            del self.active[k]
        if keys:
            self._produce(0x0000, b"", now)
        return len(keys)

    def signal(
        self,
        code: int,
        register: int,
        manufacturer: bytes = b"",
        now: float | None = None,
        *,
        record: bool = True,
    ) -> None:
        """Send a one-off event EMCY that does not stay active, e.g. the I-7232D's ``00 FF 80
        0A`` on an NMT reset request; ``register`` is sent as given. ``record``: also in 0x1003
        (False for an announcement that is no error, the NA-9161's power-on on defaults)."""
        self._produce(code, bytes(manufacturer[:5]), now, register, record=record)

    def is_active(self, code: int) -> bool:
        return any(k[0] == code for k in self.active)

    # -- producing ------------------------------------------------------------------------
    def _produce(
        self,
        code: int,
        manufacturer: bytes,
        now: float | None,
        register: int | None = None,
        *,
        urgent: bool = False,
        record: bool = True,
    ) -> None:
        now = self.node.now if now is None else now
        if record:
            self.history.appendleft(history_value(code, manufacturer))
        register = self.register if register is None else register & 0xFF
        data = code.to_bytes(2, "little") + bytes([register]) + manufacturer.ljust(5, b"\x00")
        cob = self.node.od.integer(0x1014)
        if cob & COB_ID_INVALID:
            self.counters["disabled"] += 1
            return
        if self.node.state not in COMMUNICATING:
            self.counters["suppressed_by_state"] += 1
            return
        frame = Frame(cob & 0x7FF, data)
        if urgent:
            self._transmit(frame, now)
            return
        overflow = len(self._queue) >= self.queue_limit
        if overflow:
            self._queue.popleft()
            self.counters["queue_overflow"] += 1
        self._queue.append(frame)
        if overflow and self.on_overflow is not None:
            self.on_overflow(now)
        self._flush(now)

    @property
    def queued(self) -> int:
        return len(self._queue)

    def _inhibit(self) -> float:
        return self.node.od.integer(0x1015) * 100e-6

    def _flush(self, now: float) -> None:
        while self._queue and (self._last_sent is None or now >= self._last_sent + self._inhibit()):
            self._transmit(self._queue.popleft(), now)

    def _transmit(self, frame: Frame, now: float) -> None:
        self.node.send(frame)
        self.counters["sent"] += 1
        self._last_sent = now
        if self.on_sent is not None:
            self.on_sent(frame)

    def deadline(self) -> float | None:
        if not self._queue or self._last_sent is None:
            return None
        return self._last_sent + self._inhibit()

    def poll(self, now: float) -> None:
        self._flush(now)

    def on_nmt_state(self, old: NmtState, new: NmtState, now: float) -> None:
        if new not in COMMUNICATING:
            self._queue.clear()

    # -- 0x1003 / 0x1014 -----------------------------------------------------------------
    def _history_entry(self, sub: int) -> int:
        if sub > len(self.history):
            raise SdoAbort(abort.NO_DATA, "no error recorded at this sub-index")
        return self.history[sub - 1]

    def _check_history_write(self, sub: int, value: int) -> None:
        if sub != 0 or value != 0:
            raise SdoAbort(abort.VALUE_RANGE, "only 0 may be written to 0x1003:0")

    def _write_history_count(self, value: int) -> None:
        self.history.clear()

    def _check_cob_id(self, sub: int, value: int) -> None:
        check_cob_id(value, "EMCY", in_use=not value & COB_ID_INVALID)
        old = self.node.od.integer(0x1014)
        if (
            not (old & COB_ID_INVALID)
            and not (value & COB_ID_INVALID)
            and (old & 0x7FF) != (value & 0x7FF)
        ):
            raise SdoAbort(abort.VALUE_RANGE, "set bit 31 before changing the EMCY COB-ID")

    def status(self) -> dict[str, Any]:
        return {
            **self.counters,
            "queued": len(self._queue),
            "queue_limit": self.queue_limit,
            "error_register": self.register,
            "active": [f"{c:04X}:{m.hex()}" for c, m in self.active],
        }
