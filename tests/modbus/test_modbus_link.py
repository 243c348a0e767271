"""The pymodbus adapter against the simulator over a pty pair: every function code, every fault."""

import asyncio
import time

import pytest
import serial

from fieldgate import ErrorKind
from fieldgate.plugin import PluginStartError
from fieldgate.plugins.modbus.client import ModbusExceptionError, ModbusLink
from fieldgate.plugins.modbus.codec import Request
from fieldgate.plugins.modbus.config import ModbusBackConfig
from fieldgate.plugins.modbus.simulator import Fault, ModbusSimulator
from fieldgate.polling import CommError
from fieldgate.serial_link import PtyPair

MODULES = [
    {"address": 1, "model": "M-7052D"},
    {"address": 3, "model": "M-7055D"},
    {"address": 4, "model": "M-7024"},
    {"address": 5, "model": "M-7017R"},
]


@pytest.fixture
async def wire():
    config = ModbusBackConfig(name="rs485", port="unused", baudrate=115200, modules=MODULES)
    pair = PtyPair()
    sim = ModbusSimulator(config, pair.b)
    await sim.start()
    link = ModbusLink(
        pair.a, baudrate=115200, timeout=0.15, inter_frame=0
    )  # generous: a loaded CI machine
    await link.open()
    yield link, sim, pair
    link.close()
    await sim.stop()
    pair.close()


async def test_fc1_fc2_fc3_fc4_reads(wire):
    link, sim, _ = wire
    sim.set_input("rs485/m1/di2", True)
    sim.set_input("rs485/m1/di7", 1)
    sim.set_input("rs485/m5/ai0", -1234)
    sim.set_input("rs485/m5/ai7", 32767)
    sim.modules[3].tables[sim.channels["rs485/m3/do1"][1].table][1] = True
    sim.modules[4].tables[sim.channels["rs485/m4/ao3"][1].table][3] = 0x1234
    assert await link.read_bits(1, 2, 32, 8) == [
        False,
        False,
        True,
        False,
        False,
        False,
        False,
        True,
    ]
    assert await link.read_bits(3, 1, 0, 8) == [False, True] + [False] * 6
    assert await link.read_registers(4, 3, 0, 4) == [0, 0, 0, 0x1234]
    regs = await link.read_registers(5, 4, 0, 8)
    assert regs[0] == (-1234) & 0xFFFF and regs[7] == 32767
    assert [r[:2] for r in [(q.unit, q.function) for q in sim.requests]] == [
        (1, 2),
        (3, 1),
        (4, 3),
        (5, 4),
    ]


async def test_fc5_fc15_fc6_fc16_writes(wire):
    link, sim, _ = wire
    await link.write(3, 5, 6, [True])
    assert sim.get_output("rs485/m3/do6") is True
    await link.write(3, 15, 0, [True, False, True])
    assert [sim.get_output(f"rs485/m3/do{i}") for i in range(3)] == [True, False, True]
    await link.write(4, 6, 2, [0xFFFF])
    assert sim.get_output("rs485/m4/ao2") == -1
    await link.write(4, 16, 0, [100, 200])
    assert (sim.get_output("rs485/m4/ao0"), sim.get_output("rs485/m4/ao1")) == (100, 200)
    assert [(q.function, q.address) for q in sim.requests] == [(5, 6), (15, 0), (6, 2), (16, 0)]
    assert dict(link.stats.requests) == {5: 1, 15: 1, 6: 1, 16: 1}


async def test_undeclared_addresses_answer_exception_2(wire):
    link, sim, _ = wire
    with pytest.raises(ModbusExceptionError) as info:
        await link.read_registers(5, 4, 6, 4)  # 6..9, the module has 0..7
    assert info.value.code == 2 and info.value.kind is ErrorKind.EXCEPTION
    assert link.stats.exception_codes[2] == 1
    assert await link.read_registers(5, 4, 0, 1) == [0]  # the line works on


