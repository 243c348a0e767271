"""RTU framing: CRC, request and response frames, diagnosis of bad replies (sans-I/O)."""

import pytest
from pymodbus.framer import FramerRTU

from fieldgate import ErrorKind
from fieldgate.plugins.modbus import codec
from fieldgate.plugins.modbus.codec import Request, diagnose


def test_crc_of_the_classic_read_holding_registers_frame():
    # 01 03 00 00 00 0A is sent as 01 03 00 00 00 0A C5 CD (CRC low byte first)
    assert codec.frame(1, bytes.fromhex("03 00 00 00 0A")) == bytes.fromhex("01030000000AC5CD")


@pytest.mark.parametrize("data", [b"", b"\x01", bytes(range(50)), b"\xff" * 7])
def test_crc_agrees_with_pymodbus(data):
    # pymodbus returns the CRC byte-swapped (high byte = first byte sent)
    assert codec.crc16(data) == int.from_bytes(
        FramerRTU.compute_CRC(data).to_bytes(2, "big"), "little"
    )


@pytest.mark.parametrize(
    "request_, wire",
    [
        (Request(1, 1, 0x13, 0x25), "01 01 00 13 00 25"),
        (Request(17, 2, 0xC4, 0x16), "11 02 00 C4 00 16"),
        (Request(17, 3, 0x6B, 3), "11 03 00 6B 00 03"),
        (Request(17, 4, 0x08, 1), "11 04 00 08 00 01"),
        (Request(17, 5, 0xAC, 1, (True,)), "11 05 00 AC FF 00"),
        (Request(17, 6, 0x01, 1, (0x0003,)), "11 06 00 01 00 03"),
        # the spec's FC15 example: coils 20..29 = CD 01
        (
            Request(
                17, 15, 0x13, 10, (True, False, True, True, False, False, True, True, True, False)
            ),
            "11 0F 00 13 00 0A 02 CD 01",
        ),
        (Request(17, 16, 0x01, 2, (0x000A, 0x0102)), "11 10 00 01 00 02 04 00 0A 01 02"),
    ],
)
def test_requests_encode_to_the_spec_examples_and_parse_back(request_, wire):
    adu = request_.encode()
    assert adu[:-2] == bytes.fromhex(wire)
    assert codec.crc_ok(adu)
    assert codec.request_length(adu) == len(adu)
    assert codec.parse_request(adu) == request_


def test_request_length_needs_enough_bytes_and_rejects_unknown_functions():
    adu = Request(1, 16, 0, 3, (1, 2, 3)).encode()
    assert codec.request_length(adu[:1]) is None
    assert codec.request_length(adu[:6]) is None  # byte count not there yet
    assert codec.request_length(adu[:7]) == 15
    with pytest.raises(ValueError, match="unknown function code 7"):
        codec.request_length(b"\x01\x07")


@pytest.mark.parametrize(
    "adu",
    [
        codec.frame(1, bytes.fromhex("05 00 01 12 34")),  # coil value neither FF00 nor 0000
        codec.frame(1, bytes.fromhex("0F 00 00 00 10 01 FF")),  # 16 coils in 1 byte
        codec.frame(1, bytes.fromhex("10 00 00 00 02 02 00 01")),  # 2 registers in 2 bytes
    ],
)
def test_malformed_requests_are_rejected(adu):
    with pytest.raises(ValueError):
        codec.parse_request(adu)


def test_responses():
    assert codec.read_bits_response(1, 2, [False, False, True])[:-2] == bytes.fromhex("01 02 01 04")
    assert codec.read_registers_response(5, 4, [0x1234, 0xFFFF])[:-2] == bytes.fromhex(
        "05 04 04 12 34 FF FF"
    )
    assert codec.exception_response(3, 1, 2)[:-2] == bytes.fromhex("03 81 02")
    write = Request(3, 15, 0, 8, (True,) * 8)
    assert codec.write_response(write)[:-2] == bytes.fromhex("03 0F 00 00 00 08")
    single = Request(3, 6, 7, 1, (0xBEEF,))
    assert codec.write_response(single)[:-2] == bytes.fromhex("03 06 00 07 BE EF")


def test_response_length():
    good = codec.read_registers_response(1, 3, [1, 2, 3])
    assert codec.response_length(3, good) == len(good) == 11
    assert codec.response_length(3, good[:2]) is None
    assert codec.response_length(6, b"\x01\x06") == 8
    assert codec.response_length(3, codec.exception_response(1, 3, 2)) == 5


class TestDiagnose:
    reply = codec.read_registers_response(1, 4, [10, 20])

    def test_nothing_is_a_timeout(self):
        assert diagnose(1, 4, b"") is ErrorKind.TIMEOUT

    def test_bad_crc(self):
        assert diagnose(1, 4, self.reply[:-1] + bytes([self.reply[-1] ^ 1])) is ErrorKind.CRC

    def test_reply_of_another_unit(self):
        assert (
            diagnose(1, 4, codec.read_registers_response(2, 4, [10, 20])) is ErrorKind.WRONG_ADDRESS
        )

    def test_reply_of_another_unit_behind_noise(self):
        assert (
            diagnose(1, 4, b"\x00\xff" + codec.read_registers_response(9, 4, [1]))
            is ErrorKind.WRONG_ADDRESS
        )

    def test_truncated_reply(self):
        assert diagnose(1, 4, self.reply[:5]) is ErrorKind.GARBAGE

    def test_noise(self):
        assert diagnose(1, 4, bytes([0x55, 0xAA, 0x00, 0xFF, 0x13])) is ErrorKind.GARBAGE

    def test_sound_frame_of_another_function(self):
        assert diagnose(1, 4, codec.read_registers_response(1, 3, [1])) is ErrorKind.GARBAGE


def test_bit_packing_is_lsb_first():
    bits = [True, False, True, True, False, False, True, True, True, False]
    assert codec.pack_bits(bits) == bytes([0xCD, 0x01])
    assert codec.unpack_bits(bytes([0xCD, 0x01]), 10) == bits
