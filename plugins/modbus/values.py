"""Register data types of the Modbus back: core's :mod:`fieldgate.registers` (16/32/64-bit
integers, 32/64-bit floats, text, in the orders ABCD, CDAB, BADC, DCBA; bit fields), the one
place the Modbus TCP front shares."""

from __future__ import annotations

from fieldgate.registers import (
    ORDERS,
    WORDS,
    decode,
    encode,
    get_field,
    order_name,
    set_field,
    string_words,
    width,
)

__all__ = [
    "ORDERS",
    "WORDS",
    "decode",
    "encode",
    "get_bit",
    "get_field",
    "order_name",
    "set_bit",
    "set_field",
    "string_words",
    "width",
]


def get_bit(register: int, bit: int) -> bool:
    return bool(register >> bit & 1)


def set_bit(register: int, bit: int, on: bool) -> int:
    return set_field(register, bit, 1, on)
