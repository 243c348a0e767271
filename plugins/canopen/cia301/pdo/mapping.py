"""PDO mapping (CiA 301 §7.4.8: 0x1600-, 0x1A00-), sans-I/O: what a PDO carries.

* :class:`Pdo` is one PDO's record: its communication parameters, its mapping compiled to
  :class:`Slot` items, and the run-time state the TPDO and RPDO services keep in it;
* :class:`PdoMapping` checks mapping entries against the node's objects
  (:class:`~.entries.Directory`), compiles them, **packs** a TPDO's data from the mapped
  entries (:meth:`PdoMapping.pack`), **unpacks** an RPDO's data into one value per mapped
  entry (:meth:`PdoMapping.unpack`), and serves the mapping parameter objects.

Write rules of CiA 301: mapping entries change only while sub 0 is 0 (0800 0022); sub 0
checks every entry: it exists (0602 0000 / 0609 0011), it is mappable in this direction
and has its own length (0604 0041), the whole mapping is at most 64 bits (0604 0042).

Mapping granularity: with ``granularity=8`` (the default, what the seeds' masters expect)
every entry is whole bytes; with ``granularity=1`` 1-bit BOOLEAN entries (CiA 401
0x6020-/0x6220-) pack bit after bit, LSB first, as CiA 301 lays out PDO data. RPDOs may
map CiA 301 dummy entries (index 0x0001-0x0007, sub 0, the data type's length) to skip
bits nobody uses; 0x0001 (1 bit) only with granularity 1; TPDOs refuse them (0604 0041).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial

from ..abort import DEVICE_STATE, NOT_MAPPABLE, PDO_TOO_LONG
from ..entries import (
    BOOLEAN,
    UNSIGNED8,
    UNSIGNED32,
    Abort,
    Directory,
    Entry,
    ObjectDef,
    Value,
    decode,
    encode,
)
from .defaults import COB_INVALID, PdoDefault

Frame = tuple[int, bytes]  # (can_id, data): what the PDO services return to send

COB_NO_RTR = 1 << 30
MAX_ENTRIES = 8
MAX_BITS = 64
RPDO_COMM, RPDO_MAP, TPDO_COMM, TPDO_MAP = 0x1400, 0x1600, 0x1800, 0x1A00
DUMMY_BITS = {0x0001: 1, 0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}


def dummy_types(granularity: int) -> list[int]:
    """The dummy entries (CiA 301 data type indices) an RPDO of this granularity may map."""
    return [index for index, bits in DUMMY_BITS.items() if bits % granularity == 0]


def sync_type(t: int) -> bool:
    """Transmission types 0-240: synchronous (acyclic or every n-th SYNC)."""
    return t <= 240


def async_type(t: int) -> bool:
    """Transmission types 254/255: event-driven."""
    return t >= 254


@dataclass
class Slot:
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
    slots: list[Slot] = field(default_factory=list)
    # run-time state
    sync_count: int = 0
    waiting_start: bool = False
    sync_event: bool = False  # type 0: an event since the last transmission
    pending: bool = False  # an event held back by the inhibit time
    next_allowed: float = float("-inf")
    timer_due: float | None = None
    sample: bytes | None = None  # data sampled at the last SYNC
    latched: bytes | None = None  # RPDO data waiting for the next SYNC
    _aligned_for: list[Slot] | None = field(default=None, repr=False)
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


def _map_entry(pdo: Pdo, position: int) -> int:
    return pdo.map_entries[position]  # read when asked: a remap replaces the list


class PdoMapping:
    """Mapping rules, packing and unpacking over the node's objects (``directory``).

    ``exists(index, sub)``: other objects of the node (mapping one of them is 0604 0041,
    not 0602 0000).
    """

    def __init__(
        self,
        directory: Directory,
        granularity: int = 8,
        exists: Callable[[int, int], bool] | None = None,
    ):
        if granularity not in (1, 8):
            raise ValueError("mapping granularity 1 (bits) or 8 (bytes)")
        self.directory = directory
        self.granularity = granularity
        self.exists = exists

    # -- checking and compiling --------------------------------------------------------
    def check_entry(self, pdo: Pdo, value: int) -> Slot:
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
        return Slot(index, sub, entry, bits)

    def _check_dummy(self, pdo: Pdo, index: int, sub: int, bits: int) -> Slot:
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
        return Slot(index, sub, None, bits)

    def compile(self, pdo: Pdo, values: list[int]) -> list[Slot]:
        slots = [self.check_entry(pdo, v) for v in values]
        total = sum(s.bits for s in slots)
        if total > MAX_BITS:
            raise Abort(PDO_TOO_LONG, f"the mapping needs {total} bits, at most {MAX_BITS}")
        return slots

    # -- packing and unpacking ----------------------------------------------------------
    @staticmethod
    def pack(pdo: Pdo) -> bytes:
        """A TPDO's data: each mapped entry's current value (dummy bits zero)."""
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

    @staticmethod
    def unpack(pdo: Pdo, payload: bytes) -> Iterator[tuple[Slot, Entry, Value]]:
        """An RPDO's data (at least ``pdo.length`` bytes) as (slot, entry, value) per mapped
        entry, in mapping order; dummy entries are skipped."""
        packed = None if pdo.aligned else int.from_bytes(payload, "little")
        offset = 0  # bits
        for slot in pdo.slots:
            entry = slot.entry
            if entry is None:
                pass  # a dummy entry: these bits are skipped
            elif packed is None:
                start = offset // 8
                yield slot, entry, decode(entry.dtype, payload[start : start + slot.size])
            elif entry.dtype == BOOLEAN and slot.bits == 1:
                yield slot, entry, packed >> offset & 1
            else:
                raw = packed >> offset & ((1 << slot.bits) - 1)
                yield slot, entry, decode(entry.dtype, raw.to_bytes(slot.bits // 8, "little"))
            offset += slot.bits

    # -- mapping parameter objects --------------------------------------------------------
    def map_object(self, pdo: Pdo, remapped: Callable[[Pdo], None]) -> ObjectDef:
        """0x1600+n / 0x1A00+n of ``pdo``; ``remapped(pdo)`` after sub 0 took a new mapping."""
        d = pdo.default
        kind = "Transmit" if pdo.transmit else "Receive"
        entries = [
            Entry(
                0,
                "Number of mapped objects",
                UNSIGNED8,
                "rw",
                lambda: pdo.map_count,
                lambda v: self._set_map_count(pdo, v, remapped),
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

    def _set_map_count(self, pdo: Pdo, value: int, remapped: Callable[[Pdo], None]) -> None:
        if value > MAX_ENTRIES:
            raise Abort(PDO_TOO_LONG, f"at most {MAX_ENTRIES} entries")
        slots = self.compile(pdo, pdo.map_entries[:value])
        pdo.map_count, pdo.slots = value, slots
        pdo.sample = None
        remapped(pdo)

    def _set_map_entry(self, pdo: Pdo, position: int, value: int) -> None:
        if pdo.map_count != 0:
            raise Abort(DEVICE_STATE, "mapping entries change only while sub-index 0 is 0")
        if value:
            self.check_entry(pdo, value)
        pdo.map_entries[position] = value
