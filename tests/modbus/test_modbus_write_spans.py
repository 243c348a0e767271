"""Write spans: the outputs of one module changed in one batch (one RPDO) reach it in one
FC15/FC16 from the lowest to the highest changed address, the outputs in between at the values
the gateway holds; separate writes where it holds no value (docs/modbus.md, "Requests on the
wire"). Against the simulator on a pty (the scheduler on a fake clock) and pymodbus's server."""

from __future__ import annotations

import asyncio
import logging

from pymodbus import FramerType
from pymodbus.server import ModbusSerialServer
from pymodbus.simulator import DataType as PmType
from pymodbus.simulator import SimData, SimDevice

from fieldgate import ProcessImage
from fieldgate.plugins.modbus.back import ModbusModule
from fieldgate.plugins.modbus.client import ModbusLink
from fieldgate.plugins.modbus.config import ModbusBackConfig
from fieldgate.plugins.modbus.points import Table
from fieldgate.plugins.modbus.simulator import Fault

WRITES = (5, 6, 15, 16)


def do(i: int) -> str:
    return f"rs485/m3/do{i}"


async def test_coils_0_1_5_of_one_batch_are_one_fc15_of_6_coils(make_line):
    line = await make_line([{"address": 3, "model": "M-7055D"}])
    await line.run_due()
    line.image.write_outputs({do(i): i == 3 for i in range(8)})  # the PLC's first RPDO: 0x08
    await line.run_due()
    line.requests()
    line.image.write_outputs({do(i): i in (0, 1, 3, 5) for i in range(8)})  # 0x2B
    await line.run_due()
    assert [r for r in line.requests() if r[1] in WRITES] == [(3, 15, 0, 6)]
    assert [line.sim.get_output(do(i)) for i in range(8)] == [i in (0, 1, 3, 5) for i in range(8)]


async def test_registers_of_one_batch_are_one_fc16_once_the_ones_between_are_known(make_line):
    line = await make_line([{"address": 4, "model": "M-7024"}])
    await line.run_due()
    line.image.write_output("rs485/m4/ao1", 111)
    await line.run_due()
    line.requests()
    # ao2 was never set by anyone: its value on the module is unknown, so no span over it
    line.image.write_outputs({"rs485/m4/ao0": 5, "rs485/m4/ao3": 6})
    await line.run_due()
    assert [r for r in line.requests() if r[1] in WRITES] == [(4, 6, 0, 1), (4, 6, 3, 1)]
    line.image.write_output("rs485/m4/ao2", 222)
    await line.run_due()
    line.requests()
    line.image.write_outputs({"rs485/m4/ao0": -1, "rs485/m4/ao3": -2})
    await line.run_due()
    assert [r for r in line.requests() if r[1] in WRITES] == [(4, 16, 0, 4)]
    assert [line.sim.get_output(f"rs485/m4/ao{i}") for i in range(4)] == [-1, 111, 222, -2]


async def test_write_span_false_keeps_separate_writes(make_line):
    line = await make_line([{"address": 3, "model": "M-7055D", "write_span": False}])
    await line.run_due()
    line.image.write_outputs({do(i): False for i in range(8)})
    await line.run_due()
    line.requests()
    line.image.write_outputs({do(0): True, do(5): True})
    await line.run_due()
    assert [r for r in line.requests() if r[1] in WRITES] == [(3, 5, 0, 1), (3, 5, 5, 1)]


async def test_a_refused_span_names_its_channels_and_the_changes_go_alone(make_line, caplog):
    line = await make_line([{"address": 3, "model": "M-7055D"}])
    await line.run_due()
    line.image.write_outputs({do(i): False for i in range(8)})
    await line.run_due()
    line.requests()
    line.sim.inject(3, Fault("exception", code=2, table=Table.COILS, address=3))
    with caplog.at_level(logging.WARNING, logger="fieldgate.modbus"):
        line.image.write_outputs({do(0): True, do(5): True})
        await line.run_due()
    assert [r for r in line.requests() if r[1] in WRITES] == [
        (3, 15, 0, 6),  # refused: coil 3 is
        (3, 5, 0, 1),
        (3, 5, 5, 1),
    ]
    (warning,) = [r.getMessage() for r in caplog.records if "refused FC15" in r.getMessage()]
    assert all(do(i) in warning for i in range(6))
    assert line.sim.get_output(do(0)) is True and line.sim.get_output(do(5)) is True
    assert line.module(3).write_refused == {do(i) for i in range(1, 5)}
    assert line.health[3].online and line.scheduler.pending_writes == 0
    # the refused held values fill no span until each is written again
    line.image.write_outputs({do(0): False, do(5): False})
    await line.run_due()
    assert [r for r in line.requests() if r[1] in WRITES] == [(3, 5, 0, 1), (3, 5, 5, 1)]


