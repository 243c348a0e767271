"""TIME consumer (CiA 301 §7.2.6): 0x1012 COB-ID TIME and the TIME_OF_DAY frames it names.

* 0x1012 (U32, rw), default 0x80000100: bit 31 = consume, bit 30 = produce, CAN-ID in
  bits 0-10. Production is not supported: a value with bit 30 set aborts 0609 0030, and
  so do bit 29 (29-bit frames), bits 11-28, a restricted CAN-ID while consuming
  (:mod:`.cobid`) and a new CAN-ID while consumption is on and stays on (clear bit 31
  first, as Lely does).
* A consumed frame carries a TIME_OF_DAY: 4 bytes milliseconds after midnight (28 bits,
  the top 4 reserved and ignored), then a U16 of days since 1984-01-01. Frames of
  another length, RTR frames, and milliseconds of a day or more (>= 86 400 000) are
  counted and dropped. TIME is consumed in pre-operational and operational (CiA 301).
* :attr:`TimeConsumer.last` is the last time received (``datetime`` in UTC) or None;
  :meth:`TimeConsumer.current` adds the time elapsed since then on the node's clock;
  :meth:`TimeConsumer.on_time` calls a listener with every time received. Nothing
  raises an EMCY.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any

from canopen.objectdictionary import datatypes as dt

from fieldgate.can.frame import Frame

from . import abort
from .abort import SdoAbort
from .cobid import check_cob_id
from .service import NodeHost, Service

CONSUME_BIT = 1 << 31
PRODUCE_BIT = 1 << 30
DEFAULT_COB_ID = CONSUME_BIT | 0x100
EPOCH = datetime(1984, 1, 1, tzinfo=UTC)
MS_PER_DAY = 86_400_000
MS_MASK = 0x0FFF_FFFF

log = logging.getLogger("fieldgate.canopen.time")

TimeListener = Callable[[datetime], None]


def decode_time_of_day(data: bytes) -> datetime:
    """The UTC datetime in a 6-byte TIME_OF_DAY; ValueError for another length or ms >= one day."""
    if len(data) != 6:
        raise ValueError(f"TIME_OF_DAY has 6 bytes, not {len(data)}")
    ms = int.from_bytes(data[0:4], "little") & MS_MASK
    if ms >= MS_PER_DAY:
        raise ValueError(f"{ms} ms after midnight is not within a day")
    days = data[4] | (data[5] << 8)
    return EPOCH + timedelta(days=days, milliseconds=ms)


def encode_time_of_day(when: datetime) -> bytes:
    """The 6-byte TIME_OF_DAY of an aware datetime (rounded down to the millisecond)."""
    delta = when.astimezone(UTC) - EPOCH
    if not 0 <= delta.days <= 0xFFFF:
        raise ValueError(f"{when} is outside 1984-01-01 .. 2163-06-06")
    ms = delta.seconds * 1000 + delta.microseconds // 1000
    return ms.to_bytes(4, "little") + delta.days.to_bytes(2, "little")


class TimeConsumer(Service):
    name = "time"

    def __init__(self, cob_id: int = DEFAULT_COB_ID):
        super().__init__()
        self.default_cob_id = cob_id
        self.cob_id: int | None = None  # the CAN-ID consumed, None when bit 31 is clear
        self.last: datetime | None = None
        self.received_at: float | None = None  # node time (monotonic seconds) of the last reception
        self._listeners: list[TimeListener] = []

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        node.od.add_variable(0x1012, "COB-ID TIME", dt.UNSIGNED32, "rw", self.default_cob_id)
        node.od.add_validator(0x1012, self._check)
        node.od.on_write(0x1012, lambda *_: self._load())
        self._load()

    def _load(self) -> None:
        value = self.node.od.integer(0x1012)
        self.cob_id = value & 0x7FF if value & CONSUME_BIT else None

    def on_reset_communication(self, now: float) -> None:
        self._load()

    # -- API ---------------------------------------------------------------------------------
    def on_time(self, listener: TimeListener) -> None:
        """Call ``listener(datetime)`` with every TIME received (on the engine's thread)."""
        self._listeners.append(listener)

    def current(self, now: float | None = None) -> datetime | None:
        """The network time at ``now`` (the adapter's clock, ``loop.time()``): the last TIME plus the
        time elapsed since it arrived; None before one. Without ``now``: the node's last step."""
        if self.last is None or self.received_at is None:
            return None
        elapsed = (self.node.now if now is None else now) - self.received_at
        return self.last + timedelta(seconds=max(0.0, elapsed))

    # -- frames ------------------------------------------------------------------------------
    def listen_ids(self) -> tuple[int, ...]:
        return () if self.cob_id is None else (self.cob_id,)

    def on_frame(self, frame: Frame, now: float) -> bool:
        if frame.can_id != self.cob_id:
            return False
        if frame.rtr:
            self.counters["rtr_dropped"] += 1
            return True
        try:
            when = decode_time_of_day(bytes(frame.data))
        except ValueError:
            self.counters["bad_length" if len(frame.data) != 6 else "bad_value"] += 1
            return True
        self.counters["received"] += 1
        self.last, self.received_at = when, now
        for listener in list(self._listeners):
            try:
                listener(when)
            except Exception:
                self.counters["listener_errors"] += 1
                log.exception("%s: TIME listener failed", self.node.name)
        return True

    # -- write check -------------------------------------------------------------------------
    def _check(self, sub: int, value: int) -> None:
        if value & PRODUCE_BIT:
            raise SdoAbort(abort.VALUE_RANGE, "TIME production (0x1012 bit 30) is not supported")
        consume = bool(value & CONSUME_BIT)
        can_id = check_cob_id(value, "TIME", in_use=consume)
        old = self.node.od.integer(0x1012)
        if consume and old & CONSUME_BIT and (old & 0x7FF) != can_id:
            raise SdoAbort(
                abort.VALUE_RANGE, "clear bit 31 of 0x1012 before changing the TIME CAN-ID"
            )

    def status(self) -> dict[str, Any]:
        return {**self.counters, "consuming": self.cob_id is not None, "last": self.last}
