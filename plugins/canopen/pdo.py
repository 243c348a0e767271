"""PDO engine (CiA 301 §7.2.2), sans-I/O.

Feed it what happens and it returns the frames to send, as ``(can_id, data)`` tuples:

* :meth:`PdoEngine.on_frame` ``(can_id, data, now, rtr=False)`` -- an RPDO, or a remote
  request for a TPDO;
* :meth:`PdoEngine.on_sync` ``(now, counter=None)`` -- a SYNC (``counter`` is the SYNC
  counter byte when 0x1019 is used);
* :meth:`PdoEngine.set_operational` ``(flag, now)`` -- NMT state changes; PDOs live only
  in Operational;
* :meth:`PdoEngine.on_timer` ``(now)`` -- when :meth:`PdoEngine.next_deadline` is due
  (event timers, transmissions held back by the inhibit time);
* :meth:`PdoEngine.object_changed` ``(index, sub, now)`` -- an application event on a
  mapped object (the CiA 401 profile calls it from process-image subscriptions). Frames
  it produces outside one of the calls above wait in the outbox; ``wakeup`` is called so
  the adapter can :meth:`PdoEngine.take_frames` and re-read the deadline.

The communication and mapping parameters (0x1400-, 0x1600-, 0x1800-, 0x1A00-) are
:class:`~.entries.ObjectDef` records from :meth:`PdoEngine.objects`, with the write rules
of CiA 301: a COB-ID changes only while the PDO is invalid, mapping entries only while
sub 0 is 0, sub 0 checks every entry (exists, mappable in this direction, whole bytes,
total <= 64 bits). Reserved transmission types are refused (0609 0030).

Mapping granularity: with ``granularity=8`` (the default, what the seeds' masters expect)
every entry is whole bytes; with ``granularity=1`` 1-bit BOOLEAN entries (CiA 401
0x6020-/0x6220-) pack bit after bit, LSB first, as CiA 301 lays out PDO data. RPDOs may
map CiA 301 dummy entries (index 0x0001-0x0007, sub 0, the data type's length) to skip
bits nobody uses; 0x0001 (1 bit) only with granularity 1; TPDOs refuse them (0604 0041).

Transmission types (seed-000 §2.7): 0 acyclic synchronous (on SYNC, only after an event),
1-240 every n-th SYNC (from the SYNC start value when SYNC counters are used), 252 sampled
at SYNC and sent on RTR, 253 sent on RTR, 254/255 on events and the event timer. RPDOs
of types 0-240 act at the next SYNC, 254/255 at once. An RPDO shorter than its mapping
is ignored and reported through ``length_error(True)`` (EMCY 0x8210); the next good one
reports ``length_error(False)``. Longer RPDOs use their first bytes.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Literal

from .abort import DEVICE_STATE, NOT_MAPPABLE, PDO_TOO_LONG, VALUE_RANGE
from .cobid import check_cob_id
from .entries import (
    BOOLEAN,
    UNSIGNED8,
    UNSIGNED16,
    UNSIGNED32,
    Abort,
    Directory,
    Entry,
    ObjectDef,
    count_entry,
    decode,
    encode,
)
from .layouts import COB_INVALID, PdoDefault

log = logging.getLogger("fieldgate.canopen.pdo")

Frame = tuple[int, bytes]

COB_NO_RTR = 1 << 30
MAX_ENTRIES = 8
MAX_BITS = 64
MAX_PDOS = 512
RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00
DUMMY_BITS = {0x0001: 1, 0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}


def dummy_types(granularity: int) -> list[int]:
    """The dummy entries (CiA 301 data type indices) an RPDO of this granularity may map."""
    return [index for index, bits in DUMMY_BITS.items() if bits % granularity == 0]


# CiA 301 §7.3.5: identifiers a PDO may not use.
def _sync_type(t: int) -> bool:
    return t <= 240


def _async_type(t: int) -> bool:
    return t >= 254


def _map_entry(pdo: Pdo, position: int) -> int:
    return pdo.map_entries[position]  # read when asked: a remap replaces the list


@dataclass
class _Slot:
    """One mapped object, compiled for fast packing; ``entry`` None: a dummy entry."""

    index: int
    sub: int
    entry: Entry | None
    bits: int

    @property
    def size(self) -> int:
        return self.bits // 8


@dataclass
class Pdo:
    number: int  # 1-based
    transmit: bool
    default: PdoDefault
    cob_id: int = COB_INVALID
    trans_type: int = 255
    inhibit: int = 0  # 100 us
    event_timer: int = 0  # ms
    sync_start: int = 0
    map_count: int = 0
    map_entries: list[int] = field(default_factory=lambda: [0] * MAX_ENTRIES)
    slots: list[_Slot] = field(default_factory=list)
    # run-time state
    sync_count: int = 0
    waiting_start: bool = False
    sync_event: bool = False  # type 0: an event since the last transmission
    pending: bool = False  # an event held back by the inhibit time
    next_allowed: float = float("-inf")
    timer_due: float | None = None
    sample: bytes | None = None  # data sampled at the last SYNC
    latched: bytes | None = None  # RPDO data waiting for the next SYNC
    _aligned_for: list[_Slot] | None = field(default=None, repr=False)
    _aligned: bool = field(default=True, repr=False)

    @property
    def comm_index(self) -> int:
        return (TPDO_COMM if self.transmit else RPDO_COMM) + self.number - 1

    @property
    def map_index(self) -> int:
        return (TPDO_MAP if self.transmit else RPDO_MAP) + self.number - 1

    @property
    def valid(self) -> bool:
        return not self.cob_id & COB_INVALID

    @property
    def can_id(self) -> int:
        return self.cob_id & 0x7FF

    @property
    def rtr_allowed(self) -> bool:
        return not self.cob_id & COB_NO_RTR

    @property
    def length(self) -> int:
        """Bytes the mapping fills (the last one padded with zero bits)."""
        return (sum(s.bits for s in self.slots) + 7) // 8

    @property
    def aligned(self) -> bool:
        """Every entry whole bytes (the fast path); computed once per mapping."""
        if self._aligned_for is not self.slots:
            self._aligned_for = self.slots
            self._aligned = all(s.bits % 8 == 0 for s in self.slots)
        return self._aligned

    def clear_runtime(self) -> None:
        self.sync_count = 0
        self.waiting_start = self.sync_start != 0
        self.sync_event = self.pending = False
        self.next_allowed = float("-inf")
        self.timer_due = None
        self.latched = None


@dataclass
class PdoCounters:
    rpdo_received: int = 0
    rpdo_too_short: int = 0
    rpdo_write_refused: int = 0
    tpdo_sent: int = 0
    rtr_answered: int = 0
    frames_ignored: int = (
        0  # a remote request for an RPDO, or data on a TPDO's COB-ID (another node's?)
    )


class PdoEngine:
    def __init__(
        self,
        directory: Directory,
        tpdo_defaults: list[PdoDefault],
        rpdo_defaults: list[PdoDefault],
        node_id: int,
        *,
        start_policy: Literal["async", "all", "none"] = "async",
        rpdo_timing: bool = False,
        clock: Callable[[], float] = time.monotonic,
        length_error: Callable[[bool], None] | None = None,
        wakeup: Callable[[], None] | None = None,
        exists: Callable[[int, int], bool] | None = None,
        granularity: int = 8,
    ):
        if granularity not in (1, 8):
            raise ValueError("mapping granularity 1 (bits) or 8 (bytes)")
        self.granularity = granularity
        if not 1 <= len(tpdo_defaults) <= MAX_PDOS or not 1 <= len(rpdo_defaults) <= MAX_PDOS:
            raise ValueError(f"1 to {MAX_PDOS} PDOs per direction")
        self.directory = directory
        self.node_id = node_id
        self.start_policy = start_policy
        self.rpdo_timing = rpdo_timing
        self.clock = clock
        self.length_error = length_error
        self.wakeup = wakeup
        self.exists = exists  # other objects of the node: mapping them is 0604 0041, not 0602 0000
        self.tpdos = [Pdo(n + 1, True, d) for n, d in enumerate(tpdo_defaults)]
        self.rpdos = [Pdo(n + 1, False, d) for n, d in enumerate(rpdo_defaults)]
        self.operational = False
        self.length_error_active = False
        self.counters = PdoCounters()
        self._outbox: list[Frame] = []
        self._depth = 0
        self._rx: dict[int, Pdo] = {}
        self._rtr: dict[int, Pdo] = {}
        self._timed: list[Pdo] = []
        self._events: dict[tuple[int, int], list[Pdo]] = {}
        self._queued: dict[int, Pdo] = {}
        self._queued_at: float | None = None
        self._now = 0.0
        self.reset()

    # -- life cycle ---------------------------------------------------------------
    def reset(self, node_id: int | None = None) -> None:
        """Reset communication: every parameter back to its default (for ``node_id``)."""
        if node_id is not None:
            self.node_id = node_id
        for pdo in self.tpdos + self.rpdos:
            d = pdo.default
            pdo.cob_id = d.cob_id(self.node_id)
            pdo.trans_type, pdo.inhibit, pdo.event_timer, pdo.sync_start = (
                d.trans_type,
                d.inhibit,
                d.event_timer,
                0,
            )
            pdo.map_entries = (list(d.entries) + [0] * MAX_ENTRIES)[:MAX_ENTRIES]
            pdo.map_count = len(d.entries)
            pdo.slots = self._compile(pdo, pdo.map_entries[: pdo.map_count])
            pdo.sample = None
            pdo.clear_runtime()
        self.operational = False
        self.length_error_active = False
        self._queued, self._queued_at = {}, None
        self._reindex()

    def set_operational(self, operational: bool, now: float) -> list[Frame]:
        with self._call(now):
            if operational and not self.operational:
                self.operational = True
                for pdo in self.tpdos + self.rpdos:
                    pdo.clear_runtime()
                    self._arm_timer(pdo, now)
                for pdo in self.tpdos:
                    if pdo.valid and pdo.slots and self._sent_on_start(pdo):
                        self._send(pdo, now)
            elif not operational and self.operational:
                self.operational = False
                self._queued, self._queued_at = {}, None
                for pdo in self.tpdos + self.rpdos:
                    pdo.clear_runtime()
        return self.take_frames()

    def _sent_on_start(self, pdo: Pdo) -> bool:
        if self.start_policy == "all":
            return pdo.trans_type not in (252, 253)
        return self.start_policy == "async" and _async_type(pdo.trans_type)

    # -- inputs ---------------------------------------------------------------------
    def on_frame(self, can_id: int, data: bytes, now: float, rtr: bool = False) -> list[Frame]:
        with self._call(now):
            if self.operational:
                if rtr:
                    pdo = self._rtr.get(can_id)
                    if pdo is not None:
                        data_out = (
                            pdo.sample
                            if pdo.trans_type == 252 and pdo.sample is not None
                            else self._build(pdo)
                        )
                        self._outbox.append((pdo.can_id, data_out))
                        self.counters.rtr_answered += 1
                    else:
                        self.counters.frames_ignored += 1
                else:
                    pdo = self._rx.get(can_id)
                    if pdo is not None:
                        self._receive(pdo, bytes(data))
                    else:
                        self.counters.frames_ignored += 1
        return self.take_frames()

    def on_sync(self, now: float, counter: int | None = None) -> list[Frame]:
        with self._call(now):
            if self.operational:
                for pdo in self.tpdos:
                    if pdo.valid and pdo.trans_type <= 252:
                        self._sync_tpdo(pdo, now, counter)
                for pdo in self.rpdos:
                    if pdo.latched is not None:
                        data, pdo.latched = pdo.latched, None
                        self._apply(pdo, data)
        return self.take_frames()

    def object_changed(self, index: int, sub: int, now: float) -> None:
        """An application event on (index, sub): queues the TPDOs that map it.

        Events are coalesced: inside an engine call they are handled when the call
        ends (one RPDO writing 8 DO bits that loop back gives one TPDO), outside they
        wait for the next :meth:`on_timer` (their deadline is ``now``), so a back
        updating several channels in one go also gives one TPDO.
        """
        pdos = self._events.get((index, sub))
        if not pdos or not self.operational:
            return
        if self._queued_at is None:
            self._queued_at = now
        for pdo in pdos:
            self._queued.setdefault(pdo.number, pdo)
        if self._depth == 0 and self.wakeup is not None:
            self.wakeup()

    def _run_queued(self, now: float) -> None:
        queued, self._queued, self._queued_at = self._queued, {}, None
        for pdo in queued.values():
            self._event(pdo, now)

    def on_timer(self, now: float) -> list[Frame]:
        with self._call(now):
            if self.operational:
                self._run_queued(now)
                for pdo in self._timed:
                    if pdo.pending and now >= pdo.next_allowed:
                        self._send(pdo, now)
                    elif pdo.timer_due is not None and now >= pdo.timer_due:
                        pdo.timer_due = None
                        self._event(pdo, now)
        return self.take_frames()

    def next_deadline(self) -> float | None:
        if not self.operational:
            return None
        times = [p.next_allowed for p in self._timed if p.pending] + [
            p.timer_due for p in self._timed if p.timer_due is not None
        ]
        if self._queued_at is not None:
            times.append(self._queued_at)
        return min(times) if times else None

    def take_frames(self) -> list[Frame]:
        frames, self._outbox = self._outbox, []
        return frames

    def listen_ids(self) -> set[int]:
        """CAN identifiers the engine wants: valid RPDOs and RTR-enabled valid TPDOs."""
        return set(self._rx) | set(self._rtr)

    def listens_to(self, can_id: int) -> bool:
        """``can_id in listen_ids()`` without building the set (once per received frame)."""
        return can_id in self._rx or can_id in self._rtr

    # -- behaviour ------------------------------------------------------------------
    class _CallGuard:
        def __init__(self, engine: PdoEngine):
            self.engine = engine

        def __enter__(self) -> None:
            self.engine._depth += 1

        def __exit__(self, *exc: object) -> bool:
            engine = self.engine
            if exc[0] is None and engine._depth == 1 and engine._queued and engine.operational:
                try:
                    engine._run_queued(engine._now)
                except Exception:
                    log.exception("PDO engine error (dropped)")
            engine._depth -= 1
            if exc[0] is not None and not isinstance(exc[1], (KeyboardInterrupt, SystemExit)):
                log.exception("PDO engine error (dropped)", exc_info=exc)  # type: ignore[arg-type]
                return True
            return False

    def _call(self, now: float) -> PdoEngine._CallGuard:
        if self._depth == 0:
            self._now = now
        return PdoEngine._CallGuard(self)

    def _build(self, pdo: Pdo) -> bytes:
        if pdo.aligned:
            return b"".join(
                bytes(s.size) if s.entry is None else encode(s.entry.dtype, s.entry.get())
                for s in pdo.slots
            )
        packed, offset = 0, 0
        for s in pdo.slots:
            if s.entry is not None:
                raw = int.from_bytes(encode(s.entry.dtype, s.entry.get()), "little")
                packed |= (raw & ((1 << s.bits) - 1)) << offset
            offset += s.bits
        return packed.to_bytes(pdo.length, "little")

    def _send(self, pdo: Pdo, now: float, data: bytes | None = None) -> None:
        self._outbox.append((pdo.can_id, self._build(pdo) if data is None else data))
        self.counters.tpdo_sent += 1
        pdo.pending = pdo.sync_event = False
        pdo.next_allowed = now + pdo.inhibit * 1e-4
        self._arm_timer(pdo, now)

    def _arm_timer(self, pdo: Pdo, now: float) -> None:
        active = (
            pdo.transmit
            and self.operational
            and pdo.valid
            and pdo.event_timer
            and _async_type(pdo.trans_type)
        )
        pdo.timer_due = now + pdo.event_timer / 1000 if active else None

    def _event(self, pdo: Pdo, now: float) -> None:
        if not self.operational or not pdo.valid:
            return
        if pdo.trans_type == 0:
            pdo.sync_event = True
        elif _async_type(pdo.trans_type):
            if now >= pdo.next_allowed:
                self._send(pdo, now)
            else:
                pdo.pending = True

    def _sync_tpdo(self, pdo: Pdo, now: float, counter: int | None) -> None:
        pdo.sample = self._build(pdo)
        t = pdo.trans_type
        if t == 0:
            if pdo.sync_event:
                self._send(pdo, now, pdo.sample)
        elif t <= 240:
            if pdo.waiting_start and counter is not None:
                if counter != pdo.sync_start:
                    return
                pdo.waiting_start = False
                pdo.sync_count = 0
                self._send(pdo, now, pdo.sample)
                return
            pdo.sync_count += 1
            if pdo.sync_count >= t:
                pdo.sync_count = 0
                self._send(pdo, now, pdo.sample)

    def _receive(self, pdo: Pdo, data: bytes) -> None:
        self.counters.rpdo_received += 1
        if len(data) < pdo.length:
            self.counters.rpdo_too_short += 1
            if not self.length_error_active:
                self.length_error_active = True
                if self.length_error is not None:
                    self.length_error(True)
            return
        if self.length_error_active:
            self.length_error_active = False
            if self.length_error is not None:
                self.length_error(False)
        payload = data[: pdo.length]
        if _sync_type(pdo.trans_type):
            pdo.latched = payload
        else:
            self._apply(pdo, payload)

    def _apply(self, pdo: Pdo, payload: bytes) -> None:
        packed = None if pdo.aligned else int.from_bytes(payload, "little")
        offset = 0  # bits
        for slot in pdo.slots:
            entry = slot.entry
            try:
                if entry is None:
                    pass  # a dummy entry: these bits are skipped
                elif packed is None:
                    start = offset // 8
                    entry.write(decode(entry.dtype, payload[start : start + slot.size]))  # type: ignore[arg-type]
                elif entry.dtype == BOOLEAN and slot.bits == 1:
                    entry.write(packed >> offset & 1)
                else:
                    raw = packed >> offset & ((1 << slot.bits) - 1)
                    entry.write(decode(entry.dtype, raw.to_bytes(slot.bits // 8, "little")))  # type: ignore[arg-type]
            except Abort as exc:
                self.counters.rpdo_write_refused += 1
                log.debug("RPDO%d: 0x%04X:%d refused: %s", pdo.number, slot.index, slot.sub, exc)
            offset += slot.bits

    # -- mapping ----------------------------------------------------------------------
    def _check_entry(self, pdo: Pdo, value: int) -> _Slot:
        index, sub, bits = value >> 16, value >> 8 & 0xFF, value & 0xFF
        if index in DUMMY_BITS:
            return self._check_dummy(pdo, index, sub, bits)
        try:
            entry = self.directory.entry(index, sub)  # 0602 0000 / 0609 0011 when missing
        except Abort:
            if self.exists is not None and self.exists(index, sub):
                raise Abort(NOT_MAPPABLE, f"0x{index:04X}:{sub} cannot be mapped") from None
            raise
        usable = entry.readable if pdo.transmit else entry.writable
        if not entry.mappable or not usable:
            raise Abort(
                NOT_MAPPABLE,
                f"0x{index:04X}:{sub} cannot be mapped into a {'T' if pdo.transmit else 'R'}PDO",
            )
        length = 1 if entry.dtype == BOOLEAN else entry.bits
        if bits != length:
            raise Abort(NOT_MAPPABLE, f"0x{index:04X}:{sub} is {length} bits, not {bits}")
        if bits % self.granularity:
            raise Abort(
                NOT_MAPPABLE, f"0x{index:04X}:{sub}: the mapping granularity is {self.granularity}"
            )
        return _Slot(index, sub, entry, bits)

    def _check_dummy(self, pdo: Pdo, index: int, sub: int, bits: int) -> _Slot:
        """CiA 301 dummy mapping: RPDOs only, sub 0, the data type's own length."""
        if pdo.transmit:
            raise Abort(NOT_MAPPABLE, f"dummy entry 0x{index:04X} in a TPDO")
        if index not in dummy_types(self.granularity):
            raise Abort(
                NOT_MAPPABLE,
                f"dummy entry 0x{index:04X} ({DUMMY_BITS[index]} bits) needs bit granularity",
            )
        if sub != 0:
            raise Abort(NOT_MAPPABLE, f"dummy entry 0x{index:04X} has only sub-index 0")
        if bits != DUMMY_BITS[index]:
            raise Abort(
                NOT_MAPPABLE, f"dummy entry 0x{index:04X} is {DUMMY_BITS[index]} bits, not {bits}"
            )
        return _Slot(index, sub, None, bits)

    def _compile(self, pdo: Pdo, values: list[int]) -> list[_Slot]:
        slots = [self._check_entry(pdo, v) for v in values]
        total = sum(s.bits for s in slots)
        if total > MAX_BITS:
            raise Abort(PDO_TOO_LONG, f"the mapping needs {total} bits, at most {MAX_BITS}")
        return slots

    def _reindex(self) -> None:
        # Only these TPDOs ever have a deadline (event timer, or events held back by an inhibit time).
        self._timed = [
            p
            for p in self.tpdos
            if p.valid and _async_type(p.trans_type) and (p.event_timer or p.inhibit)
        ]
        self._rx = {p.can_id: p for p in self.rpdos if p.valid}
        self._rtr = {p.can_id: p for p in self.tpdos if p.valid and p.rtr_allowed}
        self._events = {}
        for pdo in self.tpdos:
            for slot in pdo.slots:
                if slot.entry is None:
                    continue
                bucket = self._events.setdefault((slot.index, slot.sub), [])
                if pdo not in bucket:
                    bucket.append(pdo)

    # -- parameter objects ----------------------------------------------------------
    def _set_cob_id(self, pdo: Pdo, value: int) -> None:
        new_valid = not value & COB_INVALID
        can_id = check_cob_id(value, "PDO", in_use=new_valid)
        if pdo.valid and new_valid and value != pdo.cob_id:
            raise Abort(VALUE_RANGE, "the COB-ID of a valid PDO cannot change; set bit 31 first")
        if new_valid:
            clash = [
                p
                for p in (self.tpdos + self.rpdos)
                if p is not pdo and p.valid and p.can_id == can_id
            ]
            if clash:
                raise Abort(VALUE_RANGE, f"COB-ID 0x{can_id:03X} is used by another PDO")
        was_valid = pdo.valid
        pdo.cob_id = value
        if was_valid != new_valid:
            pdo.clear_runtime()
            self._arm_timer(pdo, self.clock())
        self._reindex()

    def _set_trans_type(self, pdo: Pdo, value: int) -> None:
        allowed = value <= 240 or value >= (252 if pdo.transmit else 254)
        if not allowed:
            raise Abort(
                VALUE_RANGE,
                f"transmission type {value} is not supported for a {'T' if pdo.transmit else 'R'}PDO",
            )
        pdo.trans_type = value
        pdo.clear_runtime()
        self._arm_timer(pdo, self.clock())
        self._reindex()

    def _set_while_invalid(self, pdo: Pdo, attr: str, value: int) -> None:
        if pdo.valid and pdo.transmit:
            raise Abort(
                VALUE_RANGE, f"{attr.replace('_', ' ')} can change only while the PDO is invalid"
            )
        setattr(pdo, attr, value)
        pdo.clear_runtime()
        self._reindex()

    def _set_event_timer(self, pdo: Pdo, value: int) -> None:
        pdo.event_timer = value
        self._arm_timer(pdo, self.clock())
        self._reindex()

    def _set_map_count(self, pdo: Pdo, value: int) -> None:
        if value > MAX_ENTRIES:
            raise Abort(PDO_TOO_LONG, f"at most {MAX_ENTRIES} entries")
        slots = self._compile(pdo, pdo.map_entries[:value])
        pdo.map_count, pdo.slots = value, slots
        pdo.sample = None
        self._reindex()

    def _set_map_entry(self, pdo: Pdo, position: int, value: int) -> None:
        if pdo.map_count != 0:
            raise Abort(DEVICE_STATE, "mapping entries change only while sub-index 0 is 0")
        if value:
            self._check_entry(pdo, value)
        pdo.map_entries[position] = value

    def objects(self) -> list[ObjectDef]:
        """The parameter objects of every PDO, bound to this engine."""
        result = []
        for pdo in self.rpdos + self.tpdos:
            result += [self._comm_object(pdo), self._map_object(pdo)]
        return result

    def _cob_default(self, pdo: Pdo) -> tuple[int, str | None]:
        d = pdo.default
        if d.cob_base is None:
            return COB_INVALID, None
        return d.cob_id(self.node_id), f"$NODEID+0x{d.cob_base | (0 if d.valid else COB_INVALID):X}"

    def _comm_object(self, pdo: Pdo) -> ObjectDef:
        cob, expr = self._cob_default(pdo)
        d = pdo.default
        kind = "Transmit" if pdo.transmit else "Receive"
        entries = [
            Entry(
                1,
                "COB-ID",
                UNSIGNED32,
                "rw",
                lambda: pdo.cob_id,
                lambda v: self._set_cob_id(pdo, v),
                default=cob,
                default_expr=expr,
            ),
            Entry(
                2,
                "Transmission type",
                UNSIGNED8,
                "rw",
                lambda: pdo.trans_type,
                lambda v: self._set_trans_type(pdo, v),
                default=d.trans_type,
            ),
        ]
        if pdo.transmit or self.rpdo_timing:
            entries += [
                Entry(
                    3,
                    "Inhibit time",
                    UNSIGNED16,
                    "rw",
                    lambda: pdo.inhibit,
                    lambda v: self._set_while_invalid(pdo, "inhibit", v),
                    default=d.inhibit,
                ),
                Entry(
                    5,
                    "Event timer",
                    UNSIGNED16,
                    "rw",
                    lambda: pdo.event_timer,
                    lambda v: self._set_event_timer(pdo, v),
                    default=d.event_timer,
                ),
            ]
        if pdo.transmit:
            entries.append(
                Entry(
                    6,
                    "SYNC start value",
                    UNSIGNED8,
                    "rw",
                    lambda: pdo.sync_start,
                    lambda v: self._set_while_invalid(pdo, "sync_start", v),
                    default=0,
                    high=240,
                )
            )
        highest = entries[-1].sub
        return ObjectDef(
            pdo.comm_index,
            f"{kind} PDO {pdo.number} communication parameter",
            "record",
            [count_entry(highest)] + entries,
        )

    def _map_object(self, pdo: Pdo) -> ObjectDef:
        d = pdo.default
        kind = "Transmit" if pdo.transmit else "Receive"
        entries = [
            Entry(
                0,
                "Number of mapped objects",
                UNSIGNED8,
                "rw",
                lambda: pdo.map_count,
                lambda v: self._set_map_count(pdo, v),
                default=len(d.entries),
            )
        ]
        for position in range(MAX_ENTRIES):
            default = d.entries[position] if position < len(d.entries) else 0
            entries.append(
                Entry(
                    position + 1,
                    f"Mapped object {position + 1}",
                    UNSIGNED32,
                    "rw",
                    partial(_map_entry, pdo, position),
                    partial(self._set_map_entry, pdo, position),
                    default=default,
                )
            )
        return ObjectDef(
            pdo.map_index, f"{kind} PDO {pdo.number} mapping parameter", "record", entries
        )

    # -- persistence (0x1010 store) ------------------------------------------------------
    def parameters(self) -> list[list[Any]]:
        """The parameters of every PDO that differs from its default, as plain data."""
        records = []
        for pdo in self.tpdos + self.rpdos:
            record = [
                pdo.transmit,
                pdo.number,
                pdo.cob_id,
                pdo.trans_type,
                pdo.inhibit,
                pdo.event_timer,
                pdo.sync_start,
                pdo.map_count,
                list(pdo.map_entries),
            ]
            d = pdo.default
            default = [
                pdo.transmit,
                pdo.number,
                d.cob_id(self.node_id),
                d.trans_type,
                d.inhibit,
                d.event_timer,
                0,
                len(d.entries),
                (list(d.entries) + [0] * MAX_ENTRIES)[:MAX_ENTRIES],
            ]
            if record != default:
                records.append(record)
        return records

    def load_parameters(self, records: list[Any]) -> int:
        """Apply stored records (after a reset); a record that no longer fits is skipped. Returns how many applied."""
        applied = 0
        by_key = {(p.transmit, p.number): p for p in self.tpdos + self.rpdos}
        for record in records:
            try:
                (
                    transmit,
                    number,
                    cob_id,
                    trans_type,
                    inhibit,
                    event_timer,
                    sync_start,
                    count,
                    entries,
                ) = record
                pdo = by_key[(bool(transmit), int(number))]
                entries = [int(e) for e in entries][:MAX_ENTRIES]
                slots = self._compile(pdo, entries[:count])
            except (Abort, KeyError, TypeError, ValueError):
                log.warning(
                    "stored PDO parameters %r do not fit this device; defaults kept", record
                )
                continue
            pdo.cob_id, pdo.trans_type, pdo.inhibit, pdo.event_timer, pdo.sync_start = (
                int(cob_id),
                int(trans_type),
                int(inhibit),
                int(event_timer),
                int(sync_start),
            )
            pdo.map_entries = entries + [0] * (MAX_ENTRIES - len(entries))
            pdo.map_count, pdo.slots, pdo.sample = int(count), slots, None
            pdo.clear_runtime()
            applied += 1
        self._reindex()
        return applied

    def status(self) -> dict[str, Any]:
        return {
            "operational": self.operational,
            "tpdo_valid": sum(p.valid for p in self.tpdos),
            "rpdo_valid": sum(p.valid for p in self.rpdos),
            "length_error": self.length_error_active,
            **self.counters.__dict__,
        }
