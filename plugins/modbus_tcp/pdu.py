"""Modbus request PDUs: decoding what a client asks and encoding the answers (no I/O).

The function codes served are FC1-6, FC15, FC16 and FC23 (Modbus Application Protocol
V1.1b3, sections 6.1-6.12 and 6.17); any other code, defined or not, is answered with
exception 01. The checks follow the standard's state diagrams, in its order: the function
code (01), then the PDU's length, the quantity, the byte count and the FC5 value (03); the
addresses (02) are the map's (:mod:`.map`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

ILLEGAL_FUNCTION, ILLEGAL_ADDRESS, ILLEGAL_VALUE = 0x01, 0x02, 0x03  # exception codes (section 7)
SERVER_DEVICE_FAILURE, GATEWAY_NO_RESPONSE = 0x04, 0x0B

READ_BITS = (1, 2)
READ_REGISTERS = (3, 4)
WRITE_COIL, WRITE_REGISTER, WRITE_COILS, WRITE_REGISTERS, READ_WRITE_REGISTERS = 5, 6, 15, 16, 23
SERVED = frozenset((1, 2, 3, 4, 5, 6, 15, 16, 23))
MAX_READ = {1: 2000, 2: 2000, 3: 125, 4: 125, 23: 125}  # quantities the standard allows
MAX_WRITE = {15: 1968, 16: 123, 23: 121}
COIL_ON, COIL_OFF = 0xFF00, 0x0000

_ADDRESS_COUNT = struct.Struct(">HH")
_READ_WRITE = struct.Struct(">HHHHB")


@dataclass(frozen=True, slots=True)
class Read:
    """FC1-4: ``count`` points from ``address``."""

    fc: int
    address: int
    count: int


@dataclass(frozen=True, slots=True)
class Write:
    """FC5/6/15/16: ``values`` (bools for coils, 16-bit words for registers) from ``address``."""

    fc: int
    address: int
    values: list[bool] | list[int]


@dataclass(frozen=True, slots=True)
class ReadWrite:
    """FC23: the write is done first, then the read (section 6.17)."""

    write: Write
    read: Read

    fc = READ_WRITE_REGISTERS


Request = Read | Write | ReadWrite


def decode(pdu: bytes) -> Request | int:
    """The request in ``pdu`` (function code first), or the exception code to answer."""
    fc = pdu[0]
    body = pdu[1:]
    if fc not in SERVED:
        return ILLEGAL_FUNCTION
    if fc in READ_BITS or fc in READ_REGISTERS:
        if len(body) != 4:
            return ILLEGAL_VALUE
        address, count = _ADDRESS_COUNT.unpack(body)
        return Read(fc, address, count) if 1 <= count <= MAX_READ[fc] else ILLEGAL_VALUE
    if fc == WRITE_COIL:
        if len(body) != 4:
            return ILLEGAL_VALUE
        address, value = _ADDRESS_COUNT.unpack(body)
        if value not in (COIL_ON, COIL_OFF):
            return ILLEGAL_VALUE
        return Write(fc, address, [value == COIL_ON])
    if fc == WRITE_REGISTER:
        if len(body) != 4:
            return ILLEGAL_VALUE
        address, value = _ADDRESS_COUNT.unpack(body)
        return Write(fc, address, [value])
    if fc == READ_WRITE_REGISTERS:
        if len(body) < 9:
            return ILLEGAL_VALUE
        read_address, read_count, address, count, size = _READ_WRITE.unpack_from(body)
        if not 1 <= read_count <= MAX_READ[fc]:
            return ILLEGAL_VALUE
        write = _multiple(fc, address, count, size, body[9:])
        if isinstance(write, int):
            return write
        return ReadWrite(write, Read(fc, read_address, read_count))
    if len(body) < 5:  # FC15 / FC16: address, quantity, byte count, data
        return ILLEGAL_VALUE
    address, count = _ADDRESS_COUNT.unpack_from(body)
    return _multiple(fc, address, count, body[4], body[5:])


def _multiple(fc: int, address: int, count: int, size: int, data: bytes) -> Write | int:
    if not 1 <= count <= MAX_WRITE[fc]:
        return ILLEGAL_VALUE
    if fc == WRITE_COILS:
        if size != (count + 7) // 8 or len(data) != size:
            return ILLEGAL_VALUE
        return Write(fc, address, [bool(data[i >> 3] >> (i & 7) & 1) for i in range(count)])
    if size != 2 * count or len(data) != size:
        return ILLEGAL_VALUE
    return Write(fc, address, list(struct.unpack(f">{count}H", data)))


def exception(fc: int, code: int) -> bytes:
    return bytes((fc | 0x80, code))


def encode_read(fc: int, values: list[bool] | list[int]) -> bytes:
    """The answer to FC1-4 and FC23: the byte count, then the bits (LSB first) or the words."""
    if fc in READ_BITS:
        packed = bytearray((len(values) + 7) // 8)
        for i, bit in enumerate(values):
            if bit:
                packed[i >> 3] |= 1 << (i & 7)
        return bytes((fc, len(packed))) + packed
    return bytes((fc, 2 * len(values))) + struct.pack(f">{len(values)}H", *values)


def encode_write(request: Write, pdu: bytes) -> bytes:
    """The answer to a write: FC5/6 echo the request, FC15/16 its address and quantity."""
    if request.fc in (WRITE_COIL, WRITE_REGISTER):
        return pdu
    return pdu[:5]