@pytest.mark.parametrize(
    "fault, kind",
    [
        (Fault("no_answer", count=1), ErrorKind.TIMEOUT),
        (Fault("crc", count=1), ErrorKind.CRC),
        (Fault("garbage", count=1), ErrorKind.GARBAGE),
        (Fault("truncate", count=1), ErrorKind.GARBAGE),
        (Fault("wrong_address", count=1), ErrorKind.WRONG_ADDRESS),
        (Fault("exception", count=1, code=4), ErrorKind.EXCEPTION),
    ],
)
async def test_each_fault_is_classified_and_the_next_request_works(wire, fault, kind):
    link, sim, _ = wire
    sim.set_input("rs485/m1/di0", True)
    sim.inject(1, fault)
    with pytest.raises(CommError) as info:
        await link.read_bits(1, 2, 32, 8)
    assert info.value.kind is kind
    assert link.stats.errors[kind] == 1
    assert (await link.read_bits(1, 2, 32, 8))[0] is True
    assert not sim.modules[1].faults  # a counted fault is used up


async def test_a_delayed_reply_times_out_and_does_not_poison_the_next_request(wire):
    link, sim, _ = wire
    sim.set_input("rs485/m5/ai0", 11)
    sim.set_input("rs485/m1/di0", True)
    sim.inject(5, Fault("delay", count=1, delay=0.25))
    started = time.monotonic()
    with pytest.raises(CommError) as info:
        await link.read_registers(5, 4, 0, 1)
    assert info.value.kind is ErrorKind.TIMEOUT
    assert 0.14 < time.monotonic() - started < 1.0
    await asyncio.sleep(0.25)  # the late reply arrives while the line is idle
    assert not sim.server._timers  # the simulator forgets a delayed reply once sent
    assert await link.read_bits(1, 2, 32, 1) == [True]
    assert await link.read_registers(5, 4, 0, 1) == [11]


async def test_a_fault_limited_to_one_address_hits_only_requests_covering_it(wire):
    link, sim, _ = wire
    sim.inject(5, Fault("exception", code=2, address=3))
    assert await link.read_registers(5, 4, 0, 3) == [0, 0, 0]
    with pytest.raises(ModbusExceptionError):
        await link.read_registers(5, 4, 0, 8)
    with pytest.raises(ModbusExceptionError):
        await link.read_registers(5, 4, 3, 1)
    sim.clear_faults(5)
    assert len(await link.read_registers(5, 4, 0, 8)) == 8


async def test_unknown_unit_ids_get_no_answer(wire):
    link, sim, _ = wire
    with pytest.raises(CommError) as info:
        await link.read_bits(9, 2, 32, 8)
    assert info.value.kind is ErrorKind.TIMEOUT
    assert sim.responder.served == 0 and [q.unit for q in sim.requests] == [9]


async def test_line_noise_glued_to_a_reply_is_counted_as_garbage(wire):
    # pymodbus's framer reads the noise byte as the unit id, fails the CRC and drops the
    # chunk; the adapter sees the bytes and counts garbage, not a bare timeout
    link, sim, pair = wire
    sim.set_input("rs485/m1/di3", True)
    pair.fault = lambda data: b"\x00" + data
    with pytest.raises(CommError) as info:
        await link.read_bits(1, 2, 32, 8)
    assert info.value.kind is ErrorKind.GARBAGE
    pair.fault = None
    assert (await link.read_bits(1, 2, 32, 8))[3] is True


async def test_garbage_and_broken_requests_on_the_wire_never_stop_the_simulator(wire):
    link, sim, pair = wire
    noise = serial.Serial(pair.a, timeout=0)
    try:
        good = Request(1, 2, 32, 8).encode()
        noise.write(b"\xde\xad\xbe\xef")  # noise
        await asyncio.sleep(0.05)
        noise.write(good[:-1] + bytes([good[-1] ^ 1]))  # bad CRC
        await asyncio.sleep(0.05)
    finally:
        noise.close()
    sim.set_input("rs485/m1/di1", True)
    assert (await link.read_bits(1, 2, 32, 8))[1] is True
    assert sim.responder.dropped == 2 and sim.responder.served == 1


async def test_the_inter_frame_silence_is_kept_between_requests(wire):
    link, sim, _ = wire
    link.gap = 0.02
    started = time.monotonic()
    for _ in range(4):
        await link.read_bits(1, 2, 32, 8)
    assert time.monotonic() - started >= 3 * 0.02


async def test_a_missing_port_gives_a_one_line_cause():
    link = ModbusLink("/dev/does-not-exist-fieldgate", timeout=0.05)
    with pytest.raises(
        PluginStartError,
        match="cannot open serial port /dev/does-not-exist-fieldgate: no such device",
    ):
        await link.open()
