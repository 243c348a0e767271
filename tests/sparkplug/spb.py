"""A test-side Sparkplug B codec written from the schema's field numbers alone.

It shares no code with the front's encoder (which uses protobuf's generated module): the
tests decode what the gateway publishes, and encode the commands they send, with this
hand-written protobuf wire-format reader and writer.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any

# Sparkplug data types used in the tests
INT16, INT32, INT64, UINT8, UINT16, UINT32, UINT64, FLOAT, DOUBLE, BOOLEAN, STRING = (
    2,
    3,
    4,
    5,
    6,
    7,
    8,
    9,
    10,
    11,
    12,
)


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    shift = result = 0
    while True:
        if pos >= len(data):
            raise ValueError("truncated varint")
        byte = data[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, pos
        shift += 7


def _fields(data: bytes) -> list[tuple[int, int, Any]]:
    """(field number, wire type, raw value) of every field of one message."""
    out, pos = [], 0
    while pos < len(data):
        key, pos = _varint(data, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(data, pos)
        elif wire == 1:
            value, pos = data[pos : pos + 8], pos + 8
        elif wire == 2:
            length, pos = _varint(data, pos)
            value, pos = data[pos : pos + length], pos + length
        elif wire == 5:
            value, pos = data[pos : pos + 4], pos + 4
        else:
            raise ValueError(f"wire type {wire}")
        out.append((number, wire, value))
    return out


@dataclass
class Metric:
    name: str | None = None
    alias: int | None = None
    timestamp: int | None = None
    datatype: int | None = None
    is_historical: bool = False
    is_null: bool = False
    value: Any = None
    properties: dict[str, Any] = field(default_factory=dict)
    property_types: dict[str, int] = field(default_factory=dict)

    @property
    def quality(self) -> int:
        return self.properties.get("Quality", 192)


@dataclass
class Payload:
    timestamp: int | None = None
    seq: int | None = None
    metrics: list[Metric] = field(default_factory=list)


def _signed(value: int, datatype: int | None) -> int:
    bits = {INT16: 16, INT32: 32, INT64: 64, 1: 8}.get(datatype or 0)
    if bits is None:
        return value
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >> (bits - 1) else value


def _property_set(data: bytes) -> tuple[dict[str, Any], dict[str, int]]:
    keys: list[str] = []
    values: list[tuple[int, Any]] = []
    for number, _, raw in _fields(data):
        if number == 1:
            keys.append(raw.decode())
        elif number == 2:
            ptype, value = 0, None
            for n, _, r in _fields(raw):
                if n == 1:
                    ptype = r
                elif n in (3, 4):
                    value = r
                elif n == 5:
                    value = struct.unpack("<f", r)[0]
                elif n == 6:
                    value = struct.unpack("<d", r)[0]
                elif n == 7:
                    value = bool(r)
                elif n == 8:
                    value = r.decode()
            values.append((ptype, value))
    assert len(keys) == len(values), "PropertySet keys and values differ in length"
    return {k: v for k, (_, v) in zip(keys, values, strict=True)}, {
        k: t for k, (t, _) in zip(keys, values, strict=True)
    }


def _metric(data: bytes) -> Metric:
    m = Metric()
    for number, _, raw in _fields(data):
        if number == 1:
            m.name = raw.decode()
        elif number == 2:
            m.alias = raw
        elif number == 3:
            m.timestamp = raw
        elif number == 4:
            m.datatype = raw
        elif number == 5:
            m.is_historical = bool(raw)
        elif number == 7:
            m.is_null = bool(raw)
        elif number == 9:
            m.properties, m.property_types = _property_set(raw)
        elif number == 10:
            m.value = raw
        elif number == 11:
            m.value = raw
        elif number == 12:
            m.value = struct.unpack("<f", raw)[0]
        elif number == 13:
            m.value = struct.unpack("<d", raw)[0]
        elif number == 14:
            m.value = bool(raw)
        elif number == 15:
            m.value = raw.decode()
    return m


def decode(data: bytes) -> Payload:
    p = Payload()
    for number, _, raw in _fields(data):
        if number == 1:
            p.timestamp = raw
        elif number == 2:
            p.metrics.append(_metric(raw))
        elif number == 3:
            p.seq = raw
    return p


def value_of(metric: Metric, datatype: int | None) -> Any:
    """The metric's value as the datatype (from the BIRTH) says: signed ints sign-extended."""
    if isinstance(metric.value, int) and not isinstance(metric.value, bool):
        return _signed(metric.value, datatype)
    return metric.value


# -- encoding commands ------------------------------------------------------------------------
def _enc_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _key(number: int, wire: int) -> bytes:
    return _enc_varint(number << 3 | wire)


def _len(number: int, data: bytes) -> bytes:
    return _key(number, 2) + _enc_varint(len(data)) + data


def command_metric(
    *, name: str | None = None, alias: int | None = None, datatype: int, value: Any
) -> bytes:
    out = b""
    if name is not None:
        out += _len(1, name.encode())
    if alias is not None:
        out += _key(2, 0) + _enc_varint(alias)
    out += _key(4, 0) + _enc_varint(datatype)
    if datatype == BOOLEAN:
        out += _key(14, 0) + _enc_varint(int(bool(value)))
    elif datatype == FLOAT:
        out += _key(12, 5) + struct.pack("<f", value)
    elif datatype == DOUBLE:
        out += _key(13, 1) + struct.pack("<d", value)
    elif datatype == INT64:
        out += _key(11, 0) + _enc_varint(value & 0xFFFFFFFFFFFFFFFF)
    elif datatype == STRING:
        out += _len(15, str(value).encode())
    else:
        out += _key(10, 0) + _enc_varint(value & 0xFFFFFFFF)
    return out


def command(*metrics: bytes, timestamp: int = 0) -> bytes:
    return _key(1, 0) + _enc_varint(timestamp) + b"".join(_len(2, m) for m in metrics)
