"""A channel group of a Modbus device: where its channels live, their type and order, their
conversion to engineering units; every check a group can make on its own."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator
from pydantic_core import PydanticCustomError

from fieldgate.image import DataType, Engineering, Kind
from fieldgate.topology import StrictModel

from . import values as regvalues
from .points import Table


def _invalid(message: str, loc: tuple[str | int, ...] = ()) -> PydanticCustomError:
    """A validation error whose message is ours alone (no "Value error," prefix); ``loc``
    names the field below the validated object it is about (core reports it there)."""
    return PydanticCustomError(
        "modbus_config",
        message.replace("{", "{{").replace("}", "}}"),
        {"loc": loc} if loc else None,
    )


# Which tables each channel kind may live in.
_ALLOWED = {
    Kind.DI: {Table.DISCRETE_INPUTS, Table.COILS, Table.INPUT_REGISTERS, Table.HOLDING_REGISTERS},
    Kind.DO: {Table.COILS, Table.HOLDING_REGISTERS},
    Kind.AI: {Table.INPUT_REGISTERS, Table.HOLDING_REGISTERS},
    Kind.AO: {Table.HOLDING_REGISTERS},
    Kind.SI: {Table.INPUT_REGISTERS, Table.HOLDING_REGISTERS},
    Kind.SO: {Table.HOLDING_REGISTERS},
}

RegisterType = Literal[
    "int16", "uint16", "int32", "uint32", "float32", "int64", "uint64", "float64", "string"
]
OrderName = Literal["ABCD", "CDAB", "BADC", "DCBA", "ABCDEFGH", "GHEFCDAB", "BADCFEHG", "HGFEDCBA"]
_SCALING_FIELDS = ("gain", "offset", "divider", "decimals", "unit", "range")


class ChannelGroup(StrictModel):
    """``count`` consecutive channels of one kind, starting at ``address`` in ``table``.

    ``si`` / ``so`` declare a raw byte block (special input / output, e.g. a counter's data):
    ``count`` bytes, two per register, ``byte_order`` big = byte 0 is the high byte of the
    first register (the bytes as they travel on the wire), little = its low byte.

    Analog channels in registers have a ``type`` (16/32/64-bit integers, 32/64-bit floats,
    text of ``length`` bytes) in an ``order`` (ABCD, CDAB, BADC, DCBA), or are ``bits``-wide
    fields of a register; ``gain``/``offset`` (or ``divider``), ``decimals``, ``unit`` and
    ``range`` convert them to engineering units once, here (docs/modbus.md, "Scaling").
    """

    kind: Literal["di", "do", "ai", "ao", "si", "so"]
    table: Table
    address: int = Field(ge=0, le=0xFFFF, description="first PDU address (0-based, as on the wire)")
    count: int = Field(1, ge=1, le=2000, description="number of channels")
    type: RegisterType | None = Field(
        None,
        description="analog channels: int16 (default), uint16, int32, uint32, float32, int64, "
        "uint64, float64, or string (text of length bytes)",
    )
    order: OrderName | None = Field(
        None,
        description="values wider than a byte: ABCD (default: high byte, high word first), CDAB "
        "(word swap), BADC (byte swap), DCBA (both); 64-bit ones also ABCDEFGH, GHEFCDAB, "
        "BADCFEHG, HGFEDCBA",
    )
    word_order: Literal["big", "little"] | None = Field(
        None, description="former spelling of order: big = ABCD, little = CDAB"
    )
    registers: int | None = Field(
        None,
        ge=1,
        le=123,
        description="registers each channel takes, as the device's map gives them: checked "
        "against type (a string's length is twice this when not given)",
    )
    length: int | None = Field(
        None, ge=1, le=246, description="type string: bytes of text (two per register)"
    )
    bits: int | None = Field(
        None,
        ge=1,
        le=16,
        description="analog channels: fields of this many bits inside registers, from first_bit, "
        "LSB first (unsigned); a field never crosses a register",
    )
    byte_order: Literal["big", "little"] | None = Field(
        None,
        description="si/so byte blocks: big (default) = byte 0 is the first register's high byte, little = its low byte",
    )
    first_bit: int = Field(
        0,
        ge=0,
        le=15,
        description="digital channels (and bits fields) in registers: bit of the first channel; the next ones follow, LSB first, across registers",
    )
    write_fc: Literal[5, 6, 15, 16] | None = Field(
        None,
        description="outputs: force a write function (default: single writes for one point, multiple for runs)",
    )
    poll_ms: int | None = Field(
        None,
        ge=1,
        le=3_600_000,
        description="read this group at most this often (default: every module poll)",
    )
    gain: float | None = Field(
        None, description="engineering value = raw x gain + offset (default 1)"
    )
    offset: float | None = Field(None, description="added after the gain (default 0)")
    divider: float | None = Field(
        None, gt=0, description="engineering value = raw / divider + offset (instead of gain)"
    )
    decimals: int | None = Field(
        None, ge=0, le=15, description="round the engineering value to this many decimals"
    )
    unit: str | None = Field(
        None, max_length=32, description="engineering unit (V, A, kWh, °C): OPC UA, Sparkplug"
    )
    range: tuple[float | None, float | None] | None = Field(
        None,
        description="[low, high] in engineering units (null: open): quality over-/under-range "
        "outside it; an output write outside it is refused",
    )
    label: str | None = Field(
        None, max_length=80, description="what the device's map calls it, for descriptions"
    )

    @model_validator(mode="after")
    def _consistent(self) -> ChannelGroup:
        kind = Kind(self.kind)
        if self.table not in _ALLOWED[kind]:
            allowed = ", ".join(sorted(t.value for t in _ALLOWED[kind]))
            raise _invalid(
                f"{self.kind} channels cannot live in {self.table.value}; use one of: {allowed}"
            )
        analog_registers = not (kind.is_digital or kind.is_special or self.table.is_bits)
        if self.type is not None and not analog_registers:
            raise _invalid(
                f"type applies to analog channels in registers, not to {self.kind} channels"
            )
        self._check_order(analog_registers)
        if self.byte_order is not None and not kind.is_special:
            raise _invalid(f"byte_order applies to si/so byte blocks, not to {self.kind} channels")
        if kind.is_special and self.first_bit:
            raise _invalid(
                "first_bit applies to digital channels; si/so blocks start at a register"
            )
        self._check_bits(analog_registers)
        self._check_text()
        self._check_registers()
        self._check_scaling(analog_registers)
        if self.write_fc is not None:
            if not kind.is_output:
                raise _invalid("write_fc applies to outputs (do, ao) only")
            expected = (5, 15) if self.table is Table.COILS else (6, 16)
            if self.write_fc not in expected:
                raise _invalid(
                    f"write_fc {self.write_fc} does not write {self.table.value}; use {expected[0]} or {expected[1]}"
                )
            if self.write_fc == 6 and self.words > 1:
                raise _invalid(
                    f"{_a(self.dtype)} takes {self.words} registers: it needs write_fc 16 "
                    "(its registers written at once)"
                )
        if self.last_address > 0xFFFF:
            raise _invalid(f"the group runs past address 65535 (ends at {self.last_address})")
        return self

    def _check_order(self, analog_registers: bool) -> None:
        if self.order is None and self.word_order is None:
            return
        if not analog_registers or self.bits is not None:
            raise _invalid(
                f"order applies to values in registers, not to {self.kind} channels"
                + (" or bit fields" if self.bits is not None else "")
            )
        if (
            self.order is not None
            and self.word_order is not None
            and regvalues.order_name(self.order) != regvalues.order_name(self.word_order)
        ):
            raise _invalid(
                f"order {self.order} and word_order {self.word_order} disagree; give order alone"
            )
        if self.order is not None and self.words == 1 and self.type != "string":
            raise _invalid(
                f"order applies to values of two registers or more; {_a(self.dtype)} is one "
                "register, big-endian (the Modbus rule)"
            )
        if self.order is not None and len(self.order) == 8 and self.words != 4:
            raise _invalid(
                f"order {self.order} names the 8 bytes of a 64-bit value; {_a(self.dtype)} "
                f"has {2 * self.words}: use {regvalues.order_name(self.order)}"
            )

    def _check_bits(self, analog_registers: bool) -> None:
        if self.bits is None:
            return
        if not analog_registers or self.type is not None:
            raise _invalid(
                "bits applies to analog channels in registers without a type (each is an "
                "unsigned field of the register)"
            )
        for i in range(self.count):
            start = (self.first_bit + i * self.bits) % 16
            if start + self.bits > 16:
                raise _invalid(
                    f"channel {i} (bits {start}..{start + self.bits - 1}) would cross into the "
                    "next register; a bit field stays inside one register"
                )

    def _check_text(self) -> None:
        if self.type == "string":
            if self.length is None and self.registers is None:
                raise _invalid("type string needs its length in bytes (or registers)")
        elif self.length is not None:
            raise _invalid("length applies to type string")

    def _check_registers(self) -> None:
        if self.registers is None:
            return
        if self.type == "string":
            if self.length is not None and regvalues.string_words(self.length) != self.registers:
                raise _invalid(
                    f"text of {self.length} bytes takes {regvalues.string_words(self.length)} "
                    f"registers, not {self.registers}"
                )
            return
        if Kind(self.kind).is_digital or Kind(self.kind).is_special or self.bits is not None:
            raise _invalid("registers applies to values that take whole registers")
        if self.registers != self.words:
            raise _invalid(
                f"{_a(self.dtype)} takes {self.words} register{'s' if self.words > 1 else ''}, "
                f"the map gives {self.registers}: give the type that fits {self.registers} "
                f"register{'s' if self.registers > 1 else ''}"
                + (" (int32, uint32, float32)" if self.registers == 2 else "")
                + (" (int64, uint64, float64)" if self.registers == 4 else "")
            )

    def _check_scaling(self, analog_registers: bool) -> None:
        given = [f for f in _SCALING_FIELDS if getattr(self, f) is not None]
        if not given:
            return
        if not analog_registers or self.type == "string":
            raise _invalid(
                f"{given[0]} applies to numbers in registers, not to "
                + ("text" if self.type == "string" else f"{self.kind} channels")
            )
        if self.gain is not None and self.divider is not None:
            raise _invalid("give gain or divider, not both")
        if self.gain == 0:
            raise _invalid("gain 0 would make every value the offset; give a gain other than 0")
        if self.range is not None:
            low, high = self.range
            if low is not None and high is not None and low > high:
                raise _invalid(f"range [{low}, {high}]: low is above high")

    @property
    def dtype(self) -> DataType:
        if Kind(self.kind).is_digital:
            return DataType.BOOL
        if Kind(self.kind).is_special:
            return DataType.UINT8
        if self.bits is not None:
            return DataType.UINT16
        return DataType(self.type or "int16")

    @property
    def text_length(self) -> int | None:
        if self.type != "string":
            return None
        return self.length if self.length is not None else 2 * (self.registers or 0)

    @property
    def words(self) -> int:
        """Registers one channel takes (a field inside a register: 1)."""
        if self.bits is not None or Kind(self.kind).is_digital or Kind(self.kind).is_special:
            return 1
        return regvalues.width(self.dtype, self.text_length)

    @property
    def byte_order_name(self) -> str:
        """The order of a value, as fieldgate.registers names it."""
        return regvalues.order_name(self.order or self.word_order or "ABCD")

    def engineering(self) -> Engineering | None:
        """The conversion to engineering units, None when the group asks for none."""
        if all(getattr(self, f) is None for f in _SCALING_FIELDS):
            return None
        low, high = self.range if self.range is not None else (None, None)
        return Engineering(
            self.dtype,
            self.gain if self.gain is not None else 1.0,
            self.offset or 0.0,
            self.decimals,
            self.unit or "",
            low,
            high,
            self.divider,
        )

    @property
    def last_address(self) -> int:
        if self.table.is_bits:
            return self.address + self.count - 1
        if Kind(self.kind).is_special:
            return self.address + (self.count - 1) // 2
        if Kind(self.kind).is_digital:
            return self.address + (self.first_bit + self.count - 1) // 16
        if self.bits is not None:
            return self.address + (self.first_bit + self.count * self.bits - 1) // 16
        return self.address + self.count * self.words - 1


def _a(dtype: DataType) -> str:
    """``an int16``, ``a float32``."""
    return f"{'an' if dtype.value[0] in 'aeiou' else 'a'} {dtype.value}"