async def test_pymodbus_server_sees_one_request_per_batch(fieldgate_pty):
    config = ModbusBackConfig(
        name="rs485",
        port="unused",
        baudrate=115200,
        modules=[
            {
                "address": 1,
                "channels": [
                    {"kind": "do", "table": "coils", "address": 0, "count": 8},
                    {"kind": "ao", "table": "holding_registers", "address": 0, "count": 6},
                ],
            }
        ],
    )
    image = ProcessImage()
    for spec in config.channel_specs():
        image.add(spec)
    seen: list[tuple[int, int, int]] = []

    def trace(sending: bool, pdu):
        if not sending:
            count = len(getattr(pdu, "bits", []) or getattr(pdu, "registers", []) or [])
            seen.append((pdu.function_code, pdu.address, count))
        return pdu

    pair = fieldgate_pty()
    device = SimDevice(
        1,
        simdata=(
            [SimData(0, count=16, values=False, datatype=PmType.BITS)],
            [SimData(0, count=16, values=False, datatype=PmType.BITS)],
            [SimData(0, count=16, values=0, datatype=PmType.REGISTERS)],
            [SimData(0, count=16, values=0, datatype=PmType.REGISTERS)],
        ),
    )
    server = ModbusSerialServer(
        [device], framer=FramerType.RTU, port=pair.b, baudrate=115200, trace_pdu=trace
    )
    task = asyncio.ensure_future(server.serve_forever())
    link = ModbusLink(pair.a, baudrate=115200, timeout=0.5, inter_frame=0)
    try:
        await asyncio.sleep(0.3)
        await link.open()
        (module_config,) = config.modules
        points = config.points()[1]
        module = ModbusModule(module_config, [], link, points, clock=lambda: 0.0, image=image)
        changes = image.write_outputs(
            {**{f"rs485/m1/do{i}": i == 3 for i in range(8)}, "rs485/m1/ao2": 7, "rs485/m1/ao3": 8}
        )
        await module.send_outputs({c.id: c.value for c in changes})
        seen.clear()
        batch = {"rs485/m1/do0": True, "rs485/m1/do1": True, "rs485/m1/do5": True}
        batch.update({"rs485/m1/ao1": 100, "rs485/m1/ao4": 400})
        image.write_outputs(batch)
        await module.send_outputs(batch)
        assert seen == [(15, 0, 6), (16, 1, 4)]
        coils = await server.context.async_getValues(1, 1, 0, 8)
        assert list(coils) == [True, True, False, True, False, True, False, False]
        registers = await server.context.async_getValues(1, 3, 0, 6)
        assert list(registers) == [0, 100, 7, 8, 400, 0]
    finally:
        link.close()
        await server.shutdown()
        task.cancel()


def test_write_limits_and_write_span_come_from_the_model_and_a_value_is_never_split():
    import pytest
    from pydantic import ValidationError

    from fieldgate.plugins.modbus.config import ModbusModuleConfig
    from fieldgate.plugins.modbus.models import ModbusDeviceModel

    float_out = {"kind": "ao", "table": "holding_registers", "address": 0, "type": "float32"}
    with pytest.raises(ValidationError, match="more than max_write_registers 1"):
        ModbusModuleConfig(address=1, max_write_registers=1, channels=[float_out])
    model = ModbusDeviceModel(channels=[float_out], max_write_bits=4, write_span=False)
    module = ModbusModuleConfig.model_validate(
        {"address": 1, "model": "x"}, context={"models": {"x": model}}
    )
    assert (module.max_write_bits, module.max_write_registers, module.write_span) == (4, 123, False)
