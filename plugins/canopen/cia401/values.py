"""A channel's value as CiA 401's 16-bit analog objects carry it, and back."""

from __future__ import annotations

import math

from fieldgate.image import Channel, DataType

from ..cia301.abort import VALUE_RANGE
from ..cia301.entries import Abort


def to_int16(channel: Channel, value: bool | int | float | str | None = None) -> int:
    """A channel's value as the INTEGER16 CiA 401 shows (raw bits of a UINT16, clamped otherwise)."""
    v = channel.value if value is None else value
    if isinstance(v, str):  # never served (FrontConfig.carried_types): the type allows it
        return 0
    if channel.spec.data_type is DataType.UINT16 and isinstance(v, int) and v > 0x7FFF:
        return v - 0x10000
    if isinstance(v, float) and not math.isfinite(v):
        return 0x7FFF if v == math.inf else (-0x8000 if v == -math.inf else 0)
    v = int(round(v))
    return max(-0x8000, min(0x7FFF, v))


def from_int16(channel: Channel, value: int) -> bool | int | float:
    """An INTEGER16 written to an analog output, in the channel's own data type."""
    dtype = channel.spec.data_type
    if dtype is DataType.UINT16:
        return value & 0xFFFF
    if dtype is DataType.UINT32 and value < 0:
        raise Abort(VALUE_RANGE, f"{channel.id} takes no negative values")
    if dtype is DataType.FLOAT32:
        return float(value)
    if dtype is DataType.BOOL:
        raise Abort(VALUE_RANGE, f"{channel.id} is boolean")
    return value
