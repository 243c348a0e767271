"""Where a Modbus channel lives on the wire: the four tables and one point (used by the config,
the request planner and the simulator alike)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from fieldgate import registers
from fieldgate.image import DataType, Engineering, Kind


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
    dtype: DataType  # as the device holds it
    order: str = "ABCD"  # byte and word order of a value wider than a byte (fieldgate.registers)
    bit: int | None = None  # a field inside a register: its lowest bit
    bits: int = 1  # that field's width: 1 a digital channel, 8 an si/so byte, else a bit field
    write_fc: int | None = None
    period: float | None = None
    length: int | None = None  # STRING: its bytes
    engineering: Engineering | None = None  # converted once, here (docs/modbus.md "Scaling")
    label: str = ""

    @property
    def width(self) -> int:
        """Registers or bits this point occupies."""
        if self.table.is_bits or self.bit is not None:
            return 1
        return registers.width(self.dtype, self.length)

    @property
    def end(self) -> int:
        return self.address + self.width

    @property
    def image_type(self) -> DataType:
        """The channel's type in the process image: float64 once a gain or offset converts it."""
        if self.engineering is not None and self.engineering.converts:
            return DataType.FLOAT64
        return self.dtype

    def value_of(self, raw: int | float | str) -> object:
        """What the image gets for a raw value read: engineering units, with over-/under-range
        quality outside the range."""
        eng = self.engineering
        if eng is None or isinstance(raw, str):
            return raw
        value = eng.from_raw(raw)
        quality = eng.range_quality(value)
        if not eng.converts and self.dtype.is_integer:
            value = int(value)
        return value if quality is None else (value, quality)

    def raw_of(self, value: object) -> object:
        """The raw value to write for an image value (the inverse of :meth:`value_of`)."""
        eng = self.engineering
        if eng is None or isinstance(value, str | bool) or not isinstance(value, int | float):
            return value
        return eng.to_raw(value)

    @property
    def describe_order(self) -> str:
        return "" if self.width == 1 and self.dtype is not DataType.STRING else self.order
