"""Modbus RTU framing, sans-I/O: CRC, request and response frames, and diagnosis of bad replies.

The back end sends through pymodbus's client, which silently discards a reply with a bad
CRC or from another address and then reports a plain timeout. :func:`diagnose` looks at
the bytes that really arrived and says what went wrong (timeout, CRC, wrong address,
garbage), so the error counters mean something. The simulator uses the same functions
as its own RTU responder (pymodbus's server answers for unit ids it does not serve).

Addresses are PDU addresses (0-based), as they travel on the wire.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from enum import IntEnum

from fieldgate.health import ErrorKind
from fieldgate.serial_timing import char_time


class Function(IntEnum):
    READ_COILS = 1
    READ_DISCRETE_INPUTS = 2
    READ_HOLDING_REGISTERS = 3
    READ_INPUT_REGISTERS = 4
    WRITE_SINGLE_COIL = 5
    WRITE_SINGLE_REGISTER = 6
    WRITE_MULTIPLE_COILS = 15
    WRITE_MULTIPLE_REGISTERS = 16


class ExceptionCode(IntEnum):
    ILLEGAL_FUNCTION = 1
    ILLEGAL_DATA_ADDRESS = 2
    ILLEGAL_DATA_VALUE = 3
    SERVER_DEVICE_FAILURE = 4


READ_BIT_FUNCTIONS = (Function.READ_COILS, Function.READ_DISCRETE_INPUTS)
READ_REGISTER_FUNCTIONS = (Function.READ_HOLDING_REGISTERS, Function.READ_INPUT_REGISTERS)

# Quantity limits of the Modbus application protocol (V1.1b3, §6).
MAX_READ_BITS = 2000
MAX_READ_REGISTERS = 125
MAX_WRITE_BITS = 1968
MAX_WRITE_REGISTERS = 123
MIN_FRAME = 4  # address, function, CRC


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray) -> int:
    """Modbus CRC-16 (poly 0xA001 reflected, init 0xFFFF); sent low byte first."""
    crc = 0xFFFF
    for byte in data:
        crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ byte) & 0xFF]
    return crc


def frame(unit: int, pdu: bytes) -> bytes:
    """An RTU ADU: unit, PDU, CRC (low byte first)."""
    adu = bytes([unit]) + pdu
    return adu + crc16(adu).to_bytes(2, "little")


def crc_ok(adu: bytes | bytearray) -> bool:
    return len(adu) >= MIN_FRAME and crc16(adu[:-2]) == int.from_bytes(adu[-2:], "little")


# -- requests ------------------------------------------------------------------


@dataclass(frozen=True)
class Request:
    """One request PDU, decoded. ``values`` carries what a write request writes."""

    unit: int
    function: int
    address: int
    count: int = 1
    values: tuple[bool | int, ...] = field(default=())

    def encode(self) -> bytes:
        fc = self.function
        head = bytes([fc]) + self.address.to_bytes(2, "big")
        if fc in READ_BIT_FUNCTIONS or fc in READ_REGISTER_FUNCTIONS:
            pdu = head + self.count.to_bytes(2, "big")
        elif fc == Function.WRITE_SINGLE_COIL:
            pdu = head + (b"\xff\x00" if self.values[0] else b"\x00\x00")
        elif fc == Function.WRITE_SINGLE_REGISTER:
            pdu = head + (self.values[0] & 0xFFFF).to_bytes(2, "big")
        elif fc == Function.WRITE_MULTIPLE_COILS:
            packed = pack_bits(self.values)
            pdu = head + len(self.values).to_bytes(2, "big") + bytes([len(packed)]) + packed
        elif fc == Function.WRITE_MULTIPLE_REGISTERS:
            data = b"".join((v & 0xFFFF).to_bytes(2, "big") for v in self.values)
            pdu = head + len(self.values).to_bytes(2, "big") + bytes([len(data)]) + data
        else:
            raise ValueError(f"function {fc} is not supported")
        return frame(self.unit, pdu)


def request_length(data: bytes | bytearray) -> int | None:
    """Length of the request ADU at the start of ``data``; None when more bytes are needed.

    Raises ValueError for a function code this codec does not know (the caller drops the
    frame, as a slave waits for the next silent interval).
    """
    if len(data) < 2:
        return None
    fc = data[1]
    if fc in (1, 2, 3, 4, 5, 6):
        return 8
    if fc in (15, 16):
        return None if len(data) < 7 else 9 + data[6]
    raise ValueError(f"unknown function code {fc}")


def parse_request(adu: bytes) -> Request:
    """Decode a complete request ADU whose CRC was checked. ValueError when malformed."""
    unit, fc = adu[0], adu[1]
    address = int.from_bytes(adu[2:4], "big")
    word = int.from_bytes(adu[4:6], "big")
    if fc in (1, 2, 3, 4):
        return Request(unit, fc, address, word)
    if fc == 5:
        if word not in (0x0000, 0xFF00):
            raise ValueError(f"write single coil value 0x{word:04X} is neither 0xFF00 nor 0x0000")
        return Request(unit, fc, address, 1, (word == 0xFF00,))
    if fc == 6:
        return Request(unit, fc, address, 1, (word,))
    data = adu[7:-2]
    if len(data) != adu[6]:
        raise ValueError("byte count does not match the data")
    if fc == 15:
        if (word + 7) // 8 != len(data):
            raise ValueError("byte count does not match the coil count")
        return Request(unit, fc, address, word, tuple(unpack_bits(data, word)))
    if fc == 16:
        if word * 2 != len(data):
            raise ValueError("byte count does not match the register count")
        return Request(
            unit,
            fc,
            address,
            word,
            tuple(int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)),
        )
    raise ValueError(f"unknown function code {fc}")


# -- responses -----------------------------------------------------------------


def read_bits_response(unit: int, function: int, bits: list[bool]) -> bytes:
    packed = pack_bits(bits)
    return frame(unit, bytes([function, len(packed)]) + packed)


def read_registers_response(unit: int, function: int, registers: list[int]) -> bytes:
    data = b"".join((r & 0xFFFF).to_bytes(2, "big") for r in registers)
    return frame(unit, bytes([function, len(data)]) + data)


def write_response(request: Request) -> bytes:
    """The echo a slave sends after a write (FC5/6 echo the request; FC15/16 address and count)."""
    head = bytes([request.function]) + request.address.to_bytes(2, "big")
    if request.function == Function.WRITE_SINGLE_COIL:
        return frame(request.unit, head + (b"\xff\x00" if request.values[0] else b"\x00\x00"))
    if request.function == Function.WRITE_SINGLE_REGISTER:
        return frame(request.unit, head + request.values[0].to_bytes(2, "big"))
    return frame(request.unit, head + request.count.to_bytes(2, "big"))


def exception_response(unit: int, function: int, code: int) -> bytes:
    return frame(unit, bytes([function | 0x80, code]))


def response_length(function: int, data: bytes) -> int | None:
    """Length of the response ADU for ``function`` at the start of ``data``; None if unknown yet."""
    if len(data) < 2:
        return None
    if data[1] & 0x80:
        return 5
    if function in READ_BIT_FUNCTIONS or function in READ_REGISTER_FUNCTIONS:
        return None if len(data) < 3 else 5 + data[2]
    return 8


def diagnose(unit: int, function: int, data: bytes) -> ErrorKind:
    """Why ``data`` (everything received after a request) is not a good reply."""
    if not data:
        return ErrorKind.TIMEOUT
    frames = list(_frames_with_good_crc(data, function))
    if any(u != unit for u, _ in frames):
        return ErrorKind.WRONG_ADDRESS
    if frames:
        return ErrorKind.GARBAGE  # a sound frame that is not an answer to this request
    if len(data) >= 2 and data[0] == unit and data[1] & 0x7F == function:
        expected = response_length(function, data)
        if expected is not None and len(data) >= expected:
            return ErrorKind.CRC
    return ErrorKind.GARBAGE


def _frames_with_good_crc(data: bytes, function: int) -> Iterator[tuple[int, int]]:
    """Every (unit, function) at any offset of ``data`` that forms a frame with a good CRC."""
    for start in range(len(data) - MIN_FRAME + 1):
        chunk = data[start:]
        if chunk[1] & 0x7F != function:
            continue
        length = response_length(function, chunk)
        if length is not None and len(chunk) >= length and crc_ok(chunk[:length]):
            yield chunk[0], chunk[1]


def inter_frame_gap(baudrate: int, bits_per_char: int = 11) -> float:
    """t3.5 of the Modbus serial line spec: 3.5 characters, fixed 1.75 ms above 19200 baud."""
    return 0.00175 if baudrate > 19200 else 3.5 * char_time(baudrate, bits_per_char)


# -- bit packing ---------------------------------------------------------------


def pack_bits(bits: Sequence[object]) -> bytes:
    """Coils/inputs to bytes, first bit in the LSB of the first byte."""
    out = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        if bit:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def unpack_bits(data: bytes, count: int) -> list[bool]:
    return [bool(data[i // 8] >> (i % 8) & 1) for i in range(count)]
