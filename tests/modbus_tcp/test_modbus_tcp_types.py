"""The modbus-tcp front's map with 64-bit values, text and scaled channels: the front's order
for every value of two registers or more, the float32/float64/raw views of a scaled channel
(raw: the device's own value, a write converted back), and what a client cannot write."""

from __future__ import annotations

import struct

import pytest

from fieldgate.health import HealthRegistry
from fieldgate.image import ChannelSpec, DataType, Engineering, Kind, ProcessImage, Source
from fieldgate.plugins.modbus_tcp.map import HOLDING_REGISTERS, INPUT_REGISTERS, ModbusMap

VOLTS = Engineering(DataType.INT16, divider=10, decimals=1, unit="V", low=0, high=500)
BAR = Engineering(DataType.UINT32, gain=0.01, unit="bar", low=0, high=100)


def image() -> ProcessImage:
    img = ProcessImage(clock=lambda: 0.0)
    src = Source("m", 7, 0)
    img.add(ChannelSpec("m/m7/ai0", Kind.AI, src, dtype=DataType.INT64))
    img.add(ChannelSpec("m/m7/ai1", Kind.AI, src, dtype=DataType.FLOAT64))
    img.add(ChannelSpec("m/m7/ai2", Kind.AI, src, dtype=DataType.STRING, length=5))
    img.add(ChannelSpec("m/m7/ai3", Kind.AI, src, dtype=DataType.FLOAT64, engineering=VOLTS))
    img.add(ChannelSpec("m/m7/ao0", Kind.AO, src, dtype=DataType.FLOAT64, engineering=BAR))
    img.add(ChannelSpec("m/m7/ao1", Kind.AO, src, dtype=DataType.STRING, length=4))
    return img


def split(data: bytes) -> list[int]:
    return [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]


def make(img: ProcessImage, order: str = "ABCD", view: str = "float32") -> ModbusMap:
    return ModbusMap.from_channels(list(img), ["m/m7/ao*"], order, scaled_values=view)


def test_widths_and_the_front_s_order_on_reads():
    img, health = image(), HealthRegistry()
    img.update_inputs({"m/m7/ai0": -2, "m/m7/ai1": 1.5, "m/m7/ai2": "Ünï", "m/m7/ai3": 230.1})
    m = make(img, "DCBA")
    points = {p.what: p for p in m.points}
    assert [points[f"m/m7/ai{i}"].width for i in range(4)] == [4, 4, 3, 2]
    regs = m.read(4, 0, 13, img, health)
    assert regs[0:4] == split(struct.pack("<q", -2))  # DCBA: little-endian bytes
    assert regs[4:8] == split(struct.pack("<d", 1.5))
    assert regs[8:11] == split("Ünï".encode()[::-1].rjust(6, b"\0"))  # text byte-swapped
    assert regs[11:13] == split(struct.pack("<f", 230.1))  # the scaled value as a float32
    raw = make(img, "ABCD", "raw")
    assert raw.read(4, 11, 1, img, health) == [2301]  # the device's int16, tenths of a volt


def test_a_scaled_output_written_in_each_view():
    img = image()
    floats = make(img, "CDAB")
    address = next(p.address for p in floats.points if p.what == "m/m7/ao0")
    assert floats.write(16, address, split(struct.pack(">f", 42.5))[::-1]) == {"m/m7/ao0": 42.5}
    raw = make(img, "CDAB", "raw")
    assert raw.write(16, address, [4250, 0]) == {"m/m7/ao0": pytest.approx(42.5)}  # uint32 CDAB
    assert "raw of raw uint32 x 0.01" in raw.text()
    assert "float32 (scaled, bar, 0..100)" in floats.text()


def test_text_is_written_whole_and_nan_is_refused():
    img = image()
    m = make(img)
    text_at = next(p.address for p in m.points if p.what == "m/m7/ao1")
    assert m.write(16, text_at, split(b"AB\0\0")) == {"m/m7/ao1": "AB"}
    assert m.write(6, text_at, [0x4142]) == 3  # half of it: illegal data value
    view = make(img, "ABCD", "float64")
    at = next(p.address for p in view.points if p.what == "m/m7/ao0")
    assert view.write(16, at, split(struct.pack(">d", float("nan")))) == 3
    assert view.size(HOLDING_REGISTERS) == 4 + 2 and view.size(INPUT_REGISTERS) >= 4 + 4 + 3 + 4
