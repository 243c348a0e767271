"""The back's modules on core's line scheduler, over a pty against the simulator.

The scheduler runs on a fake clock (``line.cycle()`` advances one poll period), the
transactions are real.
"""

import logging

import pytest
from modbus_line import I7232D_MODULES, PERIOD, PROBE

from fieldgate import ErrorKind, Quality
from fieldgate.plugins.modbus.simulator import Fault
from fieldgate.polling import CommError


async def test_the_i7232d_line_polls_inputs_into_the_image(make_line):
    line = await make_line(I7232D_MODULES)
    line.sim.set_input("rs485/m1/di2", True)
    line.sim.set_input("rs485/m5/ai0", 0x3FF5)
    await line.run_due()
    assert (
        line.image.value("rs485/m1/di2") is True
        and line.image["rs485/m1/di2"].quality is Quality.GOOD
    )
    assert line.image.value("rs485/m5/ai0") == 0x3FF5
    # one request per module: DI block, DO read-back, AO read-back, AI
    assert sorted(line.requests()) == [(1, 2, 32, 8), (3, 1, 0, 8), (4, 3, 0, 1), (5, 4, 0, 1)]
    line.sim.set_input("rs485/m1/di2", False)
    await line.cycle()
    assert line.image.value("rs485/m1/di2") is False


async def test_adjacent_points_are_coalesced_into_one_request(make_line):
    line = await make_line(
        [
            {"address": 5, "model": "M-7017R"},
            {
                "address": 9,
                "channels": [
                    {
                        "kind": "ai",
                        "table": "input_registers",
                        "address": 0,
                        "count": 130,
                        "type": "uint16",
                    }
                ],
            },
        ]
    )
    line.sim.set_input("rs485/m9/ai129", 4242)
    await line.run_due()
    assert sorted(line.requests()) == [(5, 4, 0, 8), (9, 4, 0, 125), (9, 4, 125, 5)]
    assert line.image.value("rs485/m9/ai129") == 4242


async def test_a_refused_block_falls_back_to_single_points(make_line, caplog):
    line = await make_line([{"address": 5, "model": "M-7017R"}])
    for i in range(8):
        line.sim.set_input(f"rs485/m5/ai{i}", 100 + i)
    line.sim.inject(5, Fault("exception", code=2, address=3))  # register 3 is refused, persistently
    with caplog.at_level(logging.WARNING, logger="fieldgate.modbus"):
        await line.run_due()
    assert line.requests() == [(5, 4, 0, 8)] + [(5, 4, a, 1) for a in range(8)]
    assert line.image["rs485/m5/ai3"].quality is Quality.CONFIG_ERROR
    assert [line.image.value(f"rs485/m5/ai{i}") for i in (0, 2, 4, 7)] == [100, 102, 104, 107]
    assert all(line.image[f"rs485/m5/ai{i}"].quality is Quality.GOOD for i in (0, 1, 2, 4, 5, 6, 7))
    assert line.health[5].online and line.health[5].consecutive_failures == 0
    # from now on the good points are coalesced around the refused one
    line.sim.set_input("rs485/m5/ai6", 66)
    await line.cycle()
    assert line.requests() == [(5, 4, 0, 3), (5, 4, 4, 4)]
    assert line.image.value("rs485/m5/ai6") == 66
    warnings = [r.getMessage() for r in caplog.records]
    assert any("reading its points one by one" in w for w in warnings) and any(
        "rs485/m5/ai3" in w for w in warnings
    )
    # the refused point is retried at the slow period; once it answers the block is whole again
    line.sim.clear_faults(5)
    line.clock.t += PROBE
    await line.run_due()
    assert (
        line.image["rs485/m5/ai3"].quality is Quality.GOOD
        and line.image.value("rs485/m5/ai3") == 103
    )
    line.requests()
    await line.cycle()
    assert line.requests() == [(5, 4, 0, 8)]


