"""Fault injection over the pty: every bad reply is counted by kind, never an exception; offline and recovery."""

import pytest

from fieldgate import ErrorKind, Quality


@pytest.mark.parametrize(
    "fault, kind",
    [
        ("silence", ErrorKind.TIMEOUT),
        ("bad-checksum", ErrorKind.CRC),
        ("garbage", ErrorKind.GARBAGE),
        ("truncate", ErrorKind.GARBAGE),
        ("wrong-address", ErrorKind.WRONG_ADDRESS),
    ],
)
async def test_each_fault_is_counted_with_its_kind_and_inputs_go_stale(
    gateway, wait_for, fault, kind
):
    # the I-7012 answers @AADI with its address (!AASOOII), so a wrong address can be told
    async with gateway(
        [{"address": 1, "model": "I-7012"}, {"address": 2, "model": "I-7017"}], checksum=True
    ) as gw:
        sim = gw.bench.simulator("rs485")
        sim.set_input("rs485/m1/di0", True)
        await wait_for(lambda: gw.read("rs485/m1/di0") is True)
        sim.inject(fault, 1, count=2)
        health = gw.health.get("rs485", 1)
        await wait_for(lambda: health.errors[kind] >= 2)
        assert gw.image["rs485/m1/di0"].quality in (
            Quality.STALE,
            Quality.GOOD,
        )  # stale until the next good read
        await wait_for(
            lambda: (
                gw.image["rs485/m1/di0"].quality is Quality.GOOD
                and health.consecutive_failures == 0
            )
        )
        assert health.online and health.error_counter == 2
        if kind is not ErrorKind.TIMEOUT:  # (a loaded test machine may time the neighbour out once)
            assert kind not in gw.health.get("rs485", 2).errors  # the neighbour is untouched


async def test_late_reply_is_not_taken_for_the_next_command(gateway, wait_for):
    async with gateway(
        [{"address": 1, "model": "I-7052"}, {"address": 2, "model": "I-7017"}], timeout_ms=80
    ) as gw:
        sim = gw.bench.simulator("rs485")
        sim.set_input("rs485/m1/di0", True)
        sim.set_input("rs485/m2/ai0", 0x1111)
        sim.inject("delay", 1, delay=0.12, count=3)  # answers after the timeout
        health1, health2 = gw.health.get("rs485", 1), gw.health.get("rs485", 2)
        await wait_for(lambda: health1.errors[ErrorKind.TIMEOUT] >= 3)
        await wait_for(
            lambda: gw.read("rs485/m1/di0") is True and gw.read("rs485/m2/ai0") == 0x1111
        )
        assert (
            ErrorKind.WRONG_ADDRESS not in health2.errors
            and ErrorKind.GARBAGE not in health2.errors
        )


async def test_module_goes_offline_after_four_failures_and_recovers(gateway, wait_for):
    async with gateway([{"address": 7, "model": "I-7055"}], fail_threshold=3) as gw:
        sim = gw.bench.simulator("rs485")
        gw.write("rs485/m7/do1", True)
        await wait_for(lambda: sim.get_output("rs485/m7/do1") is True)
        fault = sim.inject("silence", 7)
        health = gw.health.get("rs485", 7)
        await wait_for(lambda: not health.online)
        assert health.consecutive_failures == 4 and health.errors[ErrorKind.TIMEOUT] == 4
        assert (
            gw.image["rs485/m7/di0"].quality is Quality.COMM_FAULT
            and gw.image["rs485/m7/do1"].quality is Quality.COMM_FAULT
        )
        gw.write("rs485/m7/do2", True)  # written while offline: kept for later
        sim.module(7).power_cycle(
            0
        )  # the module was replaced / powered up again with its outputs off
        sim.bus.faults.remove(fault)
        await wait_for(lambda: health.online and gw.image["rs485/m7/di0"].quality is Quality.GOOD)
        await wait_for(
            lambda: (
                sim.get_output("rs485/m7/do1") is True and sim.get_output("rs485/m7/do2") is True
            )
        )
        assert gw.image["rs485/m7/do1"].quality is Quality.GOOD


async def test_absent_module_is_offline_and_probed_slowly(gateway, wait_for):
    async with gateway([{"address": 1, "model": "I-7052"}]) as gw:
        sim = gw.bench.simulator("rs485")
        sim.bus.modules.pop(1)  # nobody at that address
        health = gw.health.get("rs485", 1)
        await wait_for(lambda: not health.online)
        before = health.requests
        await wait_for(lambda: health.requests > before)  # probed again after offline_probe_ms
        assert gw.image["rs485/m1/di0"].quality is Quality.COMM_FAULT


async def test_garbage_ai_data_is_counted_not_raised(gateway, wait_for):
    async with gateway([{"address": 2, "model": "I-7017", "data_format": "engineering"}]) as gw:
        sim = gw.bench.simulator("rs485")
        sim.module(2).data_format = sim.module(
            2
        ).data_format.HEX  # the module answers in hex, $AA2 says so, reads keep working
        sim.set_input("rs485/m2/ai1", 0x2222)
        await wait_for(lambda: gw.read("rs485/m2/ai1") == 0x2222)
        back = gw.component("rs485")
        back.modules[2].data_format = back.modules[
            2
        ].data_format.ENGINEERING  # out of step: hex text parsed as numbers
        await wait_for(lambda: gw.health.get("rs485", 2).errors[ErrorKind.GARBAGE] >= 1)
        assert back.status()["dcon_modules"][0][
            "warnings"
        ]  # topology says engineering, module says hex


async def test_analog_output_module_is_polled_and_goes_offline_when_silent(gateway, wait_for):
    async with gateway([{"address": 2, "model": "I-7024"}]) as gw:
        sim = gw.bench.simulator("rs485")
        health = gw.health.get("rs485", 2)
        await wait_for(lambda: health.requests > 5)  # ~AA0 keeps an output-only module polled
        sim.inject("silence", 2)
        await wait_for(lambda: not health.online)
        assert gw.image["rs485/m2/ao0"].quality is Quality.COMM_FAULT
        sim.clear_faults()
        await wait_for(lambda: health.online and gw.image["rs485/m2/ao0"].quality is Quality.GOOD)


async def test_module_reset_between_polls_gets_its_outputs_back(gateway, wait_for):
    async with gateway(
        [{"address": 1, "model": "I-7060"}, {"address": 2, "model": "I-7022"}]
    ) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        gw.write("rs485/m1/do2", True)
        gw.write("rs485/m2/ao1", 0x800)
        # written, and each module's first contact done: a power glitch before it would be
        # the module's power-up, which on_online meets (outputs written, no reset counted)
        await wait_for(
            lambda: (
                sim.get_output("rs485/m1/do2")
                and sim.get_output("rs485/m2/ao1") == 0x800
                and back.module(1).polls > 0
                and back.module(2).polls > 0
            ),
            timeout=10,
        )
        for address in (1, 2):
            sim.module(address).power_cycle(
                0
            )  # a power glitch: outputs at power-on values (0), never offline
        assert not sim.get_output("rs485/m1/do2") and sim.get_output("rs485/m2/ao1") == 0
        await wait_for(
            lambda: sim.get_output("rs485/m1/do2") and sim.get_output("rs485/m2/ao1") == 0x800
        )
        assert back.module(1).resets == 1 and back.module(2).resets == 1
        assert (
            sim.get_output("rs485/m1/do0") is False and sim.get_output("rs485/m2/ao0") == 0
        )  # never written: left alone
        assert all(h.online for h in gw.health.modules())
