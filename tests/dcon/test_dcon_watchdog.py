"""Host watchdog end to end: ~** while masters are healthy, safe values on loss, '!' -> WATCHDOG, ~AA1 recovery."""

import asyncio

import pytest

from fieldgate import ErrorKind, Quality
from fieldgate.polling import CommError

WD = {"enabled": True, "timeout_ms": 300}


async def test_host_ok_keeps_modules_alive_while_the_master_is_healthy(gateway, wait_for):
    async with gateway([{"address": 1, "model": "I-7055", "watchdog": WD}]) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await wait_for(
            lambda: sim.module(1).watchdog_enabled and sim.module(1).watchdog_tenths == 3
        )  # ~AA3EVV = ~01303
        gw.write("rs485/m1/do0", True)
        await wait_for(
            lambda: back.host_ok_sent >= 8, timeout=3
        )  # 0.1 s period: ~0.8 s, more than twice the timeout
        assert not sim.module(1).timed_out and sim.get_output("rs485/m1/do0") is True
        assert gw.status()["backs"]["rs485"]["host_ok"]["period_ms"] == 100


async def test_master_lost_stops_host_ok_and_modules_fall_to_safe_values(gateway, wait_for):
    modules = [
        {"address": 1, "model": "I-7043", "watchdog": WD, "safe_value": 0x00F0},
        {"address": 2, "model": "I-7024", "watchdog": WD, "safe_value": [7, 7, 7, 7]},
    ]
    async with gateway(modules) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        gw.write("rs485/m1/do0", True)
        gw.write("rs485/m2/ao0", 1000)
        await wait_for(
            lambda: (
                sim.get_output("rs485/m1/do0")
                and sim.get_output("rs485/m2/ao0") == 1000
                and back.host_ok_sent > 2
            )
        )
        gw.component("plc").lose_master("heartbeat timeout")
        sent = back.host_ok_sent
        await wait_for(lambda: sim.module(1).timed_out and sim.module(2).timed_out, timeout=2)
        assert back.host_ok_sent == sent  # not one ~** after the loss
        assert sim.module(1).do_bits == 0x00F0 and sim.module(2).ao_raw == [7, 7, 7, 7]
        # the back notices (it reads ~AA0 while host OK is suspended): outputs say WATCHDOG, status too
        await wait_for(
            lambda: (
                gw.image["rs485/m1/do0"].quality is Quality.WATCHDOG
                and gw.image["rs485/m2/ao3"].quality is Quality.WATCHDOG
            )
        )
        assert back.watchdog_status(1) and back.watchdog_status(2)
        entry = next(m for m in gw.status()["backs"]["rs485"]["dcon_modules"] if m["address"] == 1)
        assert entry["watchdog"]["timed_out"] is True and entry["watchdog"]["events"] == 1


async def test_write_answered_with_bang_sets_watchdog_quality_and_clear_recovers(gateway, wait_for):
    async with gateway(
        [{"address": 1, "model": "I-7060", "watchdog": WD}, {"address": 2, "model": "I-7052"}]
    ) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await wait_for(lambda: sim.module(1).watchdog_enabled)
        sim.module(1).tick(
            sim.module(1).last_host_ok + 10
        )  # the module times out (as if ~** had been lost on the wire)
        gw.write("rs485/m1/do2", True)
        await wait_for(lambda: gw.image["rs485/m1/do2"].quality is Quality.WATCHDOG)
        health = gw.health.get("rs485", 1)
        assert health.errors[ErrorKind.WATCHDOG] == 1 and "host-watchdog" in health.last_error
        assert sim.get_output("rs485/m1/do2") is False and sim.module(1).ignored_writes == 1
        gw.write("rs485/m1/do3", True)  # ignored by the module, so not even sent: no second '!'
        await wait_for(lambda: back.scheduler.pending_writes == 0)
        assert (
            sim.module(1).ignored_writes == 1 and health.online
        )  # reads still work: the module stays online
        assert gw.image["rs485/m2/di0"].quality is Quality.GOOD  # other modules are not affected
        # explicit recovery (the I-7231D's 0x2003 write): ~AA1, then the image's outputs are written again
        assert await back.clear_watchdog(1) is True
        await wait_for(lambda: sim.get_output("rs485/m1/do2") and sim.get_output("rs485/m1/do3"))
        await wait_for(lambda: gw.image["rs485/m1/do2"].quality is Quality.GOOD)
        assert not back.watchdog_status(1) and not sim.module(1).timed_out