async def test_outputs_are_written_on_change_with_sensible_function_codes(make_line):
    line = await make_line([{"address": 3, "model": "M-7055D"}, {"address": 4, "model": "M-7024"}])
    await line.run_due()
    line.requests()
    line.image.write_output("rs485/m3/do5", True)
    await line.run_due()
    assert line.sim.get_output("rs485/m3/do5") is True
    assert line.requests()[0] == (3, 5, 5, 1)  # one coil: FC5, ahead of any read
    for i in (0, 1, 2):
        line.image.write_output(f"rs485/m3/do{i}", True)
    line.image.write_output("rs485/m4/ao2", -300)
    await line.run_due()
    writes = [r for r in line.requests() if r[1] in (5, 6, 15, 16)]
    assert sorted(writes) == [(3, 15, 0, 3), (4, 6, 2, 1)]
    assert line.sim.get_output("rs485/m4/ao2") == -300
    line.image.write_output("rs485/m3/do5", True)  # no change: nothing written
    await line.cycle()
    assert not [r for r in line.requests() if r[1] in (5, 15)]


async def test_data_types_and_word_orders_end_to_end(make_line):
    line = await make_line(
        [
            {
                "address": 8,
                "channels": [
                    {
                        "kind": "ai",
                        "table": "holding_registers",
                        "address": 0,
                        "type": "float32",
                        "word_order": "little",
                    },
                    {"kind": "ai", "table": "holding_registers", "address": 2, "type": "int32"},
                    {
                        "kind": "ai",
                        "table": "input_registers",
                        "address": 0,
                        "type": "uint32",
                        "word_order": "little",
                    },
                    {"kind": "ai", "table": "input_registers", "address": 2, "type": "uint16"},
                    {
                        "kind": "di",
                        "table": "input_registers",
                        "address": 3,
                        "count": 4,
                        "first_bit": 14,
                    },
                    {"kind": "ao", "table": "holding_registers", "address": 10, "type": "float32"},
                    {
                        "kind": "ao",
                        "table": "holding_registers",
                        "address": 12,
                        "type": "int32",
                        "word_order": "little",
                    },
                    {
                        "kind": "do",
                        "table": "holding_registers",
                        "address": 20,
                        "count": 2,
                        "first_bit": 7,
                    },
                ],
            }
        ]
    )
    sim = line.sim
    sim.set_input("rs485/m8/ai0", -12.5)
    sim.set_input("rs485/m8/ai1", -70000)
    sim.set_input("rs485/m8/ai2", 3_000_000_000)
    sim.set_input("rs485/m8/ai3", 65535)
    sim.set_input("rs485/m8/di1", True)  # bit 15 of register 3
    sim.set_input("rs485/m8/di2", True)  # bit 0 of register 4
    await line.run_due()
    image = line.image
    assert [image.value(f"rs485/m8/ai{i}") for i in range(4)] == [
        -12.5,
        -70000,
        3_000_000_000,
        65535,
    ]
    assert [image.value(f"rs485/m8/di{i}") for i in range(4)] == [False, True, True, False]
    assert (
        sim.modules[8].tables[sim.channels["rs485/m8/ai0"][1].table][1] == 0xC148
    )  # high word of -12.5 second
    image.write_output("rs485/m8/ao0", 2.5)
    image.write_output("rs485/m8/ao1", -2)
    line.requests()
    await line.run_due()
    assert (sim.get_output("rs485/m8/ao0"), sim.get_output("rs485/m8/ao1")) == (2.5, -2)
    holding = sim.modules[8].tables[sim.channels["rs485/m8/ao1"][1].table]
    assert (holding[12], holding[13]) == (0xFFFE, 0xFFFF)  # low word first
    assert (8, 16, 10, 4) in line.requests()  # float then int32, adjacent: one FC16
    # a digital output inside a register: read, modify, write; other bits untouched
    holding[20] = 0x8001
    image.write_output("rs485/m8/do1", True)  # bit 8 of register 20
    await line.run_due()
    assert holding[20] == 0x8101
    assert [r for r in line.requests() if r[1] in (3, 6)][:2] == [(8, 3, 20, 1), (8, 6, 20, 1)]


