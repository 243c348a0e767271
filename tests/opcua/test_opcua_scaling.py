"""A scaled channel (DCON analog input with its type code's range) seen by node-opcua: the raw
variable's EURange, the engineering twin with EURange and EngineeringUnits, a percent deadband
on the raw value, and a description naming the DCON command that reads it."""

from __future__ import annotations

import asyncio

from netkit import free_port

from fieldgate import Gateway, Quality, load_registry

from .uaclient import UaClient, require_node_opcua


async def test_engineering_units_range_and_percent_deadband(tmp_path):
    require_node_opcua()
    port = free_port()
    topology = {
        "gateway": {"name": "cell", "state_dir": str(tmp_path)},
        "fronts": [{"name": "ua", "type": "opcua", "listen": f"127.0.0.1:{port}"}],
        "backs": [
            {
                "name": "rs485",
                "type": "dcon",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 50,
                "modules": [{"address": 4, "model": "I-7012"}],
            }
        ],
    }
    gw = Gateway.load(topology, registry=load_registry(), simulate=True)
    await gw.start()
    ua = await UaClient.start()
    try:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 5
        while gw.image["rs485/m4/ai0"].quality is not Quality.GOOD:
            assert loop.time() < deadline
            await asyncio.sleep(0.02)
        scaling = gw.image["rs485/m4/ai0"].spec.scaling
        assert scaling is not None
        await ua.ok("connect", url=f"opc.tcp://127.0.0.1:{port}/")
        idx = (await ua.ok("namespace", uri="urn:fieldgate:cell"))["index"]
        node = f"ns={idx};s=rs485/m4/ai0"
        values = (
            await ua.ok(
                "read",
                nodeIds=[
                    f"{node}/EURange",
                    f"{node}/eng/EURange",
                    f"{node}/eng/EngineeringUnits",
                    f"{node}/eng",
                ],
            )
        )["values"]
        assert values[0]["value"] == {"low": scaling.raw_min, "high": scaling.raw_max}
        assert values[1]["value"] == {"low": scaling.eng_min, "high": scaling.eng_max}
        assert values[2]["value"]["displayName"] == scaling.unit
        raw = gw.read("rs485/m4/ai0")
        assert (
            abs(values[3]["value"] - scaling.to_engineering(raw)) < 1e-9
            and values[3]["dataType"] == "Double"
        )
        text = (await ua.ok("read", nodeIds=[node], attribute="Description"))["values"][0]["value"]
        assert "module 4 (I-7012)" in text and "#04 reply, value 1" in text
        await ua.ok("subscribe", publishingInterval=50)
        item = (await ua.ok("monitor", nodeIds=[node], deadband={"type": "Percent", "value": 10}))[
            "items"
        ][0]
        assert item["ok"], item
    finally:
        await ua.close()
        await gw.stop()
