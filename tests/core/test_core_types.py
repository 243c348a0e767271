"""The image's 64-bit, float64 and text channels, engineering units, and fronts that carry only the
types up to 32 bits (a CAN front's 16-bit words, a front written before them): what they leave
out, and the error when a topology names such a channel for them."""

from __future__ import annotations

import pytest

from fieldgate import load_registry
from fieldgate.image import (
    NARROW_TYPES,
    ChannelSpec,
    DataType,
    Engineering,
    Kind,
    ProcessImage,
    Quality,
    Source,
)
from fieldgate.plugin import GatewayContext
from fieldgate.topology import TopologyError, load_topology

CHANNELS = [
    {"kind": "ai", "table": "input_registers", "address": 0},
    {"kind": "ai", "table": "input_registers", "address": 1, "type": "uint64"},
    {"kind": "ai", "table": "input_registers", "address": 5, "type": "string", "length": 4},
    {"kind": "ai", "table": "input_registers", "address": 7, "divider": 10},
]


def topology(**front: object) -> dict:
    return {
        "gateway": {"name": "t"},
        "fronts": [{"name": "plc", "type": "memory", **front}],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "modules": [{"address": 1, "channels": CHANNELS}],
            }
        ],
    }


def test_a_front_that_carries_32_bits_leaves_out_wider_channels_and_validate_says_so():
    topo = load_topology(topology(), load_registry())
    served = GatewayContext.build(topo).front_channels(topo.front("plc"))
    assert [c.id for c in served] == ["rs485/m1/ai0"]
    (warning,) = topo.warnings()
    assert warning.startswith("fronts.plc: 3 channel(s) of a type a memory front cannot carry")
    assert "(float64, string, uint64)" in warning and "rs485/m1/ai1" in warning
    assert "fronts.plc: 3 channel(s)" in topo.summary()


def test_a_glob_leaves_them_out_and_an_id_is_an_error():
    topo = load_topology(topology(expose=["rs485/m1/*"]), load_registry())
    assert len(GatewayContext.build(topo).front_channels(topo.front("plc"))) == 1
    with pytest.raises(TopologyError) as info:
        load_topology(topology(expose=["rs485/m1/ai0", "rs485/m1/ai2"]), load_registry())
    (issue,) = info.value.issues
    assert issue.path == "fronts[0].expose[1]"
    assert "rs485/m1/ai2 is string: a memory front carries only" in issue.message


def test_the_north_facing_fronts_carry_every_type():
    registry = load_registry()
    for front_type in ("opcua", "modbus-tcp", "sparkplug"):
        ctype = registry.lookup("front", front_type)
        assert ctype is not None and ctype.model.carried_types is None  # type: ignore[union-attr]
    assert DataType.INT64 not in NARROW_TYPES and DataType.INT16 in NARROW_TYPES


def test_64_bit_and_text_channels_hold_what_they_are_given():
    image = ProcessImage(clock=lambda: 0.0)
    src = Source("b", 1, 0)
    image.add(ChannelSpec("b/m1/ai0", Kind.AI, src, dtype=DataType.UINT64))
    image.add(ChannelSpec("b/m1/ai1", Kind.AI, src, dtype=DataType.STRING, length=4))
    image.add(ChannelSpec("b/m1/ao0", Kind.AO, src, dtype=DataType.STRING, length=4))
    assert image.value("b/m1/ai1") == ""
    image.update_inputs({"b/m1/ai0": 2**64 - 1, "b/m1/ai1": "ABCD"})
    assert image.value("b/m1/ai0") == 2**64 - 1
    with pytest.raises(ValueError, match="outside uint64"):
        image.update_input("b/m1/ai0", 2**64)
    with pytest.raises(ValueError, match="text of 5 bytes is longer than the 4 bytes"):
        image.write_output("b/m1/ao0", "ABCDE")
    with pytest.raises(ValueError, match="expected text"):
        image.write_output("b/m1/ao0", 5)
    image.write_output("b/m1/ao0", "Ü12")  # 4 bytes in UTF-8
    assert image.value("b/m1/ao0") == "Ü12"


def test_engineering_units_convert_both_ways_and_bound_outputs():
    eng = Engineering(DataType.UINT32, gain=0.01, unit="bar", low=0, high=100)
    assert eng.from_raw(4242) == pytest.approx(42.42)
    assert eng.to_raw(42.42) == 4242
    assert eng.range_quality(101) is Quality.OVER_RANGE
    assert eng.range_quality(-1) is Quality.UNDER_RANGE
    assert eng.range_quality(50) is None
    tenths = Engineering(DataType.INT16, divider=10, decimals=1, offset=-40)
    assert tenths.from_raw(653) == 25.3 and tenths.to_raw(25.3) == 653
    with pytest.raises(ValueError, match="outside int16"):
        tenths.to_raw(4000)
    image = ProcessImage(clock=lambda: 0.0)
    image.add(
        ChannelSpec("b/m1/ao0", Kind.AO, Source("b", 1, 0), dtype=DataType.FLOAT64, engineering=eng)
    )
    image.write_output("b/m1/ao0", 99.5)
    with pytest.raises(ValueError, match="outside the range 0..100"):
        image.write_output("b/m1/ao0", 100.5)
    assert image.value("b/m1/ao0") == 99.5
