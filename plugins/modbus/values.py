"""Register data types: 16-bit and 32-bit integers and float32 over Modbus registers.

Each register is big-endian on the wire (the Modbus rule). A 32-bit value spans two
registers; ``word_order`` says which comes first: ``big`` (high word first, the Modbus
"natural" order, ABCD) or ``little`` (low word first, CDAB, as many PLCs store them).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

from fieldgate.image import DataType

WORDS = {
    DataType.INT16: 1,
    DataType.UINT16: 1,
    DataType.INT32: 2,
    DataType.UINT32: 2,
    DataType.FLOAT32: 2,
}

_FORMAT = {DataType.INT32: ">i", DataType.UINT32: ">I", DataType.FLOAT32: ">f"}


def decode(dtype: DataType, words: Sequence[int], word_order: str = "big") -> int | float:
    """Registers to a value. ``words`` are the raw 16-bit registers in address order."""
    if dtype is DataType.UINT16:
        return words[0] & 0xFFFF
    if dtype is DataType.INT16:
        raw = words[0] & 0xFFFF
        return raw - 0x10000 if raw & 0x8000 else raw
    high, low = (words[0], words[1]) if word_order == "big" else (words[1], words[0])
    value: int | float = struct.unpack(
        _FORMAT[dtype], (high & 0xFFFF).to_bytes(2, "big") + (low & 0xFFFF).to_bytes(2, "big")
    )[0]
    if dtype is DataType.FLOAT32 and not math.isfinite(value):
        raise ValueError(f"register pair {words} is not a finite float32")
    return value


def encode(dtype: DataType, value: int | float, word_order: str = "big") -> list[int]:
    """A value to its registers in address order. Raises ValueError when it does not fit."""
    if dtype in (DataType.INT16, DataType.UINT16):
        return [int(dtype.check(value)) & 0xFFFF]  # (an int: check() refuses anything else)
    if dtype is DataType.FLOAT32:
        raw = struct.pack(">f", float(value))
    else:
        raw = struct.pack(_FORMAT[dtype], dtype.check(value))
    high, low = int.from_bytes(raw[:2], "big"), int.from_bytes(raw[2:], "big")
    return [high, low] if word_order == "big" else [low, high]


def get_field(register: int, bit: int, dtype: DataType) -> bool | int:
    """A point inside a register: one bit (BOOL) or one byte (UINT8) starting at ``bit``."""
    if dtype is DataType.UINT8:
        return register >> bit & 0xFF
    return get_bit(register, bit)


def set_field(register: int, bit: int, dtype: DataType, value: object) -> int:
    """``register`` with the bit (BOOL) or byte (UINT8) at ``bit`` replaced by ``value``."""
    if dtype is DataType.UINT8:
        byte = int(DataType.UINT8.check(value))
        return (register & ~(0xFF << bit) | byte << bit) & 0xFFFF
    return set_bit(register, bit, bool(value))


def get_bit(register: int, bit: int) -> bool:
    return bool(register >> bit & 1)


def set_bit(register: int, bit: int, on: bool) -> int:
    return register | (1 << bit) if on else register & ~(1 << bit) & 0xFFFF