async def test_i7012_family_reports_the_timeout_through_its_status(gateway, wait_for):
    async with gateway([{"address": 4, "model": "I-7012", "watchdog": WD}]) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await wait_for(lambda: sim.module(4).watchdog_enabled)
        sim.module(4).tick(sim.module(4).last_host_ok + 10)
        gw.write("rs485/m4/do1", True)  # @AADO answers !AA even when ignored: ~AA0 tells
        await wait_for(
            lambda: back.watchdog_status(4) and gw.image["rs485/m4/do1"].quality is Quality.WATCHDOG
        )
        back.request_clear_watchdog(4)  # fire and forget, as an SDO handler would
        await wait_for(
            lambda: sim.get_output("rs485/m4/do1") is True and not back.watchdog_status(4)
        )


async def test_clear_watchdog_on_a_silent_module_fails_cleanly(gateway, wait_for):
    async with gateway([{"address": 1, "model": "I-7060", "watchdog": WD}]) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await wait_for(lambda: sim.module(1).watchdog_enabled)
        sim.inject("silence", 1)
        assert await back.clear_watchdog(1) is False


async def test_watchdog_enabled_at_run_time(gateway, wait_for):
    """0x2001/0x2002 path: set_watchdog() sends ~AA3EVV and starts ~** at a third of the timeout."""
    async with gateway([{"address": 3, "model": "I-7066"}]) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await wait_for(lambda: gw.health.get("rs485", 3).requests > 2)
        assert back.host_ok_sent == 0 and not sim.module(3).watchdog_enabled
        await back.set_watchdog(3, True, 600)
        assert sim.module(3).watchdog_enabled and sim.module(3).watchdog_tenths == 6
        await wait_for(lambda: back.host_ok_sent >= 3)
        assert back.host_ok_period() == 0.2
        await back.set_watchdog(3, False)
        assert not sim.module(3).watchdog_enabled


async def test_master_back_resumes_host_ok(gateway, wait_for):
    async with gateway([{"address": 1, "model": "I-7065", "watchdog": {"timeout_ms": 2000}}]) as gw:
        back = gw.component("rs485")
        await wait_for(lambda: back.host_ok_sent >= 1)
        gw.component("plc").lose_master()
        stopped_at = back.host_ok_sent
        gw.masters.ok("plc")
        await wait_for(lambda: back.host_ok_sent > stopped_at)


def test_the_simulated_module_keeps_its_watchdog_running_while_host_ok_is_paused():
    # as a module does: ~AA1 resets the flag only; the watchdog runs from the last ~**
    from fieldgate.plugins.dcon.profiles import find_profile
    from fieldgate.plugins.dcon.simulated import SimBus, SimModule

    bus = SimBus(checksum=False)
    bus.add(SimModule(find_profile("I-7060"), 1))
    assert bus.command(b"~013101\r", 0.0) == (b"!01\r", 0.0)  # enabled, 0.1 s
    assert bus.command(b"~010\r", 0.5) == (b"!0184\r", 0.0)  # timed out (bit 2)
    assert bus.command(b"~011\r", 0.6) == (b"!01\r", 0.0)
    assert bus.command(b"~010\r", 0.6) == (b"!0184\r", 0.0)  # at once again: no ~** since
    assert bus.command(b"~**\r", 0.7) is None
    assert bus.command(b"~011\r", 0.7) == (b"!01\r", 0.0)
    assert bus.command(b"~010\r", 0.75) == (b"!0180\r", 0.0)  # cleared, and it holds


async def test_a_clear_queued_as_the_master_comes_back_resumes_host_ok_first(gateway, wait_for):
    # the I-7231D case: the master was lost (~** paused), the module timed out; the master
    # comes back and 0x2003 is written in the same moment: ~** must go out before ~AA1
    async with gateway([{"address": 1, "model": "I-7060", "watchdog": WD}]) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        gw.write("rs485/m1/do1", True)
        await wait_for(lambda: sim.module(1).watchdog_enabled and sim.get_output("rs485/m1/do1"))
        gw.context.masters.lost("plc", "heartbeat timeout")
        await wait_for(lambda: back.watchdog_status(1), timeout=3)
        assert sim.module(1).do_bits == 0  # the safe value
        gw.context.masters.ok("plc")
        cleared = back.request_clear_watchdog(1)  # same loop turn as the master's return
        await asyncio.wait_for(cleared, 3)
        status = next(m for m in back.status()["dcon_modules"] if m["address"] == 1)
        assert status["watchdog"]["last_clear"] == "cleared"
        await wait_for(lambda: sim.get_output("rs485/m1/do1") is True)  # outputs written again
        sent = back.host_ok_sent
        await wait_for(lambda: back.host_ok_sent >= sent + 6, timeout=3)  # two timeouts later
        assert not back.watchdog_status(1) and not sim.module(1).timed_out


