"""Topology models of the ``modbus`` back and their expansion into points.

A module declares channel groups by Modbus table (coils, discrete inputs, holding
registers, input registers; :mod:`.groups`), or names a ``model`` (one of the topology's
``models:``, :mod:`.models`, or a preset), or both (the model's channels first).
:func:`module_points` turns a module into :class:`Point` objects: one per channel, saying
where it lives on the wire and how to convert it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

from pydantic import Field, PrivateAttr, ValidationInfo, model_validator

from fieldgate.image import ChannelSpec, ErrorMode, Kind, Source, channel_id
from fieldgate.topology import ModuleConfig, SerialBackConfig

from . import presets
from .codec import (
    MAX_READ_BITS,
    MAX_READ_REGISTERS,
    MAX_WRITE_BITS,
    MAX_WRITE_REGISTERS,
    inter_frame_gap,
)
from .groups import ChannelGroup, _invalid
from .models import ModbusDeviceModel
from .plan import ReadBlock, plan_reads
from .points import Point, Table

_MODEL_DEFAULTS = (
    "max_read_registers",
    "max_read_bits",
    "coalesce_gap",
    "max_write_registers",
    "max_write_bits",
    "write_span",
)
"""What a topology's model gives its modules where they say nothing."""


class ModbusModuleConfig(ModuleConfig):
    address: int = Field(ge=1, le=247, description="Modbus unit id (slave address)")
    model: str | None = Field(
        None,
        description=f"a model of the topology's models, or a preset: {', '.join(presets.names())}",
    )
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
    max_write_registers: int = Field(
        MAX_WRITE_REGISTERS,
        ge=1,
        le=MAX_WRITE_REGISTERS,
        description="largest FC16 write (a write span is split here)",
    )
    max_write_bits: int = Field(
        MAX_WRITE_BITS,
        ge=1,
        le=MAX_WRITE_BITS,
        description="largest FC15 write (a write span is split here)",
    )
    write_span: bool = Field(
        True,
        description="write the outputs changed in one batch as one FC15/FC16 from the lowest "
        "to the highest changed address, the outputs in between with the values the gateway "
        "holds (false: only adjacent changes share a request)",
    )

    _model: ModbusDeviceModel | None = PrivateAttr(None)  # the topology's model it names

    @model_validator(mode="after")
    def _complete(self, info: ValidationInfo) -> ModbusModuleConfig:
        self._resolve_model(info.context or {})
        if self.model is None and not self.channels:
            raise _invalid("a module needs a model (yours or a preset) or a channels list")
        self._check_counts()
        groups = self.groups()
        _check_output_overlap(groups)
        widest = max((g.words for g in groups if not g.table.is_bits), default=1)
        if widest > self.max_read_registers:
            raise _invalid(
                f"a channel takes {widest} registers, more than max_read_registers "
                f"{self.max_read_registers}: it could never be read whole",
                ("max_read_registers",),
            )
        widest_out = max(
            (g.words for g in groups if Kind(g.kind).is_output and not g.table.is_bits), default=1
        )
        if widest_out > self.max_write_registers:
            raise _invalid(
                f"an output takes {widest_out} registers, more than max_write_registers "
                f"{self.max_write_registers}: it could never be written whole",
                ("max_write_registers",),
            )
        return self

    def _resolve_model(self, context: dict[str, Any]) -> None:
        """``model`` names a model of the topology (``models:``) or a preset; the topology's
        model gives its read limits where the module gives none."""
        if self.model is None:
            self._model = None
            return
        found = context.get("models", {}).get(self.model)
        if found is None and self._model is not None:
            return  # validated before (an assignment re-validates without the topology)
        if found is not None:
            self._model = found
            for name in _MODEL_DEFAULTS:
                limit = getattr(found, name)
                if limit is not None and name not in self.model_fields_set:
                    self.__dict__[name] = limit  # (no re-validation: the model checked it)
            return
        if presets.find(self.model) is not None:
            return
        if self.model in context.get("model_names", ()):
            raise _invalid(
                f"model '{self.model}' has errors of its own (models.{self.model})", ("model",)
            )
        mine = sorted(context.get("models", {}))
        raise _invalid(
            f"unknown model '{self.model}'; "
            + (f"the topology's models: {', '.join(mine)}; " if mine else "")
            + f"presets: {', '.join(presets.names())}; or leave model out and declare channels",
            ("model",),
        )

    def _model_groups(self) -> list[ChannelGroup]:
        """The groups the model gives: the topology's model's, or the preset's."""
        if self._model is not None:
            return list(self._model.channels)
        preset = presets.find(self.model) if self.model else None
        return [ChannelGroup(**raw) for raw in preset.groups] if preset else []

    def _check_counts(self) -> None:
        """``counts`` keeps the first N channels of a kind of the model: 0 up to what it has."""
        for kind, n in self.counts.items():
            if n < 0:
                raise _invalid(f"must be 0 or more (got {n})", ("counts", kind))
            if self.model is None:
                raise _invalid(
                    "counts applies to a model's channels; this module has no model",
                    ("counts", kind),
                )
            base = self._model_groups()
            have = sum(g.count for g in base if g.kind == kind)
            if n > have:
                kinds = ", ".join(
                    f"{sum(g.count for g in base if g.kind == k)} {k.upper()}"
                    for k in dict.fromkeys(g.kind for g in base)
                )
                has = f"{have} {kind.upper()}" if have else f"no {kind.upper()}, only {kinds}"
                raise _invalid(f"{self.model} has {has} (got {n})", ("counts", kind))

    def groups(self) -> list[ChannelGroup]:
        """The model's groups (cut to ``counts``) followed by the declared ones."""
        out: list[ChannelGroup] = []
        left = dict(self.counts)
        for group in self._model_groups():
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
    if g.bits is not None:  # a field covers its bit cells
        return [
            (
                g.table,
                g.address + (g.first_bit + i * g.bits + b) // 16,
                (g.first_bit + i * g.bits + b) % 16,
            )
            for i in range(g.count)
            for b in range(g.bits)
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
    if g.bits is not None:
        bit = g.first_bit + i * g.bits
        return g.address + bit // 16, bit % 16
    return g.address + i * g.words, None


def _field_bits(g: ChannelGroup) -> int:
    if Kind(g.kind).is_special:
        return 8
    return g.bits if g.bits is not None else 1


def _label(g: ChannelGroup, i: int) -> str:
    if not g.label:
        return ""
    return g.label if g.count == 1 else f"{g.label} [{i}]"


def module_points(back: str, module: ModbusModuleConfig) -> list[Point]:
    points: list[Point] = []
    next_index = {k: 0 for k in Kind}
    for g in module.groups():
        kind = Kind(g.kind)
        period = g.poll_ms / 1000 if g.poll_ms else None
        engineering = g.engineering()
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
                    order=g.byte_order_name,
                    bit=bit,
                    bits=_field_bits(g),
                    write_fc=g.write_fc,
                    period=period,
                    length=g.text_length,
                    engineering=engineering,
                    label=_label(g, i),
                )
            )
    return points


