"""The modbus-tcp map and its exception rules, without a socket."""

from __future__ import annotations

import struct

from fieldgate.health import HealthRegistry, ModuleHealth
from fieldgate.image import ChannelSpec, DataType, Kind, ProcessImage, Quality, Source
from fieldgate.plugins.modbus_tcp.map import (
    COILS,
    DISCRETE_INPUTS,
    GATEWAY_NO_RESPONSE,
    HOLDING_REGISTERS,
    ILLEGAL_ADDRESS,
    ILLEGAL_FUNCTION,
    ILLEGAL_VALUE,
    INPUT_REGISTERS,
    ModbusMap,
)


def image() -> ProcessImage:
    img = ProcessImage(clock=lambda: 0.0)
    for i in range(3):
        img.add(ChannelSpec(f"b/m1/di{i}", Kind.DI, Source("b", 1, i)))
        img.add(ChannelSpec(f"b/m1/do{i}", Kind.DO, Source("b", 1, i)))
    img.add(ChannelSpec("b/m2/ai0", Kind.AI, Source("b", 2, 0)))
    img.add(ChannelSpec("b/m2/ai1", Kind.AI, Source("b", 2, 1), dtype=DataType.FLOAT32))
    img.add(ChannelSpec("b/m2/ao0", Kind.AO, Source("b", 2, 0), dtype=DataType.INT32))
    img.add(ChannelSpec("b/m2/ao1", Kind.AO, Source("b", 2, 1)))
    img.add(ChannelSpec("b/m2/so0", Kind.SO, Source("b", 2, 0)))
    return img


def make(img: ProcessImage, **kw: object) -> ModbusMap:
    return ModbusMap.from_channels(
        list(img), writable=["b/m1/do[12]", "b/m2/ao0", "b/m2/so0"], **kw
    )  # type: ignore[arg-type]


def test_tables_addresses_and_widths():
    m = make(image())
    assert m.size(COILS) == 3 and m.size(DISCRETE_INPUTS) == 3
    assert m.size(HOLDING_REGISTERS) == 2 + 1 + 1  # int32 ao0, int16 ao1, so0
    assert m.size(INPUT_REGISTERS) == 1 + 2 + 2 * 2  # ai0, float ai1, 2 status registers per module
    points = {p.what: p for p in m.points}
    assert (points["b/m2/ao0"].address, points["b/m2/ao0"].width) == (0, 2)
    assert points["b/m2/ao1"].address == 2 and points["b/m2/so0"].address == 3
    assert points["b/m1 status"].address == 3 and points["b/m2 error counter"].address == 6
    assert [p.what for p in m.points if p.writable] == [
        "b/m1/do1",
        "b/m1/do2",
        "b/m2/ao0",
        "b/m2/so0",
    ]


def test_reads_encode_values_and_module_status():
    img, health = image(), HealthRegistry()
    m = make(img)
    img.update_input("b/m1/di1", True)
    img.update_input("b/m2/ai0", -2)
    img.update_input("b/m2/ai1", 1.5)
    img.write_output("b/m2/ao0", -70000)
    assert m.read(2, 0, 3, img, health) == [False, True, False]
    high, low = struct.unpack(">HH", struct.pack(">f", 1.5))
    assert m.read(4, 0, 3, img, health) == [0xFFFE, high, low]
    assert m.read(3, 0, 2, img, health) == [(-70000 >> 16) & 0xFFFF, -70000 & 0xFFFF]
    little = make(img, word_order="little")
    assert little.read(3, 0, 2, img, health) == [-70000 & 0xFFFF, (-70000 >> 16) & 0xFFFF]
    # module 1: online (unknown to health counts as online), not all inputs good (di0/di2 not read)
    assert m.read(4, 3, 1, img, health) == [0b01]
    assert m.read(4, 1, 1, img, health) == [high]  # half of a 32-bit value may be read
    module2 = health.add(ModuleHealth("b", 2, error_counter=70000))
    module2.online = False
    assert m.read(4, 5, 2, img, health) == [0b10, 70000 & 0xFFFF]  # offline, inputs good; wraps


def test_exceptions():
    img, health = image(), HealthRegistry()
    m = make(img)
    assert m.read(1, 2, 2, img, health) == ILLEGAL_ADDRESS  # one past the end
    assert m.read(4, 7, 1, img, health) == ILLEGAL_ADDRESS
    assert m.read_error(3, 0, 5) == ILLEGAL_ADDRESS and m.read_error(3, 0, 4) is None
    assert m.write(5, 0, [True]) == ILLEGAL_FUNCTION  # do0 is served, not writable
    assert m.write(15, 0, [True, True]) == ILLEGAL_FUNCTION  # one refused point refuses all
    assert m.write(15, 1, [True, True, True]) == ILLEGAL_ADDRESS
    assert m.write(6, 1, [5]) == ILLEGAL_VALUE  # the low half of int32 ao0
    assert m.write(6, 0, [5]) == ILLEGAL_VALUE  # only the high half
    assert m.write(6, 2, [5]) == ILLEGAL_FUNCTION  # ao1 is not writable
    assert m.write(6, 3, [256]) == ILLEGAL_VALUE  # a byte
    # a write is one batch: channel id -> value
    assert m.write(16, 0, [0xFFFE, 0x0000]) == {"b/m2/ao0": -131072}
    assert m.write(15, 1, [True, False]) == {"b/m1/do1": True, "b/m1/do2": False}
    assert m.write(6, 3, [255]) == {"b/m2/so0": 255}


def test_comm_fault_exception_only_when_asked():
    img, health = image(), HealthRegistry()
    img.update_input("b/m2/ai0", 7)
    img.set_quality(["b/m2/ai0"], Quality.COMM_FAULT)
    assert make(img).read(4, 0, 1, img, health) == [7]
    strict = make(img, comm_fault_exception=True)
    assert strict.read(4, 0, 1, img, health) == GATEWAY_NO_RESPONSE
    assert strict.read(4, 1, 2, img, health) != GATEWAY_NO_RESPONSE  # other points unaffected


def test_the_printed_map_lists_every_point():
    text = make(image()).text()
    assert "holding register (FC3 / FC6, FC16)  0-1      b/m2/ao0" in text
    assert "b/m1/do1" in text and "read/write" in text
    assert text.rstrip().endswith("values wider than a register: ABCD order")
