"""si/so byte blocks (a high-speed counter's raw data, NA-9161 special modules) on Modbus:
declaration, points, reads and writes through the simulator, the simulator's animation."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from fieldgate.image import DataType, Kind
from fieldgate.plugins.modbus import values as regvalues
from fieldgate.plugins.modbus.config import ModbusBackConfig, module_points
from fieldgate.plugins.modbus.simulator import _animated_value

HSC = {
    "address": 6,
    "channels": [
        {"kind": "si", "table": "input_registers", "address": 0, "count": 6},
        {"kind": "so", "table": "holding_registers", "address": 0, "count": 2},
    ],
}


def back(*modules: dict) -> ModbusBackConfig:
    return ModbusBackConfig(name="rs485", port="/dev/null", modules=list(modules))


def test_a_byte_block_is_one_uint8_channel_per_byte_two_per_register():
    cfg = back(HSC)
    specs = {s.id: s for s in cfg.channel_specs()}
    assert [s.kind for s in specs.values()] == [Kind.SI] * 6 + [Kind.SO] * 2
    assert {s.data_type for s in specs.values()} == {DataType.UINT8}
    points = module_points("rs485", cfg.modules[0])
    # byte_order big (default): byte 0 is the high byte of the first register, as on the wire
    assert [(p.address, p.bit) for p in points[:6]] == [
        (0, 8),
        (0, 0),
        (1, 8),
        (1, 0),
        (2, 8),
        (2, 0),
    ]
    little = {**HSC, "channels": [{**HSC["channels"][1], "byte_order": "little"}]}
    assert [(p.address, p.bit) for p in module_points("rs485", back(little).modules[0])] == [
        (0, 0),
        (0, 8),
    ]


@pytest.mark.parametrize(
    "group, message",
    [
        (
            {"kind": "so", "table": "input_registers", "address": 0},
            "cannot live in input_registers",
        ),
        (
            {"kind": "si", "table": "discrete_inputs", "address": 0},
            "cannot live in discrete_inputs",
        ),
        ({"kind": "si", "table": "input_registers", "address": 0, "type": "int16"}, "type applies"),
        (
            {"kind": "ai", "table": "input_registers", "address": 0, "byte_order": "big"},
            "byte_order",
        ),
        ({"kind": "si", "table": "input_registers", "address": 0, "first_bit": 3}, "first_bit"),
    ],
)
def test_bad_byte_block_declarations_are_refused_with_a_reason(group, message):
    with pytest.raises(ValidationError, match=message):
        back({"address": 1, "channels": [group]})


def test_overlapping_output_bytes_are_refused():
    groups = [
        {"kind": "so", "table": "holding_registers", "address": 0, "count": 2},
        {"kind": "do", "table": "holding_registers", "address": 0, "count": 1, "first_bit": 9},
    ]
    with pytest.raises(ValidationError, match="overlap"):
        back({"address": 1, "channels": groups})


def test_register_fields():
    assert regvalues.get_field(0x1234, 8, 8) == 0x12
    assert regvalues.get_field(0x1234, 0, 8) == 0x34
    assert regvalues.set_field(0x1234, 8, 8, 0xAB) == 0xAB34
    assert regvalues.set_field(0x1234, 0, 8, 0xAB) == 0x12AB
    assert regvalues.set_field(0x0000, 15, 1, True) == 0x8000
    assert regvalues.get_field(0xABCD, 4, 4) == 0xC
    with pytest.raises(ValueError):
        regvalues.set_field(0, 0, 8, 256)


async def test_a_counter_block_is_read_and_written_through_the_simulated_line(make_line):
    line = await make_line([HSC])
    sim, image = line.sim, line.image
    for i, byte in enumerate((0x01, 0x02, 0x03, 0x04, 0x05, 0x06)):
        sim.set_input(f"rs485/m6/si{i}", byte)
    registers = sim.modules[6].tables[sim.channels["rs485/m6/si0"][1].table]
    assert [registers[a] for a in range(3)] == [0x0102, 0x0304, 0x0506]
    await line.run_due()
    assert [image.value(f"rs485/m6/si{i}") for i in range(6)] == [1, 2, 3, 4, 5, 6]
    line.requests()
    image.write_output("rs485/m6/so0", 0x10)
    image.write_output("rs485/m6/so1", 0x27)
    await line.run_due()
    assert (sim.get_output("rs485/m6/so0"), sim.get_output("rs485/m6/so1")) == (0x10, 0x27)
    holding = sim.modules[6].tables[sim.channels["rs485/m6/so0"][1].table]
    assert holding[0] == 0x1027
    writes = [r for r in line.requests() if r[1] in (6, 16)]
    assert writes == [(6, 6, 0, 1)]  # both bytes of the register in one write


def test_the_simulator_animates_a_counter_block_as_a_little_endian_count():
    (p0, p1, *_rest) = module_points("rs485", back(HSC).modules[0])
    tick = 0x1234
    assert (_animated_value(p0, tick), _animated_value(p1, tick)) == (0x34, 0x12)
