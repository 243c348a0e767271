"""Request planning, sans-I/O: which reads and writes cover a module's points.

* Reads: points of one table are sorted and coalesced into blocks of adjacent addresses
  (or across holes up to ``gap``), each within the protocol limit (125 registers,
  2000 bits) or the module's own lower limit.
* Writes: changed outputs become runs of adjacent addresses; a run of one coil or one
  16-bit register uses FC5/FC6, longer runs and 32-bit values FC15/FC16 (split at the
  1968-bit / 123-register limits), unless a group forces its function code.
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

    def describe(self) -> str:
        return f"FC{self.function} at {self.address} x{len(self.values)}"


def plan_writes(changes: list[tuple[Point, Value]], allow_multiple: bool = True) -> list[WriteOp]:
    """Write requests for changed coil and register outputs (not bits inside registers)."""
    ops: list[WriteOp] = []
    coils = sorted(
        ((p, v) for p, v in changes if p.table is Table.COILS), key=lambda pv: pv[0].address
    )
    registers = sorted(
        ((p, v) for p, v in changes if p.table is Table.HOLDING_REGISTERS and p.bit is None),
        key=lambda pv: pv[0].address,
    )
    for run in _runs(coils):
        bits = [bool(v) for _, v in run]
        ops.extend(
            _ops(
                run,
                bits,
                Function.WRITE_SINGLE_COIL,
                Function.WRITE_MULTIPLE_COILS,
                MAX_WRITE_BITS,
                allow_multiple,
            )
        )
    for run in _runs(registers):
        words = [
            w for p, v in run for w in regvalues.encode(p.dtype, p.raw_of(v), p.order, p.length)
        ]
        ops.extend(
            _ops(
                run,
                words,
                Function.WRITE_SINGLE_REGISTER,
                Function.WRITE_MULTIPLE_REGISTERS,
                MAX_WRITE_REGISTERS,
                allow_multiple,
            )
        )
    return ops


def _runs(
    items: list[tuple[Point, Value]],
) -> list[list[tuple[Point, Value]]]:
    """Split sorted (point, value) pairs into runs of adjacent addresses with the same forced function."""
    runs: list[list[tuple[Point, Value]]] = []
    for p, v in items:
        last = runs[-1][-1][0] if runs else None
        if (
            last is not None
            and p.address == last.end
            and p.write_fc == last.write_fc
            and p.write_fc not in (5, 6)
        ):
            runs[-1].append((p, v))
        else:
            runs.append([(p, v)])
    return runs


def _ops(
    run: list[tuple[Point, Value]],
    words: list[bool] | list[int],
    single: int,
    multiple: int,
    limit: int,
    allow_multiple: bool,
) -> list[WriteOp]:
    points = [p for p, _ in run]
    forced = points[0].write_fc
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
