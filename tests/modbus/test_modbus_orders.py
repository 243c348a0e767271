"""Every register data type in the four orders, against a decoder of the test's own: the order's
name read literally (``BADC`` = the value's bytes B, A, D, C in register order)."""

from __future__ import annotations

import math
import struct

import pytest

from fieldgate import registers
from fieldgate.image import DataType

FORMAT = {
    DataType.INT32: ">i",
    DataType.UINT32: ">I",
    DataType.FLOAT32: ">f",
    DataType.INT64: ">q",
    DataType.UINT64: ">Q",
    DataType.FLOAT64: ">d",
}
LONG = {"ABCD": "ABCDEFGH", "CDAB": "GHEFCDAB", "BADC": "BADCFEHG", "DCBA": "HGFEDCBA"}
VALUES = {
    DataType.INT32: -123456789,
    DataType.UINT32: 0xDEADBEEF,
    DataType.FLOAT32: 230.1,
    DataType.INT64: -0x123456789ABCDEF,
    DataType.UINT64: 0xFEDCBA9876543210,
    DataType.FLOAT64: 12345.678901234,
}


def literal_words(dtype: DataType, value: float, order: str) -> list[int]:
    """The registers as the order's letters spell them: letter k = the value's k-th byte."""
    data = struct.pack(FORMAT[dtype], value)
    name = order if len(data) == 4 else LONG[order]
    laid = bytes(data[ord(letter) - ord("A")] for letter in name)
    return [int.from_bytes(laid[i : i + 2], "big") for i in range(0, len(laid), 2)]


@pytest.mark.parametrize("order", registers.ORDERS)
@pytest.mark.parametrize("dtype", list(VALUES))
def test_every_wide_type_in_every_order_both_ways(dtype: DataType, order: str) -> None:
    value = VALUES[dtype]
    words = registers.encode(dtype, value, order)
    assert words == literal_words(dtype, value, order)
    back = registers.decode(dtype, words, order)
    if dtype is DataType.FLOAT32:
        assert back == pytest.approx(value, rel=1e-7)
    else:
        assert back == value


def test_the_64_bit_orders_by_their_eight_letters() -> None:
    for short, long in LONG.items():
        assert registers.order_name(long) == short
        words = registers.encode(DataType.UINT64, 0x0102030405060708, long)
        assert words == registers.encode(DataType.UINT64, 0x0102030405060708, short)
    assert registers.encode(DataType.UINT64, 0x0102030405060708, "GHEFCDAB") == [
        0x0708,
        0x0506,
        0x0304,
        0x0102,
    ]
    assert registers.order_name("big") == "ABCD" and registers.order_name("little") == "CDAB"
    with pytest.raises(ValueError, match="unknown order"):
        registers.order_name("ACBD")


def test_a_power_meter_with_byte_swapped_floats_reads_230_1() -> None:
    # 230.1 is 0x43661999 (A=43 B=66 C=19 D=99); a BADC meter sends 66 43 99 19
    words = [0x6643, 0x9919]
    assert registers.decode(DataType.FLOAT32, words, "BADC") == pytest.approx(230.1, rel=1e-6)
    # read as the Modbus default (ABCD) the same registers are the 2.4e-41-class nonsense
    wrong = registers.decode(DataType.FLOAT32, words, "ABCD")
    assert not 200 < abs(float(wrong)) < 260


def test_16_bit_values_are_one_big_endian_register_in_any_order() -> None:
    for order in registers.ORDERS:
        assert registers.encode(DataType.INT16, -2, order) == [0xFFFE]
        assert registers.decode(DataType.UINT16, [0x1234], order) == 0x1234


def test_text_in_register_order_padded_and_cut_at_nul() -> None:
    assert registers.encode(DataType.STRING, "ABCDE", "ABCD", 6) == [0x4142, 0x4344, 0x4500]
    assert registers.encode(DataType.STRING, "ABCDE", "BADC", 6) == [0x4241, 0x4443, 0x0045]
    assert registers.decode(DataType.STRING, [0x4142, 0x4344, 0x4500], "ABCD") == "ABCDE"
    assert registers.decode(DataType.STRING, [0x4241, 0x4443, 0x0045], "BADC") == "ABCDE"
    assert registers.decode(DataType.STRING, [0x4142, 0x2020, 0x4344], "ABCD") == "AB  CD"
    assert registers.decode(DataType.STRING, [0x4142, 0x2020, 0x0000], "ABCD") == "AB"
    assert registers.decode(DataType.STRING, [0x4100, 0x4242], "ABCD") == "A"  # ends at NUL
    assert registers.encode(DataType.STRING, "Ü", "ABCD", 2) == [0xC39C]  # UTF-8
    # an odd length: the last register's low byte is not the text's; a cut never splits a char
    assert registers.decode(DataType.STRING, [0x4142, 0x4344, 0x4546], "ABCD", 5) == "ABCDE"
    assert registers.decode(DataType.STRING, [0x41C3, 0x9C00], "ABCD", 2) == "A"
    with pytest.raises(ValueError, match="longer than the 4 bytes"):
        registers.encode(DataType.STRING, "ABCDE", "ABCD", 4)


def test_refusals_say_why() -> None:
    with pytest.raises(ValueError, match="outside int64"):
        registers.encode(DataType.INT64, 2**63)
    with pytest.raises(ValueError, match="outside uint64"):
        registers.encode(DataType.UINT64, -1)
    with pytest.raises(ValueError, match="not a finite float64"):
        registers.decode(DataType.FLOAT64, registers.encode(DataType.FLOAT64, math.inf))
    with pytest.raises(ValueError, match="expected a number"):
        registers.encode(DataType.FLOAT32, "1.5")


def test_bit_fields() -> None:
    assert registers.get_field(0xABCD, 4, 4) == 0xC
    assert registers.get_field(0xABCD, 0, 1) is True
    assert registers.set_field(0xABCD, 4, 4, 0x3) == 0xAB3D
    with pytest.raises(ValueError, match="does not fit a field of 4 bits"):
        registers.set_field(0, 0, 4, 16)