async def test_failure_then_offline_then_slow_reprobe_then_recovery(make_line, caplog):
    line = await make_line(I7232D_MODULES)
    await line.run_due()
    line.sim.set_input("rs485/m5/ai0", 1234)
    line.sim.inject(5, Fault("no_answer"))
    health = line.health[5]
    with caplog.at_level(logging.WARNING, logger="fieldgate.polling"):
        for n in range(1, 5):
            await line.cycle()
            assert health.consecutive_failures == n
            expected = Quality.STALE if n <= 3 else Quality.COMM_FAULT
            assert line.image["rs485/m5/ai0"].quality is expected
    assert not health.online and health.errors[ErrorKind.TIMEOUT] == 4
    assert (
        sum("module 5" in r.getMessage() and "timeout" in r.getMessage() for r in caplog.records)
        == 1
    )  # once per burst
    # while offline, the dead module costs nothing until its slow re-probe is due
    line.requests()
    for _ in range(int(PROBE / PERIOD) - 2):
        await line.cycle()
    assert 5 not in {r[0] for r in line.requests()}
    assert line.health[1].online and line.image["rs485/m1/di0"].quality is Quality.GOOD
    line.clock.t += 2 * PERIOD
    await line.run_due()
    assert [r for r in line.requests() if r[0] == 5] == [(5, 4, 0, 1)]  # one probe
    assert not health.online
    line.sim.clear_faults()
    line.clock.t += PROBE
    await line.run_due()
    assert health.online and health.consecutive_failures == 0
    assert (
        line.image["rs485/m5/ai0"].quality is Quality.GOOD
        and line.image.value("rs485/m5/ai0") == 1234
    )


async def test_a_dead_output_only_module_is_noticed_through_read_back(make_line):
    line = await make_line([{"address": 4, "model": "M-7024"}])
    line.image.write_output("rs485/m4/ao0", 500)
    await line.run_due()
    assert line.sim.get_output("rs485/m4/ao0") == 500
    line.sim.inject(4, Fault("no_answer"))
    for _ in range(4):
        await line.cycle()
    assert not line.health[4].online
    assert line.image["rs485/m4/ao0"].quality is Quality.COMM_FAULT
    line.image.write_output("rs485/m4/ao0", 600)
    line.sim.clear_faults()
    line.clock.t += PROBE
    await line.run_due()
    assert (
        line.health[4].online and line.sim.get_output("rs485/m4/ao0") == 600
    )  # written on recovery


async def test_every_fault_kind_is_counted_in_the_module_health(make_line):
    line = await make_line([{"address": 1, "model": "M-7052D"}], fail_threshold=10)
    kinds = {
        "no_answer": ErrorKind.TIMEOUT,
        "crc": ErrorKind.CRC,
        "garbage": ErrorKind.GARBAGE,
        "truncate": ErrorKind.GARBAGE,
        "wrong_address": ErrorKind.WRONG_ADDRESS,
    }
    for fault in kinds:
        line.sim.inject(1, Fault(fault, count=1))
        await line.cycle()
    health = line.health[1]
    assert dict(health.errors) == {
        ErrorKind.TIMEOUT: 1,
        ErrorKind.CRC: 1,
        ErrorKind.GARBAGE: 2,
        ErrorKind.WRONG_ADDRESS: 1,
    }
    assert health.error_counter == 5 and health.online
    line.sim.set_input("rs485/m1/di0", True)
    await line.cycle()
    assert line.image.value("rs485/m1/di0") is True and health.consecutive_failures == 0
    assert line.scheduler.stats.errors[ErrorKind.CRC] == 1


async def test_retries_hide_a_single_bad_reply(make_line):
    line = await make_line([{"address": 1, "model": "M-7052D"}], retries=1)
    line.scheduler.retries = 1
    line.sim.set_input("rs485/m1/di4", True)
    line.sim.inject(1, Fault("crc", count=1))
    await line.run_due()
    assert (
        line.image.value("rs485/m1/di4") is True
        and line.image["rs485/m1/di4"].quality is Quality.GOOD
    )
    assert line.health[1].errors[ErrorKind.CRC] == 1


