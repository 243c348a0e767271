"""Topology models of the ``modbus`` back and their expansion into points.

A module declares channel groups by Modbus table (coils, discrete inputs, holding
registers, input registers), or names a ``model`` preset, or both (preset channels
first). :func:`module_points` turns a module into :class:`Point` objects: one per
channel, saying where it lives on the wire and how to convert it.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from fieldgate.image import ChannelSpec, DataType, ErrorMode, Kind, Source, channel_id
from fieldgate.topology import ModuleConfig, SerialBackConfig, StrictModel

from . import presets
from .codec import MAX_READ_BITS, MAX_READ_REGISTERS, inter_frame_gap
from .plan import plan_reads
from .points import Point, Table
from .values import WORDS


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

RegisterType = Literal["int16", "uint16", "int32", "uint32", "float32"]


class ChannelGroup(StrictModel):
    """``count`` consecutive channels of one kind, starting at ``address`` in ``table``.

    ``si`` / ``so`` declare a raw byte block (special input / output, e.g. a counter's data):
    ``count`` bytes, two per register, ``byte_order`` big = byte 0 is the high byte of the
    first register (the bytes as they travel on the wire), little = its low byte.
    """

    kind: Literal["di", "do", "ai", "ao", "si", "so"]
    table: Table
    address: int = Field(ge=0, le=0xFFFF, description="first PDU address (0-based, as on the wire)")
    count: int = Field(1, ge=1, le=2000, description="number of channels")
    type: RegisterType | None = Field(
        None, description="analog channels: register data type (default int16)"
    )
    word_order: Literal["big", "little"] = Field(
        "big", description="32-bit types: big = high word first, little = low word first"
    )
    byte_order: Literal["big", "little"] | None = Field(
        None,
        description="si/so byte blocks: big (default) = byte 0 is the first register's high byte, little = its low byte",
    )
    first_bit: int = Field(
        0,
        ge=0,
        le=15,
        description="digital channels in registers: bit of the first channel; the next ones follow, LSB first, across registers",
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

    @model_validator(mode="after")
    def _consistent(self) -> ChannelGroup:
        kind = Kind(self.kind)
        if self.table not in _ALLOWED[kind]:
            allowed = ", ".join(sorted(t.value for t in _ALLOWED[kind]))
            raise _invalid(
                f"{self.kind} channels cannot live in {self.table.value}; use one of: {allowed}"
            )
        if self.type is not None and (kind.is_digital or kind.is_special or self.table.is_bits):
            raise _invalid(
                f"type applies to analog channels in registers, not to {self.kind} channels"
            )
        if self.byte_order is not None and not kind.is_special:
            raise _invalid(f"byte_order applies to si/so byte blocks, not to {self.kind} channels")
        if kind.is_special and self.first_bit:
            raise _invalid(
                "first_bit applies to digital channels; si/so blocks start at a register"
            )
        if self.write_fc is not None:
            if not kind.is_output:
                raise _invalid("write_fc applies to outputs (do, ao) only")
            expected = (5, 15) if self.table is Table.COILS else (6, 16)
            if self.write_fc not in expected:
                raise _invalid(
                    f"write_fc {self.write_fc} does not write {self.table.value}; use {expected[0]} or {expected[1]}"
                )
            if self.write_fc == 6 and WORDS[self.dtype] == 2:
                raise _invalid("32-bit values need write_fc 16 (two registers written at once)")
        if self.last_address > 0xFFFF:
            raise _invalid(f"the group runs past address 65535 (ends at {self.last_address})")
        return self

    @property
    def dtype(self) -> DataType:
        if Kind(self.kind).is_digital:
            return DataType.BOOL
        if Kind(self.kind).is_special:
            return DataType.UINT8
        return DataType(self.type or "int16")

    @property
    def last_address(self) -> int:
        if self.table.is_bits:
            return self.address + self.count - 1
        if Kind(self.kind).is_special:
            return self.address + (self.count - 1) // 2
        if Kind(self.kind).is_digital:
            return self.address + (self.first_bit + self.count - 1) // 16
        return self.address + self.count * WORDS[self.dtype] - 1


class ModbusModuleConfig(ModuleConfig):
    address: int = Field(ge=1, le=247, description="Modbus unit id (slave address)")
    model: str | None = Field(None, description=f"preset: {', '.join(presets.names())}")
    channels: list[ChannelGroup] = Field(
        default_factory=list, description="channel groups (after the preset's, if any)"
    )
    counts: dict[Literal["di", "do", "ai", "ao"], int] = Field(
        default_factory=dict,
        description="use only the first N channels of a kind from the preset, e.g. {ai: 1}; at most what the preset has",
    )
    max_read_registers: int = Field(
        MAX_READ_REGISTERS,
        ge=1,
        le=MAX_READ_REGISTERS,
        description="largest coalesced register read",
    )
    max_read_bits: int = Field(
        MAX_READ_BITS, ge=1, le=MAX_READ_BITS, description="largest coalesced bit read"
    )
    coalesce_gap: int = Field(
        0,
        ge=0,
        le=100,
        description="also read across holes of up to this many unused registers/bits",
    )

    @field_validator("model")
    @classmethod
    def _known_model(cls, model: str | None) -> str | None:
        if model is not None and presets.find(model) is None:
            raise _invalid(
                f"unknown model '{model}'; presets: {', '.join(presets.names())}; or leave model out and declare channels"
            )
        return model

    @model_validator(mode="after")
    def _complete(self) -> ModbusModuleConfig:
        if self.model is None and not self.channels:
            raise _invalid("a module needs a model preset or a channels list")
        self._check_counts()
        _check_output_overlap(self.groups())
        return self

    def _check_counts(self) -> None:
        """``counts`` keeps the first N channels of a kind of the preset: 0 up to what it has."""
        preset = presets.find(self.model) if self.model else None
        for kind, n in self.counts.items():
            if n < 0:
                raise _invalid(f"must be 0 or more (got {n})", ("counts", kind))
            if preset is None:
                raise _invalid(
                    "counts applies to a model preset's channels; this module has no model",
                    ("counts", kind),
                )
            have = sum(g["count"] for g in preset.groups if g["kind"] == kind)
            if n > have:
                has = (
                    f"{have} {kind.upper()}"
                    if have
                    else f"no {kind.upper()}, only {preset.description}"
                )
                raise _invalid(f"{preset.model} has {has} (got {n})", ("counts", kind))

    def groups(self) -> list[ChannelGroup]:
        """Preset groups (cut to ``counts``) followed by the declared ones."""
        out: list[ChannelGroup] = []
        preset = presets.find(self.model) if self.model else None
        left = dict(self.counts)
        for raw in preset.groups if preset else ():
            group = ChannelGroup(**raw)
            if group.kind in left:
                take = min(group.count, left[group.kind])
                left[group.kind] -= take
                if take == 0:
                    continue
                group = group.model_copy(update={"count": take})
            out.append(group)
        return out + list(self.channels)


def _check_output_overlap(groups: list[ChannelGroup]) -> None:
    owners: dict[tuple[Table, int] | tuple[Table, int, int], int] = {}
    for i, g in enumerate(groups):
        if not Kind(g.kind).is_output:
            continue
        for cell in _cells(g):
            if cell in owners and owners[cell] != i:
                raise _invalid(f"output channels overlap in {g.table.value} at address {cell[1]}")
            owners[cell] = i


def _cells(g: ChannelGroup) -> list[tuple[Table, int] | tuple[Table, int, int]]:
    if g.table.is_bits:
        return [(g.table, a) for a in range(g.address, g.address + g.count)]
    if Kind(g.kind).is_digital:
        return [
            (g.table, g.address + (g.first_bit + i) // 16, (g.first_bit + i) % 16)
            for i in range(g.count)
        ]
    if Kind(g.kind).is_special:  # a byte covers 8 bit cells of its register
        return [
            (g.table, g.address + i // 2, _byte_shift(g, i) + b)
            for i in range(g.count)
            for b in range(8)
        ]
    return [(g.table, a) for a in range(g.address, g.last_address + 1)]


def _byte_shift(g: ChannelGroup, i: int) -> int:
    """Where byte ``i`` of a si/so block sits in its register: 8 (high byte) or 0."""
    first_high = (g.byte_order or "big") == "big"
    return 8 if (i % 2 == 0) == first_high else 0


def _place(g: ChannelGroup, i: int) -> tuple[int, int | None]:
    """(address, bit inside the register or None) of channel ``i`` of a group."""
    if g.table.is_bits:
        return g.address + i, None
    if Kind(g.kind).is_special:  # two bytes per register
        return g.address + i // 2, _byte_shift(g, i)
    if Kind(g.kind).is_digital:
        bit = g.first_bit + i
        return g.address + bit // 16, bit % 16
    return g.address + i * WORDS[g.dtype], None


def module_points(back: str, module: ModbusModuleConfig) -> list[Point]:
    points: list[Point] = []
    next_index = {k: 0 for k in Kind}
    for g in module.groups():
        kind = Kind(g.kind)
        period = g.poll_ms / 1000 if g.poll_ms else None
        for i in range(g.count):
            index = next_index[kind]
            next_index[kind] += 1
            address, bit = _place(g, i)
            points.append(
                Point(
                    channel_id(back, module.address, kind, index),
                    kind,
                    index,
                    g.table,
                    address,
                    g.dtype,
                    word_order=g.word_order,
                    bit=bit,
                    write_fc=g.write_fc,
                    period=period,
                )
            )
    return points


class ModbusBackConfig(SerialBackConfig):
    type: Literal["modbus"] = "modbus"
    modules: list[ModbusModuleConfig] = Field(min_length=1)
    inter_frame_ms: float | None = Field(
        None,
        ge=0,
        le=1000,
        description="silence kept before each request; default 3.5 character times (1.75 ms above 19200 baud)",
    )

    def channel_specs(self) -> list[ChannelSpec]:
        specs = []
        for m in self.modules:
            for p in module_points(self.name, m):
                error_mode, shutdown_mode = (
                    m.output_modes(p.kind, p.index) if p.kind.is_output else (ErrorMode(), None)
                )
                specs.append(
                    ChannelSpec(
                        p.channel,
                        p.kind,
                        Source(self.name, m.address, p.index),
                        dtype=p.dtype,
                        error_mode=error_mode,
                        shutdown_mode=shutdown_mode,
                    )
                )
        return specs

    def points(self) -> dict[int, list[Point]]:
        return {m.address: module_points(self.name, m) for m in self.modules}

    def poll_wire_time(self, module: ModuleConfig) -> float | None:
        """Worst case on the wire of one poll (``validate``'s poll budget): every read block
        due at once, each an 8-byte request, its reply, and the t3.5 silence before each."""
        assert isinstance(module, ModbusModuleConfig)
        points = [p for p in module_points(self.name, module) if not p.kind.is_output]
        if not points:  # an output-only module is read back
            points = module_points(self.name, module)
        timing = self.timing()
        gap = (
            inter_frame_gap(self.baudrate)
            if self.inter_frame_ms is None
            else self.inter_frame_ms / 1000
        )
        total = 0.0
        for block in plan_reads(
            points, module.max_read_registers, module.max_read_bits, gap=module.coalesce_gap
        ):
            data = (block.count + 7) // 8 if block.table.is_bits else 2 * block.count
            total += timing.wire_time(8 + 5 + data) + 2 * gap
        return total
