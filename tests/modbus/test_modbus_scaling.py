"""Types that must fit their registers, scaling applied once in the back and inverted for writes,
over/under-range quality, on a real RTU line (the simulator on a pty pair)."""

from __future__ import annotations

import pytest
from modbus_line import Line

from fieldgate import DataType, Quality
from fieldgate.plugins.modbus.points import Table
from fieldgate.plugins.modbus.simulator import SimModule
from fieldgate.topology import TopologyError, load_topology


def topology(channels: list[dict], **module: object) -> dict:
    return {
        "gateway": {"name": "t"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "modules": [{"address": 1, "channels": channels, **module}],
            }
        ],
    }


def errors(registry, channels: list[dict], **module: object) -> list[str]:
    with pytest.raises(TopologyError) as info:
        load_topology(topology(channels, **module), registry)
    return [f"{i.path}: {i.message}" for i in info.value.issues]


AI = {"kind": "ai", "table": "holding_registers", "address": 0}


@pytest.mark.parametrize(
    "group, message",
    [
        ({**AI, "type": "float64", "registers": 2}, "a float64 takes 4 registers, the map gives 2"),
        ({**AI, "type": "int16", "registers": 2}, "int16 takes 1 register, the map gives 2"),
        ({**AI, "type": "string", "length": 10, "registers": 4}, "takes 5 registers, not 4"),
        ({**AI, "type": "string"}, "type string needs its length"),
        ({**AI, "type": "int16", "order": "CDAB"}, "an int16 is one register"),
        ({**AI, "type": "float32", "order": "GHEFCDAB"}, "names the 8 bytes of a 64-bit value"),
        ({**AI, "type": "int32", "order": "CDAB", "word_order": "big"}, "disagree"),
        ({**AI, "bits": 5, "count": 4}, "would cross into the next register"),
        ({**AI, "bits": 4, "type": "uint16"}, "bits applies to analog channels"),
        ({**AI, "type": "string", "length": 4, "gain": 2}, "applies to numbers in registers"),
        ({"kind": "di", "table": "coils", "address": 0, "unit": "V"}, "not to di channels"),
        ({**AI, "gain": 2, "divider": 10}, "give gain or divider, not both"),
        ({**AI, "range": [10, 0]}, "low is above high"),
        ({**AI, "gain": 0}, "gain 0"),
        (
            {
                "kind": "ao",
                "table": "holding_registers",
                "address": 0,
                "type": "int64",
                "write_fc": 6,
            },
            "an int64 takes 4 registers: it needs write_fc 16",
        ),
    ],
)
def test_a_type_that_does_not_fit_its_registers_is_refused(registry, group, message):
    issues = errors(registry, [group])
    assert any(message in issue for issue in issues), issues


def test_a_value_wider_than_the_module_reads_at_once_is_refused(registry):
    issues = errors(registry, [{**AI, "type": "float64"}], max_read_registers=2)
    assert any("takes 4 registers, more than max_read_registers 2" in i for i in issues), issues


def test_scaled_channels_are_float64_with_their_engineering_units(registry):
    topo = load_topology(
        topology(
            [
                {**AI, "divider": 10, "decimals": 1, "unit": "°C", "range": [-40, 125]},
                {**AI, "address": 1, "type": "uint32", "gain": 0.001, "offset": -5},
                {**AI, "address": 3, "unit": "bar", "range": [0, 10]},  # a unit, no conversion
                {**AI, "address": 4, "type": "string", "length": 8, "label": "Serial number"},
            ]
        ),
        registry,
    )
    specs = {s.id: s for s in topo.channel_specs}
    temp, energy, pressure, serial = (specs[f"rs485/m1/ai{i}"] for i in range(4))
    assert temp.data_type is DataType.FLOAT64 and temp.engineering is not None
    assert temp.engineering.divider == 10 and temp.engineering.unit == "°C"
    assert temp.engineering.eu_range == (-40, 125)
    assert energy.data_type is DataType.FLOAT64 and energy.engineering.raw_type is DataType.UINT32
    assert pressure.data_type is DataType.INT16 and pressure.engineering.unit == "bar"
    assert serial.data_type is DataType.STRING and serial.length == 8
    assert serial.label == "Serial number"


SCALED = [
    {**AI, "divider": 10, "decimals": 1, "unit": "°C", "range": [-40, 125]},
    {**AI, "address": 1, "type": "float32", "order": "BADC", "unit": "V", "range": [0, 300]},
    {
        "kind": "ao",
        "table": "holding_registers",
        "address": 10,
        "type": "uint32",
        "order": "CDAB",
        "gain": 0.01,
        "unit": "bar",
        "range": [0, 100],
    },
]