async def test_a_module_refusing_fc15_is_written_with_fc5(make_line):
    line = await make_line([{"address": 3, "model": "M-7055D"}])
    await line.run_due()
    line.sim.inject(3, Fault("exception", code=1, table=None, address=None, count=1))
    line.requests()
    for i in range(3):
        line.image.write_output(f"rs485/m3/do{i}", True)
    await line.run_due()
    writes = [r for r in line.requests() if r[1] in (5, 15)]
    assert writes == [(3, 15, 0, 3), (3, 5, 0, 1), (3, 5, 1, 1), (3, 5, 2, 1)]
    assert [line.sim.get_output(f"rs485/m3/do{i}") for i in range(3)] == [True, True, True]
    assert line.module(3).allow_multiple_writes is False


async def test_a_refused_write_is_counted_and_the_line_goes_on(make_line):
    line = await make_line([{"address": 4, "model": "M-7024"}])
    await line.run_due()
    line.sim.inject(4, Fault("exception", code=3, address=1))
    line.image.write_output("rs485/m4/ao1", 9999)
    await line.run_due()
    assert line.link.stats.exception_codes[3] >= 1
    assert line.health[4].online and line.scheduler.pending_writes == 0
    line.image.write_output("rs485/m4/ao2", 5)
    await line.run_due()
    assert line.sim.get_output("rs485/m4/ao2") == 5


async def test_group_poll_periods(make_line):
    line = await make_line(
        [
            {
                "address": 2,
                "channels": [
                    {"kind": "ai", "table": "input_registers", "address": 0, "count": 2},
                    {
                        "kind": "ai",
                        "table": "input_registers",
                        "address": 2,
                        "count": 2,
                        "poll_ms": 1000,
                    },
                ],
            }
        ]
    )
    await line.run_due()
    assert sorted(line.requests()) == [(2, 4, 0, 2), (2, 4, 2, 2)]
    for _ in range(3):
        await line.cycle()
    assert line.requests() == [(2, 4, 0, 2)] * 3  # the slow group waits for its second
    line.clock.t += 1.0
    await line.run_due()
    assert sorted(line.requests()) == [(2, 4, 0, 2), (2, 4, 2, 2)]


async def test_a_poll_with_no_group_due_records_no_request(make_line):
    line = await make_line(
        [
            {
                "address": 2,
                "channels": [
                    {"kind": "ai", "table": "input_registers", "address": 0, "poll_ms": 60000}
                ],
            }
        ]
    )
    await line.run_due()
    assert line.requests() == [(2, 4, 0, 1)]
    requests = line.health[2].requests
    for _ in range(3):
        await line.cycle()
    assert line.requests() == [] and line.health[2].requests == requests


async def test_a_probe_always_makes_a_transaction(make_line):
    # an offline module must prove it answers, even when none of its groups is due
    line = await make_line(
        [
            {
                "address": 2,
                "channels": [
                    {"kind": "ai", "table": "input_registers", "address": 0, "poll_ms": 60000}
                ],
            }
        ]
    )
    await line.run_due()
    module = line.module(2)
    line.requests()
    assert await module.read_inputs() == {} and line.requests() == []  # not due: no transaction
    await module.probe()
    assert line.requests() == [(2, 4, 0, 1)]
    line.sim.inject(2, Fault("no_answer", count=1))
    with pytest.raises(CommError):
        await module.probe()
    line.sim.inject(2, Fault("exception", count=1, code=2))
    await module.probe()  # an exception response is an answer


async def test_a_slow_group_of_a_dead_module_fails_at_once_on_every_poll(make_line):
    line = await make_line(
        [
            {
                "address": 2,
                "channels": [
                    {"kind": "ai", "table": "input_registers", "address": 0, "poll_ms": 60000}
                ],
            }
        ]
    )
    await line.run_due()
    line.sim.inject(2, Fault("no_answer"))
    line.clock.t += 60
    await line.run_due()
    assert line.health[2].consecutive_failures == 1
    for _ in range(3):  # a failed read stays due: the next polls retry it
        await line.cycle()
    assert not line.health[2].online
