"""The Modbus map of a ``modbus-tcp`` front and the requests on it (no I/O here).

The map is generated from the front's channels in their order (its ``expose`` list, or the
default order), each table from address 0 without gaps:

* coils (FC1 read, FC5/FC15 write): DO channels;
* discrete inputs (FC2): DI channels;
* input registers (FC4): AI channels, then SI bytes (one register each, 0..255), then two
  registers per module: status (bit 0 online, bit 1 every input of the module good) and its
  error counter (failed transactions, wrapping at 65535);
* holding registers (FC3 read, FC6/FC16 write): AO channels, then SO bytes.

A 16-bit channel takes one register (int16 as two's complement); int32, uint32 and float32
(IEEE 754) take two, high word first unless ``word_order: little``. The same YAML gives the
same map; a module appended at the end of ``expose`` leaves every earlier address where it was.
``fieldgate map TOPOLOGY --front NAME`` prints it.

Exceptions (answered by :class:`ModbusMap`'s ``read``/``write``):

| code | when |
|---|---|
| 01 illegal function | a write to a point that is mapped but not writable (an input, an output not in ``writable``, a status register) |
| 02 illegal data address | any address of the request outside the table |
| 03 illegal data value | half of a 32-bit value written, a byte (SI/SO) above 255 |
| 0B gateway target failed to respond | with ``comm_fault: exception``: a read that includes a point whose module is offline |
"""

from __future__ import annotations

import fnmatch
import struct
from collections.abc import Iterable
from dataclasses import dataclass

from fieldgate.health import HealthRegistry
from fieldgate.image import Channel, DataType, Kind, ProcessImage, Quality, Value

from .pdu import GATEWAY_NO_RESPONSE, ILLEGAL_ADDRESS, ILLEGAL_FUNCTION, ILLEGAL_VALUE

COILS, DISCRETE_INPUTS, HOLDING_REGISTERS, INPUT_REGISTERS = (
    "coil",
    "discrete input",
    "holding register",
    "input register",
)
TABLE_OF_FC = {
    1: COILS,
    2: DISCRETE_INPUTS,
    3: HOLDING_REGISTERS,
    4: INPUT_REGISTERS,
    5: COILS,
    15: COILS,
    6: HOLDING_REGISTERS,
    16: HOLDING_REGISTERS,
    23: HOLDING_REGISTERS,
}
TABLES = (COILS, DISCRETE_INPUTS, INPUT_REGISTERS, HOLDING_REGISTERS)
WIDE = {DataType.INT32, DataType.UINT32, DataType.FLOAT32}
_DTYPES = {d.value: d for d in DataType}  # a point's type by name, without Enum's lookup


@dataclass(frozen=True)
class Point:
    table: str
    address: int
    width: int  # registers (1 or 2); bits: 1
    what: str  # channel id, or "rs485/m3 status" / "rs485/m3 error counter"
    dtype: str
    writable: bool = False
    channel_id: str | None = None
    module: tuple[str, int] | None = None  # status registers: the module