async def test_a_clear_while_host_ok_is_off_goes_out_without_it_and_the_status_says_so(
    gateway, wait_for
):
    async with gateway([{"address": 1, "model": "I-7060", "watchdog": WD}]) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await wait_for(lambda: sim.module(1).watchdog_enabled)
        back.set_host_ok(False)  # the master switched host OK off (DeviceNet class attribute 4)
        await wait_for(lambda: back.watchdog_status(1), timeout=3)
        sent = back.host_ok_sent
        with pytest.raises(CommError):
            await asyncio.wait_for(back.request_clear_watchdog(1), 3)
        assert back.host_ok_sent == sent  # no ~** while it is off
        status = next(m for m in back.status()["dcon_modules"] if m["address"] == 1)
        assert "switched off by the master" in status["watchdog"]["last_clear"]
        assert back.watchdog_status(1)  # the module timed out again at once: 0x2003 says 1


async def test_safe_value_current_keeps_the_outputs_at_a_host_watchdog_timeout(gateway, wait_for):
    """``safe_value: current`` (the I-7241D's rule, seed-003 §7.2.11, audit 003 #27): at the
    timeout the outputs stay what they are, instead of the value stored in the module. The back
    latches them (~AA5S, ~AA5 per AO) when the host OK stops and after each write made while it
    is stopped; a module with its own safe_value keeps it."""
    slow = {"enabled": True, "timeout_ms": 900}
    modules = [
        {"address": 1, "model": "I-7043", "watchdog": slow},
        {"address": 2, "model": "I-7024", "watchdog": slow},
        {"address": 3, "model": "I-7043", "watchdog": slow, "safe_value": 0x000F},
    ]
    async with gateway(modules, safe_value="current") as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        gw.write("rs485/m1/do0", True)
        gw.write("rs485/m1/do5", True)
        gw.write("rs485/m2/ao0", 1000)
        gw.write("rs485/m3/do7", True)
        await wait_for(
            lambda: (
                sim.module(1).do_bits == 0x21
                and sim.module(2).ao_raw[0] == 1000
                and sim.module(3).do_bits == 0x80
                and sim.module(3).safe_do == 0x000F  # stored when it came online
                and back.host_ok_sent > 2
            )
        )
        assert sim.module(1).safe_do == 0  # nothing latched while the master is healthy
        gw.component("plc").lose_master("heartbeat timeout")
        await wait_for(lambda: sim.module(1).safe_do == 0x21 and sim.module(2).safe_ao[0] == 1000)
        gw.write("rs485/m1/do2", True)  # a write while the host OK is off: latched as well
        await wait_for(lambda: sim.module(1).safe_do == 0x25)
        await wait_for(lambda: all(sim.module(a).timed_out for a in (1, 2, 3)), timeout=3)
        assert sim.module(1).do_bits == 0x25 and sim.module(2).ao_raw[0] == 1000
        assert sim.module(3).do_bits == 0x000F  # its own safe value
        latched = {
            m["address"]: m["safe_values_latched"]
            for m in gw.status()["backs"]["rs485"]["dcon_modules"]
        }
        assert latched[1] >= 2 and latched[2] >= 1 and latched[3] == 0


async def test_by_default_the_modules_stored_safe_value_applies(gateway, wait_for):
    async with gateway([{"address": 1, "model": "I-7043", "watchdog": WD}]) as gw:
        sim = gw.bench.simulator("rs485")
        gw.write("rs485/m1/do0", True)
        await wait_for(lambda: sim.module(1).do_bits == 0x01)
        gw.component("plc").lose_master("heartbeat timeout")
        await wait_for(lambda: sim.module(1).timed_out, timeout=2)
        assert sim.module(1).do_bits == 0 and sim.module(1).safe_do == 0