def device_specs(back: str, modules: Sequence[ModbusModuleConfig]) -> list[ChannelSpec]:
    """The channels of a Modbus back's modules (RTU and TCP alike)."""
    specs = []
    for m in modules:
        for p in module_points(back, m):
            error_mode, shutdown_mode = (
                m.output_modes(p.kind, p.index) if p.kind.is_output else (ErrorMode(), None)
            )
            specs.append(
                ChannelSpec(
                    p.channel,
                    p.kind,
                    Source(back, m.address, p.index),
                    dtype=p.image_type,
                    error_mode=error_mode,
                    shutdown_mode=shutdown_mode,
                    engineering=p.engineering,
                    length=p.length,
                    label=p.label,
                )
            )
    return specs


def poll_blocks(back: str, module: ModbusModuleConfig) -> list[ReadBlock]:
    """The reads of one poll of ``module`` with every group due (an output-only module is
    read back): what validate's poll budget counts."""
    points = [p for p in module_points(back, module) if not p.kind.is_output]
    if not points:
        points = module_points(back, module)
    return plan_reads(
        points, module.max_read_registers, module.max_read_bits, gap=module.coalesce_gap
    )


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
        return device_specs(self.name, self.modules)

    def points(self) -> dict[int, list[Point]]:
        return {m.address: module_points(self.name, m) for m in self.modules}

    def poll_requests(self, module: ModuleConfig) -> int | None:
        assert isinstance(module, ModbusModuleConfig)
        return len(poll_blocks(self.name, module))

    def poll_wire_time(self, module: ModuleConfig) -> float | None:
        """Worst case on the wire of one poll (``validate``'s poll budget): every read block
        due at once, each an 8-byte request, its reply, and the t3.5 silence before each."""
        assert isinstance(module, ModbusModuleConfig)
        timing = self.timing()
        gap = (
            inter_frame_gap(self.baudrate)
            if self.inter_frame_ms is None
            else self.inter_frame_ms / 1000
        )
        total = 0.0
        for block in poll_blocks(self.name, module):
            data = (block.count + 7) // 8 if block.table.is_bits else 2 * block.count
            total += timing.wire_time(8 + 5 + data) + 2 * gap
        return total