class ModbusMap:
    def __init__(
        self, points: Iterable[Point], word_order: str = "big", comm_fault_exception: bool = False
    ):
        self.points = list(points)
        self.word_order = word_order
        self.comm_fault_exception = comm_fault_exception
        # table -> address -> (point, word index inside the point)
        self.slots: dict[str, list[tuple[Point, int]]] = {t: [] for t in TABLES}
        for p in self.points:
            for i in range(p.width):
                assert len(self.slots[p.table]) == p.address + i, "a table has no gaps"
                self.slots[p.table].append((p, i))

    @classmethod
    def from_channels(
        cls,
        channels: Iterable[Channel],
        writable: Iterable[str] = (),
        word_order: str = "big",
        comm_fault_exception: bool = False,
    ) -> ModbusMap:
        patterns = list(writable)
        channels = list(channels)
        points: list[Point] = []
        next_address = dict.fromkeys(TABLES, 0)

        def add(
            table: str,
            width: int,
            what: str,
            dtype: str,
            writable: bool = False,
            cid: str | None = None,
            module: tuple[str, int] | None = None,
        ) -> None:
            points.append(
                Point(table, next_address[table], width, what, dtype, writable, cid, module)
            )
            next_address[table] += width

        for kinds, table in (
            ((Kind.DO,), COILS),
            ((Kind.DI,), DISCRETE_INPUTS),
            ((Kind.AI, Kind.SI), INPUT_REGISTERS),
            ((Kind.AO, Kind.SO), HOLDING_REGISTERS),
        ):
            for kind in kinds:
                for ch in channels:
                    if ch.kind is not kind:
                        continue
                    dtype = ch.spec.data_type
                    width = 2 if dtype in WIDE else 1
                    is_writable = kind.is_output and any(
                        fnmatch.fnmatchcase(ch.id, p) for p in patterns
                    )
                    add(table, width, ch.id, dtype.value, is_writable, ch.id)
        modules: list[tuple[str, int]] = []
        for ch in channels:
            key = (ch.source.back, ch.source.module)
            if key not in modules:
                modules.append(key)
        for back, address in modules:
            add(
                INPUT_REGISTERS,
                1,
                f"{back}/m{address} status",
                "bits: 0 online, 1 inputs good",
                module=(back, address),
            )
            add(
                INPUT_REGISTERS,
                1,
                f"{back}/m{address} error counter",
                "uint16",
                module=(back, address),
            )
        return cls(points, word_order, comm_fault_exception)

    def size(self, table: str) -> int:
        return len(self.slots[table])

    # -- values ------------------------------------------------------------------------------
    def _words(self, point: Point, value: bool | int | float) -> list[int]:
        dtype = _DTYPES[point.dtype]
        if dtype is DataType.FLOAT32:
            raw = struct.unpack(">I", struct.pack(">f", float(value)))[0]
        else:
            raw = int(value) & (0xFFFF_FFFF if point.width == 2 else 0xFFFF)
        if point.width == 1:
            return [raw]
        words = [raw >> 16, raw & 0xFFFF]
        return words if self.word_order == "big" else words[::-1]

    def _value(self, point: Point, words: list[int]) -> int | float:
        dtype = _DTYPES[point.dtype]
        if point.width == 1:
            word = words[0]
            if dtype is DataType.INT16:
                return word - 0x10000 if word & 0x8000 else word
            return word
        high, low = words if self.word_order == "big" else words[::-1]
        raw = (high << 16) | low
        if dtype is DataType.FLOAT32:
            return float(struct.unpack(">f", struct.pack(">I", raw))[0])
        if dtype is DataType.INT32:
            return raw - 0x1_0000_0000 if raw & 0x8000_0000 else raw
        return raw

    def _module_word(self, point: Point, image: ProcessImage, health: HealthRegistry) -> int:
        assert point.module is not None
        back, address = point.module
        try:
            h = health.get(back, address)
            online, errors = h.online, h.error_counter
        except KeyError:
            online, errors = True, 0
        if point.what.endswith("error counter"):
            return errors & 0xFFFF
        inputs = [c for c in image.channels(back=back, module=address) if not c.kind.is_output]
        good = all(c.quality is Quality.GOOD for c in inputs)
        return int(online) | int(good) << 1

    # -- requests ----------------------------------------------------------------------------
    def read_error(self, fc: int, address: int, count: int) -> int | None:
        """02 when a read of ``count`` points from ``address`` leaves its table, else None."""
        if count < 1 or address < 0 or address + count > len(self.slots[TABLE_OF_FC[fc]]):
            return ILLEGAL_ADDRESS
        return None

    def read(
        self, fc: int, address: int, count: int, image: ProcessImage, health: HealthRegistry
    ) -> list[bool] | list[int] | int:
        """Values for FC1-4 (and the read half of FC23), or an exception code."""
        error = self.read_error(fc, address, count)
        if error is not None:
            return error
        slots = self.slots[TABLE_OF_FC[fc]]
        part = slots[address : address + count]
        if self.comm_fault_exception and any(
            p.channel_id is not None and image[p.channel_id].quality is Quality.COMM_FAULT
            for p, _ in part
        ):
            return GATEWAY_NO_RESPONSE
        if TABLE_OF_FC[fc] in (COILS, DISCRETE_INPUTS):
            return [bool(image[p.channel_id].value) for p, _ in part if p.channel_id is not None]
        out: list[int] = []
        words: list[int] = []
        for p, i in part:
            cid = p.channel_id
            if cid is None:
                out.append(self._module_word(p, image, health))
            elif p.width == 1:  # int16, uint16, a byte: the value's low 16 bits
                out.append(int(image[cid].value) & 0xFFFF)
            else:  # a 32-bit value's two words, one after the other (a read may start at either)
                if i == 0 or not words:
                    words = self._words(p, image[cid].value)
                out.append(words[i])
                if i:
                    words = []
        return out

    def write(
        self, fc: int, address: int, values: list[bool] | list[int]
    ) -> dict[str, Value] | int:
        """The outputs FC5/6/15/16 (and the write half of FC23) set, as one batch (channel id
        -> value), or the exception code (nothing is to be written then)."""
        table = TABLE_OF_FC[fc]
        slots = self.slots[table]
        count = len(values)
        if count < 1 or address < 0 or address + count > len(slots):
            return ILLEGAL_ADDRESS
        part = slots[address : address + count]
        if not all(p.writable for p, _ in part):
            return ILLEGAL_FUNCTION
        if table == COILS:
            return {
                p.channel_id: bool(v)
                for (p, _), v in zip(part, values, strict=True)
                if p.channel_id
            }
        updates: dict[str, Value] = {}
        k = 0
        while k < count:
            p, i = part[k]
            if i != 0 or k + p.width > count:
                return ILLEGAL_VALUE  # a 32-bit value is written whole
            value = self._value(p, [int(v) for v in values[k : k + p.width]])
            if _DTYPES[p.dtype] is DataType.UINT8 and not 0 <= int(value) <= 0xFF:
                return ILLEGAL_VALUE
            assert p.channel_id is not None
            updates[p.channel_id] = value
            k += p.width
        return updates

    # -- the printed map -----------------------------------------------------------------------
    def rows(self) -> list[tuple[str, str, str, str, str]]:
        """(table, address range, point, type, access) per point, tables in FC order."""
        fc_of = {
            COILS: "FC1 / FC5, FC15",
            DISCRETE_INPUTS: "FC2",
            HOLDING_REGISTERS: "FC3 / FC6, FC16",
            INPUT_REGISTERS: "FC4",
        }
        out = []
        for table in (COILS, DISCRETE_INPUTS, HOLDING_REGISTERS, INPUT_REGISTERS):
            for p in (q for q in self.points if q.table == table):
                span = f"{p.address}" if p.width == 1 else f"{p.address}-{p.address + p.width - 1}"
                access = "read/write" if p.writable else "read"
                out.append((f"{table} ({fc_of[table]})", span, p.what, p.dtype, access))
        return out

    def text(self) -> str:
        rows = [("table", "address", "point", "type", "access"), *self.rows()]
        widths = [max(len(r[i]) for r in rows) for i in range(5)]
        lines = [
            "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows
        ]
        lines.insert(1, "  ".join("-" * w for w in widths))
        totals = ", ".join(
            f"{self.size(t)} {t}s"
            for t in (COILS, DISCRETE_INPUTS, HOLDING_REGISTERS, INPUT_REGISTERS)
        )
        return (
            "\n".join(lines)
            + f"\n{totals}; addresses are 0-based (PDU addresses); 32-bit values: {self.word_order} word order\n"
        )
