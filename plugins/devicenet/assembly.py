"""Assembly instances built from the channels a front serves (seed-003 §4).

One instance per I/O category with channels, numbered from 0x64 in the order DO, AO, DI,
AI (empty categories take no number). Digital channels: 8 per byte, LSB = lowest
channel, each module starting a new byte (:func:`fieldgate.layout.pack_bits`). Analog
channels: one 16-bit little-endian word each (two's complement for signed values).

After them, numbered on, the *combined* instances fieldgate adds where a direction has
more than one category: "all outputs" (DO then AO) and "all inputs" (DI then AI),
concatenated. Every I/O connection path (:mod:`.paths`) names one instance, so a
connection that carries all inputs has a real assembly behind its path too.

Outputs reach the process image in one place, :meth:`Assemblies.consume` (poll, change of
state and cyclic data, Assembly and Application Set).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from fieldgate.image import Channel, DataType, Kind, ProcessImage, Value
from fieldgate.layout import bit_values, byte_value, of_kind, pack_bits

FIRST_INSTANCE = 0x64
CATEGORY_ORDER = (Kind.DO, Kind.AO, Kind.DI, Kind.AI)

Values = dict[str, Value]


def word_of(channel: Channel) -> int:
    value = channel.value
    if isinstance(value, float):
        value = max(-0x8000, min(0xFFFF, round(value)))
    return int(value) & 0xFFFF


def value_of_word(channel: Channel, word: int) -> int | float:
    signed = word - 0x10000 if word & 0x8000 else word
    data_type = channel.spec.data_type
    if data_type is DataType.UINT16 or data_type is DataType.UINT32:
        return word
    if data_type is DataType.FLOAT32:
        return float(signed)
    return signed


def plural(size: int) -> str:
    return f"{size} byte{'s' if size != 1 else ''}"


@dataclass
class Assembly:
    """The channels of one category (DO, AO, DI or AI)."""

    instance: int
    kind: Kind
    slots: list[Any]  # digital: lists of 8 channel slots; analog: channels

    @property
    def is_output(self) -> bool:
        return self.kind.is_output

    @property
    def size(self) -> int:
        return len(self.slots) if self.kind.is_digital else 2 * len(self.slots)

    @property
    def channels(self) -> list[Channel]:
        if self.kind.is_digital:
            return [c for group in self.slots for c in group if c is not None]
        return list(self.slots)

    @property
    def label(self) -> str:
        return f"{self.kind.value.upper()} assembly 0x{self.instance:02X} ({plural(self.size)})"

    @property
    def members(self) -> tuple[Assembly, ...]:
        return (self,)

    def data(self) -> bytes:
        if self.kind.is_digital:
            return bytes(byte_value(group) for group in self.slots)
        return b"".join(word_of(c).to_bytes(2, "little") for c in self.slots)

    def values(self, data: bytes) -> Values:
        """An output assembly's bytes (``len(data) == size``) as values of its channels; a word
        that does not fit its channel's type is left out (the channel keeps its value)."""
        values: Values = {}
        if self.kind.is_digital:
            for group, byte in zip(self.slots, data, strict=True):
                values.update(bit_values(group, byte))
            return values
        for i, channel in enumerate(self.slots):
            word = int.from_bytes(data[2 * i : 2 * i + 2], "little")
            try:
                values[channel.id] = channel.dtype.check(value_of_word(channel, word))
            except ValueError:
                pass
        return values


@dataclass
class Combined:
    """Every category assembly of one direction, concatenated (fieldgate's "all inputs" /
    "all outputs" instances)."""

    instance: int
    parts: tuple[Assembly, ...]

    @property
    def is_output(self) -> bool:
        return self.parts[0].is_output

    @property
    def size(self) -> int:
        return sum(a.size for a in self.parts)

    @property
    def channels(self) -> list[Channel]:
        return [c for a in self.parts for c in a.channels]

    @property
    def members(self) -> tuple[Assembly, ...]:
        return self.parts

    @property
    def label(self) -> str:
        what = "outputs" if self.is_output else "inputs"
        inside = " + ".join(
            f"{a.kind.value.upper()} 0x{a.instance:02X} ({plural(a.size)})" for a in self.parts
        )
        return f"all {what} assembly 0x{self.instance:02X}: {inside}"

    def data(self) -> bytes:
        return b"".join(a.data() for a in self.parts)

    def values(self, data: bytes) -> Values:
        values: Values = {}
        offset = 0
        for assembly in self.parts:
            values.update(assembly.values(data[offset : offset + assembly.size]))
            offset += assembly.size
        return values


AnyAssembly = Assembly | Combined


class Assemblies:
    def __init__(self, image: ProcessImage, channels: Sequence[Channel], origin: str = "devicenet"):
        self.image = image
        self.origin = origin
        self.channels = list(channels)
        self.instances: dict[int, AnyAssembly] = {}
        number = FIRST_INSTANCE
        for kind in CATEGORY_ORDER:
            members = of_kind(channels, kind)
            if not members:
                continue
            slots = pack_bits(members) if kind.is_digital else members
            self.instances[number] = Assembly(number, kind, slots)
            number += 1
        self.categories = [a for a in self.instances.values() if isinstance(a, Assembly)]
        self.inputs = [a for a in self.categories if not a.is_output]  # DI, AI
        self.outputs = [a for a in self.categories if a.is_output]  # DO, AO
        self.all_outputs: AnyAssembly | None = self.outputs[0] if self.outputs else None
        self.all_inputs: AnyAssembly | None = self.inputs[0] if self.inputs else None
        for direction in (self.outputs, self.inputs):
            if len(direction) > 1:
                combined = Combined(number, tuple(direction))
                self.instances[number] = combined
                number += 1
                if combined.is_output:
                    self.all_outputs = combined
                else:
                    self.all_inputs = combined

    @property
    def max_instance(self) -> int:
        return max(self.instances, default=0)

    @property
    def largest(self) -> int:
        return max((a.size for a in self.instances.values()), default=0)

    @property
    def produced_size(self) -> int:
        """The size of all inputs (the default poll response)."""
        return self.all_inputs.size if self.all_inputs else 0

    @property
    def consumed_size(self) -> int:
        """The size of all outputs (the default poll request)."""
        return self.all_outputs.size if self.all_outputs else 0

    def consume(self, assembly: AnyAssembly, data: bytes) -> list[str]:
        """Write consumed bytes (``len(data) == assembly.size``) to the outputs of an output
        assembly, as one batch: the one place where I/O and explicit data reach the image;
        returns the ids that changed."""
        return [
            change.id for change in self.image.write_outputs(assembly.values(data), self.origin)
        ]

    def input_ids(self) -> list[str]:
        return [c.id for a in self.inputs for c in a.channels]

    def output_ids(self) -> list[str]:
        return [c.id for a in self.outputs for c in a.channels]