async def test_scaling_is_applied_once_in_the_back_with_range_quality(make_line):
    line: Line = await make_line([{"address": 1, "channels": SCALED}])
    module: SimModule = line.sim.modules[1]
    cells = module.tables[Table.HOLDING_REGISTERS]
    cells[0] = 235  # raw: 23.5 °C
    cells[1], cells[2] = 0x6643, 0x9919  # 230.1 V, byte-swapped
    await line.run_due()
    assert line.image.value("rs485/m1/ai0") == 23.5
    assert line.image.value("rs485/m1/ai1") == pytest.approx(230.1, rel=1e-6)
    assert line.image["rs485/m1/ai0"].quality is Quality.GOOD
    cells[0] = 1300  # 130.0 °C: above the range
    cells[1], cells[2] = 0xC0BF, 0x0000  # -1.5 V (BADC of 0xBFC00000): below
    await line.cycle()
    assert line.image.value("rs485/m1/ai0") == 130.0
    assert line.image["rs485/m1/ai0"].quality is Quality.OVER_RANGE
    assert line.image.value("rs485/m1/ai1") == -1.5
    assert line.image["rs485/m1/ai1"].quality is Quality.UNDER_RANGE


async def test_a_scaled_output_is_written_back_as_raw_in_its_order(make_line):
    line: Line = await make_line([{"address": 1, "channels": SCALED}])
    await line.run_due()
    line.image.write_output("rs485/m1/ao0", 12.34)  # bar -> raw 1234, uint32 CDAB
    await line.run_due()
    cells = line.sim.modules[1].tables[Table.HOLDING_REGISTERS]
    assert [cells[10], cells[11]] == [1234, 0]
    assert (16, 10, 2) in [(f, a, c) for _u, f, a, c in line.requests()]
    with pytest.raises(ValueError, match="outside the range 0.0..100.0"):
        line.image.write_output("rs485/m1/ao0", 150.0)
    assert line.sim.get_output("rs485/m1/ao0") == pytest.approx(12.34)


async def test_64_bit_values_text_and_bit_fields_on_the_line(make_line):
    channels = [
        {**AI, "type": "uint64", "order": "CDAB"},
        {**AI, "address": 4, "type": "int64", "order": "DCBA"},
        {**AI, "address": 8, "type": "float64", "order": "BADC"},
        {**AI, "address": 12, "type": "string", "length": 10},
        {**AI, "address": 20, "count": 4, "bits": 4},
        {"kind": "ao", "table": "holding_registers", "address": 30, "type": "string", "length": 6},
        {
            "kind": "ao",
            "table": "holding_registers",
            "address": 33,
            "type": "int64",
            "order": "CDAB",
        },
    ]
    line: Line = await make_line([{"address": 1, "channels": channels}])
    line.sim.set_input("rs485/m1/ai0", 2**64 - 2)
    line.sim.set_input("rs485/m1/ai1", -(2**62) + 7)
    line.sim.set_input("rs485/m1/ai2", 1.0e100)
    line.sim.set_input("rs485/m1/ai3", "SN-42")
    line.sim.modules[1].tables[Table.HOLDING_REGISTERS][20] = 0xABCD
    await line.run_due()
    image = line.image
    assert image.value("rs485/m1/ai0") == 2**64 - 2
    assert image.value("rs485/m1/ai1") == -(2**62) + 7
    assert image.value("rs485/m1/ai2") == 1.0e100
    assert image.value("rs485/m1/ai3") == "SN-42"
    assert [image.value(f"rs485/m1/ai{i}") for i in range(4, 8)] == [0xD, 0xC, 0xB, 0xA]
    image.write_outputs({"rs485/m1/ao0": "ÜBER", "rs485/m1/ao1": -5})
    await line.run_due()
    cells = line.sim.modules[1].tables[Table.HOLDING_REGISTERS]
    assert [cells[30], cells[31], cells[32]] == [0xC39C, 0x4245, 0x5200]  # UTF-8, NUL padded
    assert [cells[a] for a in range(33, 37)] == [0xFFFB, 0xFFFF, 0xFFFF, 0xFFFF]  # CDAB of -5
    with pytest.raises(ValueError, match="longer than the 6 bytes"):
        image.write_output("rs485/m1/ao0", "seven!!")
