"""Assembly instances built from the channels a front serves (seed-003 §4).

One instance per I/O category with channels, numbered from 0x64 in the order DO, AO, DI,
AI (empty categories take no number). Digital channels: 8 per byte, LSB = lowest
channel, each module starting a new byte (:func:`fieldgate.layout.pack_bits`). Analog
channels: one 16-bit little-endian word each (two's complement for signed values).

I/O connections produce every input assembly (DI then AI) and consume every output
assembly (DO then AO), concatenated: :attr:`Assemblies.produced` / :meth:`consume`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from fieldgate.image import Channel, DataType, Kind, ProcessImage, Value
from fieldgate.layout import bit_values, byte_value, of_kind, pack_bits

FIRST_INSTANCE = 0x64
CATEGORY_ORDER = (Kind.DO, Kind.AO, Kind.DI, Kind.AI)


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


@dataclass
class Assembly:
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

    def data(self) -> bytes:
        if self.kind.is_digital:
            return bytes(byte_value(group) for group in self.slots)
        return b"".join(word_of(c).to_bytes(2, "little") for c in self.slots)

    def values(self, data: bytes) -> dict[str, Value]:
        """An output assembly's bytes (``len(data) == size``) as values of its channels; a
        word that does not fit its channel's type is left out (the channel keeps its value)."""
        values: dict[str, Value] = {}
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

    def write(self, image: ProcessImage, data: bytes, origin: str) -> list[str]:
        """Write an output assembly's bytes to its channels, as one batch; returns the ids
        that changed."""
        return [change.id for change in image.write_outputs(self.values(data), origin)]


class Assemblies:
    def __init__(self, image: ProcessImage, channels: Sequence[Channel], origin: str = "devicenet"):
        self.image = image
        self.origin = origin
        self.channels = list(channels)
        self.instances: dict[int, Assembly] = {}
        number = FIRST_INSTANCE
        for kind in CATEGORY_ORDER:
            members = of_kind(channels, kind)
            if not members:
                continue
            slots = pack_bits(members) if kind.is_digital else members
            self.instances[number] = Assembly(number, kind, slots)
            number += 1
        self.inputs = [a for a in self.instances.values() if not a.is_output]  # DI, AI
        self.outputs = [a for a in self.instances.values() if a.is_output]  # DO, AO

    @property
    def max_instance(self) -> int:
        return max(self.instances, default=0)

    @property
    def produced_size(self) -> int:
        return sum(a.size for a in self.inputs)

    @property
    def consumed_size(self) -> int:
        return sum(a.size for a in self.outputs)

    def produced(self) -> bytes:
        return b"".join(a.data() for a in self.inputs)

    def consume(self, data: bytes) -> list[str]:
        """Write a consumed I/O message (every output assembly, concatenated) as one batch;
        returns the ids that changed."""
        values: dict[str, Value] = {}
        offset = 0
        for assembly in self.outputs:
            values.update(assembly.values(data[offset : offset + assembly.size]))
            offset += assembly.size
        return [change.id for change in self.image.write_outputs(values, self.origin)]

    def input_ids(self) -> list[str]:
        return [c.id for a in self.inputs for c in a.channels]

    def output_ids(self) -> list[str]:
        return [c.id for a in self.outputs for c in a.channels]
