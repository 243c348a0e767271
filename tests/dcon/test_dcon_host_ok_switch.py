"""The back-wide host-OK switch a front may use (the I-7241D's Application class attribute 4)."""

WD = {"enabled": True, "timeout_ms": 300}


async def test_host_ok_switched_off_lets_modules_time_out_until_switched_on_and_cleared(
    gateway, wait_for
):
    async with gateway(
        [{"address": 1, "model": "I-7060", "watchdog": WD}, {"address": 2, "model": "I-7052"}]
    ) as gw:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        gw.write("rs485/m1/do0", True)
        await wait_for(lambda: back.host_ok_sent >= 2 and sim.get_output("rs485/m1/do0") is True)
        back.set_host_ok(False)
        stopped_at = back.host_ok_sent
        await wait_for(lambda: sim.module(1).timed_out)
        await wait_for(lambda: back.watchdog_status(1))  # seen through ~AA0 while ~** is off
        assert (
            back.host_ok_sent == stopped_at and sim.get_output("rs485/m1/do0") is False
        )  # safe value 0
        assert gw.status()["backs"]["rs485"]["host_ok"]["enabled"] is False and gw.masters.all_ok
        back.set_host_ok(True)
        await wait_for(lambda: back.host_ok_sent > stopped_at)
        assert sim.module(1).timed_out and back.watchdog_status(1)  # the timeout stays until ~AA1
        assert await back.clear_watchdog(1) is True
        await wait_for(lambda: sim.get_output("rs485/m1/do0") is True)
        assert not back.watchdog_status(1)
