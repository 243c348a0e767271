"""Request PDUs decoded and answers encoded, without a socket (the function codes served,
the standard's quantity and byte-count rules, and exception 01 for everything else: D6)."""

from __future__ import annotations

import struct

import pytest

from fieldgate.plugins.modbus_tcp.pdu import (
    ILLEGAL_FUNCTION,
    ILLEGAL_VALUE,
    SERVED,
    Read,
    ReadWrite,
    Write,
    decode,
    encode_read,
    encode_write,
    exception,
)


def test_reads():
    assert decode(struct.pack(">BHH", 1, 10, 2000)) == Read(1, 10, 2000)
    assert decode(struct.pack(">BHH", 4, 0, 125)) == Read(4, 0, 125)
    for fc, over in ((1, 2001), (2, 2001), (3, 126), (4, 126)):
        assert decode(struct.pack(">BHH", fc, 0, over)) == ILLEGAL_VALUE
        assert decode(struct.pack(">BHH", fc, 0, 0)) == ILLEGAL_VALUE
        assert decode(struct.pack(">BH", fc, 0)) == ILLEGAL_VALUE  # too short
        assert decode(struct.pack(">BHHB", fc, 0, 1, 0)) == ILLEGAL_VALUE  # a byte too many


def test_single_writes():
    assert decode(struct.pack(">BHH", 5, 3, 0xFF00)) == Write(5, 3, [True])
    assert decode(struct.pack(">BHH", 5, 3, 0x0000)) == Write(5, 3, [False])
    assert decode(struct.pack(">BHH", 5, 3, 0x0001)) == ILLEGAL_VALUE  # not "any non-zero"
    assert decode(struct.pack(">BHH", 6, 1, 0xFFFF)) == Write(6, 1, [0xFFFF])
    assert decode(struct.pack(">BHHB", 6, 1, 1, 0)) == ILLEGAL_VALUE


def test_multiple_writes_and_their_byte_counts():
    assert decode(struct.pack(">BHHBB", 15, 0, 3, 1, 0b101)) == Write(15, 0, [True, False, True])
    assert decode(struct.pack(">BHHBB", 15, 0, 9, 1, 0xFF)) == ILLEGAL_VALUE  # needs 2 bytes
    assert decode(struct.pack(">BHHBBB", 15, 0, 9, 2, 0xFF, 0x01)) == Write(15, 0, [True] * 9)
    assert decode(struct.pack(">BHHB", 15, 0, 1969, 247) + bytes(247)) == ILLEGAL_VALUE
    assert decode(struct.pack(">BHHBHH", 16, 2, 2, 4, 7, 8)) == Write(16, 2, [7, 8])
    assert decode(struct.pack(">BHHBH", 16, 2, 2, 4, 7)) == ILLEGAL_VALUE  # data short
    assert decode(struct.pack(">BHHB", 16, 0, 124, 248) + bytes(248)) == ILLEGAL_VALUE
    assert decode(struct.pack(">BHH", 16, 0, 1)) == ILLEGAL_VALUE  # no byte count


def test_read_write_multiple_registers():
    pdu = struct.pack(">BHHHHBH", 23, 0, 2, 1, 1, 2, 99)
    assert decode(pdu) == ReadWrite(Write(23, 1, [99]), Read(23, 0, 2))
    assert decode(struct.pack(">BHHHHBH", 23, 0, 126, 1, 1, 2, 99)) == ILLEGAL_VALUE
    assert decode(struct.pack(">BHHHHBH", 23, 0, 1, 1, 122, 2, 99)) == ILLEGAL_VALUE


def test_every_function_code_outside_the_served_set_is_exception_01():
    """D6: pymodbus answered FC 8 (echo), 17 ("Pymodbus"), 24 (FIFO 0,1,2,3), 43, ..."""
    for fc in range(256):
        if fc not in SERVED:
            assert decode(bytes([fc]) + bytes(4)) == ILLEGAL_FUNCTION, fc
            assert decode(bytes([fc])) == ILLEGAL_FUNCTION, fc
    assert SERVED == {1, 2, 3, 4, 5, 6, 15, 16, 23}


def test_answers():
    assert encode_read(1, [True, False, True, True, False, False, False, False, True]) == bytes(
        [1, 2, 0b1101, 0b1]
    )
    assert encode_read(3, [0x1234, 0xFFFF]) == bytes([3, 4, 0x12, 0x34, 0xFF, 0xFF])
    single = struct.pack(">BHH", 6, 1, 5)
    assert encode_write(Write(6, 1, [5]), single) == single
    multiple = struct.pack(">BHHBHH", 16, 2, 2, 4, 7, 8)
    assert encode_write(Write(16, 2, [7, 8]), multiple) == struct.pack(">BHH", 16, 2, 2)
    assert exception(3, 2) == b"\x83\x02" and exception(0x80, 1) == b"\x80\x01"


@pytest.mark.parametrize("fc", sorted(SERVED))
def test_a_lone_function_code_is_a_value_error_not_a_crash(fc):
    assert decode(bytes([fc])) == ILLEGAL_VALUE
