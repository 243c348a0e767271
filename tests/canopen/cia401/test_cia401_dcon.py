"""The I-7231D's DCON host-watchdog objects 0x2001-0x2003 over a simulated DCON back."""

from __future__ import annotations

import asyncio
import uuid

import pytest
from io_bench import demo_7232d

from fieldgate import Gateway, Quality, load_registry
from fieldgate.plugins.canopen.cia301.abort import SdoAbort

WD = {"enabled": True, "timeout_ms": 300}


async def wait_for(predicate, timeout=3.0):
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not predicate():
        assert loop.time() < deadline, "condition not reached in time"
        await asyncio.sleep(0.01)


def test_no_dcon_back_no_watchdog_objects():
    b = demo_7232d()
    assert 0x2000 in b.node.od and 0x2001 not in b.node.od and 0x2003 not in b.node.od


async def test_watchdog_objects_drive_the_dcon_back(tmp_path):
    registry = load_registry()
    if registry.lookup("back", "dcon") is None:
        pytest.skip("the dcon back plugin is not installed")
    topology = {
        "gateway": {"name": "i7231d", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "virtual",
                "channel": f"fg-dcon-{uuid.uuid4().hex[:8]}",
                "node_id": 1,
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "dcon",
                "port": "simulated",
                "timeout_ms": 60,
                "poll_ms": 10,
                "offline_probe_ms": 100,
                "modules": [
                    {"address": 1, "model": "I-7060", "watchdog": WD},
                    {"address": 2, "model": "I-7052"},
                ],
            }
        ],
    }
    gw = Gateway.load(topology, registry=registry, simulate=True)
    await gw.start()
    try:
        od = gw.component("can").node.od
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await wait_for(lambda: sim.module(1).watchdog_enabled)
        assert [od.get(0x2001, s) for s in range(3)] == [2, 1, 0]
        assert od.get(0x2002, 1) == 3 and od.get(0x2011, 1) == "I-7060"
        od.write(0x2002, 1, bytes([5]))
        await wait_for(lambda: sim.module(1).watchdog_tenths == 5)
        assert back.module(1).watchdog_timeout_ms == 500
        # the module times out: 0x2003 shows it; writing 0 sends ~AA1 and the module recovers
        sim.module(1).tick(sim.module(1).last_host_ok + 10)
        gw.write("rs485/m1/do1", True)
        await wait_for(lambda: gw.image["rs485/m1/do1"].quality is Quality.WATCHDOG)
        assert od.get(0x2003, 1) == 1 and od.get(0x2003, 2) == 0
        with pytest.raises(SdoAbort) as refused:
            od.write(0x2003, 1, bytes([1]))
        assert refused.value.code == 0x06090030
        od.write(0x2003, 1, bytes([0]))
        await wait_for(
            lambda: not sim.module(1).timed_out and sim.get_output("rs485/m1/do1") is True
        )
        assert od.get(0x2003, 1) == 0
        with pytest.raises(SdoAbort):
            od.write(0x2002, 1, bytes([0]))
    finally:
        await gw.stop()
