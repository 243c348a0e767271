"""The Modbus map of a ``modbus-tcp`` front and the requests on it (no I/O here).

The map is generated from the front's channels in their order (its ``expose`` list, or the
default order), each table from address 0 without gaps:

* coils (FC1 read, FC5/FC15 write): DO channels;
* discrete inputs (FC2): DI channels;
* input registers (FC4): AI channels, then SI bytes (one register each, 0..255), then two
  registers per module: status (bit 0 online, bit 1 every input of the module good) and its
  error counter (failed transactions, wrapping at 65535);
* holding registers (FC3 read, FC6/FC16 write): AO channels, then SO bytes.

A 16-bit channel takes one register (int16 as two's complement); 32-bit values (int32,
uint32, float32) take two, 64-bit values (int64, uint64, float64) four, text its bytes (two a
register), in the front's ``order`` (ABCD, CDAB, BADC, DCBA: ``fieldgate.registers``, the
same code the Modbus back reads devices with). A channel the back scaled (float64 in
engineering units) is served as ``scaled_values`` says: float32 (default), float64, or raw
(the device's own register value and type; a write is converted back). The same YAML gives
the same map; a module appended at the end of ``expose`` leaves every earlier address where
it was. ``fieldgate map TOPOLOGY --front NAME`` prints it.

Exceptions (answered by :class:`ModbusMap`'s ``read``/``write``):

| code | when |
|---|---|
| 01 illegal function | a write to a point that is mapped but not writable (an input, an output not in ``writable``, a status register) |
| 02 illegal data address | any address of the request outside the table |
| 03 illegal data value | part of a value of several registers written, a byte (SI/SO) above 255, a float that is not finite, text that is not UTF-8 |
| 0B gateway target failed to respond | with ``comm_fault: exception``: a read that includes a point whose module is offline |
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Iterable
from dataclasses import dataclass

from fieldgate import registers
from fieldgate.health import HealthRegistry
from fieldgate.image import (
    Channel,
    DataType,
    Engineering,
    Kind,
    ProcessImage,
    Quality,
    Value,
    integer_range,
)

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
SCALED_VIEWS = {"float32": DataType.FLOAT32, "float64": DataType.FLOAT64}
_DTYPES = {d.value: d for d in DataType}  # a point's type by name, without Enum's lookup


@dataclass(frozen=True)
class Point:
    table: str
    address: int
    width: int  # registers; bits: 1
    what: str  # channel id, or "rs485/m3 status" / "rs485/m3 error counter"
    dtype: str  # as served
    writable: bool = False
    channel_id: str | None = None
    module: tuple[str, int] | None = None  # status registers: the module
    length: int | None = None  # text: its bytes
    raw: Engineering | None = None  # served raw: the channel's conversion, undone on reads
    note: str = ""  # for the printed map: the unit and range, "raw of ..."


class ModbusMap:
    def __init__(
        self, points: Iterable[Point], word_order: str = "big", comm_fault_exception: bool = False
    ):
        self.points = list(points)
        self.order = registers.order_name(word_order)
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
        scaled_values: str = "float32",
    ) -> ModbusMap:
        """``word_order``: the order of values wider than a register (ABCD, CDAB, BADC, DCBA;
        big = ABCD, little = CDAB); ``scaled_values``: how a channel the back scaled is served
        (float32, float64, raw)."""
        patterns = list(writable)
        channels = list(channels)
        points: list[Point] = []
        next_address = dict.fromkeys(TABLES, 0)

        def add(table: str, width: int, what: str, dtype: str, **more: object) -> None:
            points.append(Point(table, next_address[table], width, what, dtype, **more))  # type: ignore[arg-type]  # (Point's own fields)
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
                    is_writable = kind.is_output and any(
                        fnmatch.fnmatchcase(ch.id, p) for p in patterns
                    )
                    dtype, raw, note = _served(ch, scaled_values)
                    width = (
                        1
                        if dtype in (DataType.BOOL, DataType.UINT8)
                        else registers.width(dtype, ch.spec.length)
                    )
                    add(
                        table,
                        width,
                        ch.id,
                        dtype.value,
                        writable=is_writable,
                        channel_id=ch.id,
                        length=ch.spec.length,
                        raw=raw,
                        note=note,
                    )
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
    def _words(self, point: Point, value: Value) -> list[int]:
        """A value's registers as served (a value the served type cannot hold is clamped)."""
        dtype = _DTYPES[point.dtype]
        if point.raw is not None and not isinstance(value, str | bool):
            value = _to_raw(point.raw, value)
        if point.width == 1 and dtype is not DataType.STRING:
            return [int(value) & 0xFFFF]  # (fast path: int16, uint16, a byte or a field)
        try:
            return registers.encode(dtype, value, self.order, point.length)
        except (ValueError, OverflowError):
            return registers.encode(
                dtype, _clamped(dtype, value, point.length), self.order, point.length
            )

    def _value(self, point: Point, words: list[int]) -> Value:
        """What a client wrote, as the channel's value; ValueError when it cannot be one."""
        dtype = _DTYPES[point.dtype]
        value: Value
        if point.width == 1 and dtype is not DataType.STRING:
            word = words[0]
            value = word - 0x10000 if dtype is DataType.INT16 and word & 0x8000 else word
        else:
            value = registers.decode(dtype, words, self.order, point.length)
        if point.raw is not None and not isinstance(value, str):
            return point.raw.from_raw(value)
        return value

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
            elif p.width == 1 and p.raw is None:  # int16, uint16, a byte: its low 16 bits
                out.append(int(image[cid].value) & 0xFFFF)
            else:  # a wide value's words, one after the other (a read may start at any)
                if i == 0 or not words:
                    words = self._words(p, image[cid].value)
                out.append(words[i])
                if i == p.width - 1:
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
                return ILLEGAL_VALUE  # a value of several registers is written whole
            try:
                value = self._value(p, [int(v) for v in values[k : k + p.width]])
            except ValueError:  # a float that is not finite
                return ILLEGAL_VALUE
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
                dtype = p.dtype + (f" ({p.length} bytes)" if p.length else "")
                dtype += f" ({p.note})" if p.note else ""
                out.append((f"{table} ({fc_of[table]})", span, p.what, dtype, access))
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
            + f"\n{totals}; addresses are 0-based (PDU addresses); values wider than a register: "
            f"{self.order} order\n"
        )


