"""Values as 16-bit registers, in the byte and word orders devices use (one place for both the
Modbus back that reads them and the Modbus TCP front that serves them).

A register travels big-endian (high byte first). A value wider than one register is its
bytes, most significant first (``A`` is the most significant byte of a 32-bit value,
``A``..``H`` of a 64-bit one), spread over consecutive registers in one of four orders:

| order | 32-bit registers | 64-bit registers | what it is |
|---|---|---|---|
| ``ABCD`` | AB CD | AB CD EF GH | big-endian, the Modbus "natural" order (``word_order: big``) |
| ``CDAB`` | CD AB | GH EF CD AB | word swap: low word first (``word_order: little``; many PLCs) |
| ``BADC`` | BA DC | BA DC FE HG | byte swap inside each register (some power meters) |
| ``DCBA`` | DC BA | HG FE DC BA | both: little-endian |

The 64-bit orders may be named by their eight letters too (``GHEFCDAB``). A 16-bit value is
one register, big-endian, whatever the order (the Modbus rule; a device that swaps the bytes
of its 16-bit registers swaps its wider values too, and those take the order). Text
(STRING) is its UTF-8 bytes in register order, the first character in the high byte of the
first register (``ABCD``; ``BADC``: in the low byte), padded with NUL; it reads up to the
first NUL, trailing spaces dropped.
Encoding is the exact inverse of decoding, so a value written with FC6/FC16 lands in the
registers as FC3/FC4 read it.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

from .image import DataType

ORDERS = ("ABCD", "CDAB", "BADC", "DCBA")
LONG_NAMES = {"ABCDEFGH": "ABCD", "GHEFCDAB": "CDAB", "BADCFEHG": "BADC", "HGFEDCBA": "DCBA"}
ALIASES = {"big": "ABCD", "little": "CDAB", **LONG_NAMES}

WORDS = {
    DataType.INT16: 1,
    DataType.UINT16: 1,
    DataType.INT32: 2,
    DataType.UINT32: 2,
    DataType.FLOAT32: 2,
    DataType.INT64: 4,
    DataType.UINT64: 4,
    DataType.FLOAT64: 4,
}
"""Registers a number of each type takes (a STRING takes ``string_words(length)``)."""

_FORMAT = {
    DataType.INT16: ">h",
    DataType.UINT16: ">H",
    DataType.INT32: ">i",
    DataType.UINT32: ">I",
    DataType.FLOAT32: ">f",
    DataType.INT64: ">q",
    DataType.UINT64: ">Q",
    DataType.FLOAT64: ">d",
}


def order_name(order: str) -> str:
    """One of :data:`ORDERS` for any accepted spelling (``big``, ``GHEFCDAB``); ValueError else."""
    name = ALIASES.get(order, order.upper() if order.upper() in ORDERS else "")
    if not name:
        raise ValueError(
            f"unknown order {order!r}: one of ABCD, CDAB, BADC, DCBA (64-bit also ABCDEFGH, "
            "GHEFCDAB, BADCFEHG, HGFEDCBA; big = ABCD, little = CDAB)"
        )
    return name


def string_words(length: int) -> int:
    """Registers that hold ``length`` bytes of text."""
    return (length + 1) // 2


def width(dtype: DataType, length: int | None = None) -> int:
    """Registers a value of ``dtype`` takes (``length``: bytes of a STRING)."""
    if dtype is DataType.STRING:
        return string_words(length or 0)
    return WORDS[dtype]


def _swap(data: bytes, order: str) -> bytes:
    """The bytes in register order from the value's bytes, or back (the steps are their own
    inverse and commute): registers reversed for CDAB/DCBA, bytes swapped inside each for
    BADC/DCBA."""
    words = [data[i : i + 2] for i in range(0, len(data), 2)]
    if order in ("CDAB", "DCBA"):
        words.reverse()
    if order in ("BADC", "DCBA"):
        words = [w[::-1] for w in words]
    return b"".join(words)


def decode(
    dtype: DataType, words: Sequence[int], order: str = "ABCD", length: int | None = None
) -> int | float | str:
    """Registers (in address order) to a value; ValueError for a float that is not finite.
    ``length``: a STRING's bytes (an odd length leaves the last register's other byte out; text
    is cut to fit them, never a character split)."""
    order = order_name(order) if WORDS.get(dtype) != 1 else "ABCD"
    raw = b"".join((w & 0xFFFF).to_bytes(2, "big") for w in words)
    data = _swap(raw, order)
    if dtype is DataType.STRING:
        raw_text = data[:length] if length is not None else data
        text = raw_text.split(b"\0", 1)[0].decode("utf-8", errors="replace").rstrip(" ")
        while length is not None and len(text.encode()) > length:  # a replacement char is 3
            text = text[:-1]
        return text
    value: int | float = struct.unpack(_FORMAT[dtype], data[: 2 * WORDS[dtype]])[0]
    if dtype.is_float and not math.isfinite(value):
        raise ValueError(f"registers {list(words)} are not a finite {dtype.value}")
    return value


def encode(
    dtype: DataType, value: object, order: str = "ABCD", length: int | None = None
) -> list[int]:
    """A value to its registers in address order; ValueError when it does not fit the type
    (``length``: the bytes a STRING has)."""
    order = order_name(order) if WORDS.get(dtype) != 1 else "ABCD"
    if dtype is DataType.STRING:
        if not isinstance(value, str):
            raise ValueError(f"expected text, got {value!r}")
        size = length or 0
        data = value.encode()
        if len(data) > size:
            raise ValueError(f"text of {len(data)} bytes is longer than the {size} bytes it has")
        data = data.ljust(2 * string_words(size), b"\0")
    elif dtype.is_float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"expected a number, got {value!r}")
        data = struct.pack(_FORMAT[dtype], float(value))
    else:
        data = struct.pack(_FORMAT[dtype], dtype.check(value))
    swapped = _swap(data, order)
    return [int.from_bytes(swapped[i : i + 2], "big") for i in range(0, len(swapped), 2)]


def get_field(register: int, bit: int, bits: int = 1) -> bool | int:
    """The field of ``bits`` bits at ``bit`` of a register: a bool for one bit, else unsigned."""
    if bits == 1:
        return bool(register >> bit & 1)
    return register >> bit & ((1 << bits) - 1)


def set_field(register: int, bit: int, bits: int, value: object) -> int:
    """``register`` with the field of ``bits`` bits at ``bit`` replaced by ``value`` (ValueError
    when it does not fit)."""
    if bits == 1:
        field = int(bool(value))
    else:
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1 << bits:
            raise ValueError(
                f"{value!r} does not fit a field of {bits} bits (0..{(1 << bits) - 1})"
            )
        field = value
    mask = ((1 << bits) - 1) << bit
    return (register & ~mask | field << bit) & 0xFFFF
