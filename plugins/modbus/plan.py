"""Request planning, sans-I/O: which reads and writes cover a module's points.

* Reads: points of one table are sorted and coalesced into blocks of adjacent addresses
  (or across holes up to ``gap``), each within the protocol limit (125 registers,
  2000 bits) or the module's own lower limit.
* Writes: the changed outputs of one table become spans from the lowest to the highest
  changed address, the unchanged outputs in between filled with the values the back holds
  for them, so that one batch (one RPDO) reaches the module in one request where it can
  (:func:`plan_writes`); a span of one coil or one 16-bit register uses FC5/FC6, longer
  ones and 32-bit values FC15/FC16 (split at the 1968-bit / 123-register limits or the
  module's own), unless a group forces its function code.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from fieldgate.image import Quality, Value

from . import values as regvalues
from .codec import MAX_WRITE_BITS, MAX_WRITE_REGISTERS, Function
from .points import Point, Table


@dataclass
class ReadBlock:
    table: Table
    address: int
    count: int
    points: list[Point] = field(default_factory=list)
    due: float = 0.0  # next read, for groups with their own poll_ms

    @property
    def function(self) -> int:
        return self.table.read_function

    @property
    def end(self) -> int:
        return self.address + self.count

    def describe(self) -> str:
        return f"FC{self.function} {self.table.value} {self.address}..{self.end - 1}"


def plan_reads(
    points: list[Point], max_registers: int = 125, max_bits: int = 2000, gap: int = 0
) -> list[ReadBlock]:
    """Coalesce input points into as few read requests as the limits allow."""
    blocks: list[ReadBlock] = []
    by_table: dict[Table, list[Point]] = {}
    for p in points:
        by_table.setdefault(p.table, []).append(p)
    for table, pts in by_table.items():
        limit = max_bits if table.is_bits else max_registers
        current: ReadBlock | None = None
        for p in sorted(pts, key=lambda p: (p.address, p.bit or 0)):
            if (
                current is not None
                and p.address <= current.end + gap
                and max(current.end, p.end) - current.address <= limit
            ):
                current.count = max(current.end, p.end) - current.address
                current.points.append(p)
                continue
            current = ReadBlock(table, p.address, p.width, [p])
            blocks.append(current)
    return blocks


def decode_block(block: ReadBlock, data: Sequence[int]) -> dict[str, object]:
    """Readings of every point of a block from the bits or registers read.

    Values are converted to engineering units here (``Point.value_of``: over-/under-range
    quality outside the range). Registers that are not a finite float give the point
    over-range quality.
    """
    readings: dict[str, object] = {}
    bits, start = block.table.is_bits, block.address
    for p in block.points:
        offset = p.address - start
        if bits:
            readings[p.channel] = bool(data[offset])
        elif p.bit is not None:
            readings[p.channel] = p.value_of(regvalues.get_field(data[offset], p.bit, p.bits))
        else:
            try:
                raw = regvalues.decode(p.dtype, data[offset : offset + p.width], p.order, p.length)
            except ValueError:
                readings[p.channel] = (0.0, Quality.OVER_RANGE)
            else:
                readings[p.channel] = p.value_of(raw)
    return readings


@dataclass
class WriteOp:
    function: int
    address: int
    values: list[bool] | list[int]  # bools for coils, 16-bit words for registers
    points: list[Point]
    filled: frozenset[str] = frozenset()  # channels of ``points`` not changed: held values

    def describe(self) -> str:
        return f"FC{self.function} at {self.address} x{len(self.values)}"


def plan_writes(
    changes: list[tuple[Point, Value]],
    allow_multiple: bool = True,
    held: Sequence[tuple[Point, Value]] = (),
    max_bits: int = MAX_WRITE_BITS,
    max_registers: int = MAX_WRITE_REGISTERS,
) -> list[WriteOp]:
    """Write requests for changed coil and register outputs (not bits inside registers).

    The changed outputs of one table go out as spans: one FC15/FC16 from the lowest to
    the highest changed address, the addresses in between filled from ``held`` (outputs
    the back owns, with the values it holds for them). A span stops where an address in
    between is not held (a hole, an input, a bit field, an output of unknown value or one
    forced to FC5/FC6) and at the request limit (``max_bits`` / ``max_registers``, never
    inside a value); a span of one coil or one 16-bit register is FC5/FC6. Outputs forced
    to FC5/FC6, and every output when ``allow_multiple`` is off, are written one request
    per coil/register, in address order.
    """
    ops: list[WriteOp] = []
    for table, single, multiple, limit in (
        (Table.COILS, Function.WRITE_SINGLE_COIL, Function.WRITE_MULTIPLE_COILS, max_bits),
        (
            Table.HOLDING_REGISTERS,
            Function.WRITE_SINGLE_REGISTER,
            Function.WRITE_MULTIPLE_REGISTERS,
            max_registers,
        ),
    ):
        mine = sorted(
            ((p, v) for p, v in changes if p.table is table and p.bit is None),
            key=lambda pv: pv[0].address,
        )
        changed = {p.channel for p, _ in mine}
        if not allow_multiple:
            spans = [[pv] for pv in mine]
        else:
            fill = {
                p.address: (p, v)
                for p, v in held
                if p.table is table
                and p.bit is None
                and p.write_fc not in (5, 6)
                and p.channel not in changed
            }
            spans = _spans(mine, fill, limit)
        for span in spans:
            for op in _ops(span, _words(span), single, multiple, limit, allow_multiple):
                op.filled = frozenset(p.channel for p in op.points) - changed
                ops.append(op)
    return ops


def _words(span: list[tuple[Point, Value]]) -> list[bool] | list[int]:
    if span[0][0].table.is_bits:
        return [bool(v) for _, v in span]
    return [w for p, v in span for w in regvalues.encode(p.dtype, p.raw_of(v), p.order, p.length)]


def _spans(
    changes: list[tuple[Point, Value]],
    fill: dict[int, tuple[Point, Value]],
    limit: int,
) -> list[list[tuple[Point, Value]]]:
    """Sorted changes (one table) grouped into spans, the held outputs in between filled in;
    an output forced to FC5/FC6 is a span of its own."""
    spans: list[list[tuple[Point, Value]]] = []
    for p, v in changes:
        last = spans[-1] if spans else None
        if last is not None and p.write_fc not in (5, 6) and last[-1][0].write_fc not in (5, 6):
            between = _filler(last[-1][0].end, p.address, fill)
            if between is not None and p.end - last[0][0].address <= limit:
                last.extend(between)
                last.append((p, v))
                continue
        spans.append([(p, v)])
    return spans


def _filler(
    start: int, end: int, fill: dict[int, tuple[Point, Value]]
) -> list[tuple[Point, Value]] | None:
    """The held outputs covering every address from ``start`` up to ``end``, or None
    where an address is not held (or a held value runs past ``end``)."""
    out: list[tuple[Point, Value]] = []
    address = start
    while address < end:
        found = fill.get(address)
        if found is None:
            return None
        out.append(found)
        address = found[0].end
    return out if address == end else None


def _ops(
    run: list[tuple[Point, Value]],
    words: list[bool] | list[int],
    single: int,
    multiple: int,
    limit: int,
    allow_multiple: bool,
) -> list[WriteOp]:
    points = [p for p, _ in run]
    forced = next((p.write_fc for p in points if p.write_fc is not None), None)
    use_single = forced == single or (forced is None and len(words) == 1) or not allow_multiple
    if use_single:
        return [WriteOp(single, points[0].address + i, [w], points) for i, w in enumerate(words)]
    ops: list[WriteOp] = []
    address, offset = points[0].address, 0
    chunk: list[bool] | list[int] = []
    chunk_points: list[Point] = []
    for p in points:  # split at the limit, never inside a value
        mine = words[offset : offset + p.width]
        offset += p.width
        if chunk and len(chunk) + len(mine) > limit:
            ops.append(WriteOp(multiple, address, chunk, chunk_points))
            address, chunk, chunk_points = address + len(chunk), [], []
        chunk = chunk + mine
        chunk_points.append(p)
    ops.append(WriteOp(multiple, address, chunk, chunk_points))
    return ops