def _served(channel: Channel, scaled_values: str) -> tuple[DataType, Engineering | None, str]:
    """(type served, the conversion to undo for a raw view, a note) of a channel."""
    spec = channel.spec
    eng = spec.engineering
    if eng is None:
        return spec.data_type, None, ""
    unit = f", {eng.unit}" if eng.unit else ""
    if eng.eu_range is not None:
        unit += f", {eng.low:g}..{eng.high:g}"
    if not eng.converts:
        return spec.data_type, None, unit.removeprefix(", ")
    if scaled_values == "raw":
        return eng.raw_type, eng, f"raw of {eng.describe()}"
    return SCALED_VIEWS[scaled_values], None, f"scaled{unit}"


def _to_raw(eng: Engineering, value: int | float) -> int | float:
    try:
        return eng.to_raw(value)
    except ValueError:  # beyond the raw type: clamped
        wide = Engineering(DataType.FLOAT64, eng.gain, eng.offset, divider=eng.divider)
        clamped = _clamped(eng.raw_type, wide.to_raw(value), None)
        assert not isinstance(clamped, str)  # (a number type)
        return clamped


def _clamped(dtype: DataType, value: Value, length: int | None) -> Value:
    """The nearest value the served type can hold (text cut to its bytes)."""
    if dtype is DataType.STRING:
        data = str(value).encode()[: length or 0]
        return data.decode("utf-8", errors="ignore")
    if dtype.is_float:
        number = float(value)
        if math.isnan(number):
            return number
        return math.copysign(math.inf, number) if abs(number) > 3.4e38 else number
    low, high = integer_range(dtype)
    try:
        return max(low, min(high, round(float(value))))
    except (ValueError, OverflowError):  # text in a number's place, nan
        return 0
