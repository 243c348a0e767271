"""Where a Modbus channel lives on the wire: the four tables and one point (used by the config,
the request planner and the simulator alike)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from fieldgate.image import DataType, Kind

from .values import WORDS


class Table(StrEnum):
    COILS = "coils"  # FC1 read, FC5/FC15 write
    DISCRETE_INPUTS = "discrete_inputs"  # FC2
    HOLDING_REGISTERS = "holding_registers"  # FC3 read, FC6/FC16 write
    INPUT_REGISTERS = "input_registers"  # FC4

    @property
    def is_bits(self) -> bool:
        return self in (Table.COILS, Table.DISCRETE_INPUTS)

    @property
    def read_function(self) -> int:
        return {
            Table.COILS: 1,
            Table.DISCRETE_INPUTS: 2,
            Table.HOLDING_REGISTERS: 3,
            Table.INPUT_REGISTERS: 4,
        }[self]


@dataclass(frozen=True)
class Point:
    """One channel and where it lives on the wire."""

    channel: str
    kind: Kind
    index: int
    table: Table
    address: int  # bit address, or first register
    dtype: DataType
    word_order: str = "big"
    bit: int | None = None  # digital channel (or si/so byte: 0 low, 8 high) inside a register
    write_fc: int | None = None
    period: float | None = None

    @property
    def width(self) -> int:
        """Registers or bits this point occupies."""
        return 1 if self.table.is_bits or self.bit is not None else WORDS[self.dtype]

    @property
    def end(self) -> int:
        return self.address + self.width
