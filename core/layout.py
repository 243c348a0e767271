"""Default order and packing of channels as fronts present them.

The seeds' rule (I-7232D §3.1, I-7231D, I-7241D): modules in ascending address order,
all channels of one module before the next; digital channels packed 8 per byte, LSB =
lowest channel, each module starting a new byte (a padded last byte when its count is
not a multiple of 8); analog channels one 16-bit word each.

Fronts with other rules (the NA-9161 packs digital channels across modules) build on
:func:`default_order` and :func:`pack_bits` with ``per_module=False``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from .image import Channel, Kind, ProcessImage


def default_order(image: ProcessImage, back_order: Sequence[str] | None = None) -> list[Channel]:
    """Every channel: backs in topology order, modules by ascending address, channels by index."""
    rank = {name: i for i, name in enumerate(back_order or [])}
    return sorted(
        image,
        key=lambda c: (
            rank.get(c.source.back, len(rank)),
            c.source.back,
            c.source.module,
            c.source.index,
        ),
    )


def of_kind(channels: Iterable[Channel], kind: Kind) -> list[Channel]:
    return [c for c in channels if c.kind is kind]


def pack_bits(
    channels: Sequence[Channel], *, per_module: bool = True
) -> list[list[Channel | None]]:
    """Group digital channels into bytes of 8 slots (None = padding bit), LSB first."""
    result: list[list[Channel | None]] = []
    current: list[Channel | None] = []
    last_module: tuple[str, int] | None = None
    for channel in channels:
        module = (channel.source.back, channel.source.module)
        if current and (len(current) == 8 or (per_module and module != last_module)):
            result.append(current + [None] * (8 - len(current)))
            current = []
        current.append(channel)
        last_module = module
    if current:
        result.append(current + [None] * (8 - len(current)))
    return result


def byte_value(slots: Sequence[Channel | None]) -> int:
    """The byte a group of 8 digital slots reads as (padding bits read 0)."""
    value = 0
    for bit, ch in enumerate(slots):  # a plain loop: every TPDO and poll response packs bytes
        if ch is not None and ch.value:
            value |= 1 << bit
    return value


def bit_values(slots: Sequence[Channel | None], value: int) -> dict[str, bool]:
    """Each real bit of ``value`` for its channel (padding bits dropped), LSB first."""
    return {ch.id: bool(value >> bit & 1) for bit, ch in enumerate(slots) if ch is not None}


def write_byte(
    image: ProcessImage, slots: Sequence[Channel | None], value: int, origin: str
) -> list[str]:
    """Write each real bit of ``value`` to its output channel, as one batch; returns the ids
    that changed."""
    return [change.id for change in image.write_outputs(bit_values(slots, value), origin)]
