"""Register data types and word orders."""

import math

import pytest

from fieldgate import DataType
from fieldgate.plugins.modbus import values


@pytest.mark.parametrize(
    "dtype, value, order, words",
    [
        (DataType.INT16, -1, "big", [0xFFFF]),
        (DataType.INT16, -32768, "big", [0x8000]),
        (DataType.UINT16, 65535, "big", [0xFFFF]),
        (DataType.INT32, 0x12345678, "big", [0x1234, 0x5678]),
        (DataType.INT32, 0x12345678, "little", [0x5678, 0x1234]),
        (DataType.INT32, -2, "big", [0xFFFF, 0xFFFE]),
        (DataType.UINT32, 0xDEADBEEF, "big", [0xDEAD, 0xBEEF]),
        (DataType.UINT32, 0xDEADBEEF, "little", [0xBEEF, 0xDEAD]),
        (DataType.FLOAT32, 1.0, "big", [0x3F80, 0x0000]),
        (DataType.FLOAT32, 1.0, "little", [0x0000, 0x3F80]),
        (DataType.FLOAT32, -2.5, "big", [0xC020, 0x0000]),
    ],
)
def test_known_encodings_both_ways(dtype, value, order, words):
    assert values.encode(dtype, value, order) == words
    assert values.decode(dtype, words, order) == value


def test_float_round_trip_is_float32_precise():
    words = values.encode(DataType.FLOAT32, 3.14159, "little")
    assert values.decode(DataType.FLOAT32, words, "little") == pytest.approx(3.14159, rel=1e-7)


@pytest.mark.parametrize(
    "dtype, value",
    [
        (DataType.INT16, 40000),
        (DataType.UINT16, -1),
        (DataType.INT32, 2**31),
        (DataType.UINT32, -5),
    ],
)
def test_out_of_range_values_are_refused(dtype, value):
    with pytest.raises(ValueError, match="outside"):
        values.encode(dtype, value)


def test_nan_registers_are_reported():
    nan_words = values.encode(DataType.FLOAT32, math.nan)
    with pytest.raises(ValueError, match="finite"):
        values.decode(DataType.FLOAT32, nan_words)


def test_bits_of_a_register():
    assert values.get_bit(0b1010, 1) and not values.get_bit(0b1010, 2)
    assert values.set_bit(0x00FF, 15, True) == 0x80FF
    assert values.set_bit(0x80FF, 0, False) == 0x80FE
