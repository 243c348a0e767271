"""The opcua front browsed, read, subscribed and written by node-opcua (not the server's library).

A gateway with the modbus back on simulated modules (pseudo-terminals) and the opcua front on
a free loopback port; the client is ``tests/opcua/node/client.js`` in its own process.
"""

from __future__ import annotations

import asyncio
import datetime
import time
from typing import Any

import pytest
import pytest_asyncio
from netkit import free_port, wait_until

from fieldgate import Gateway, Quality, load_registry
from fieldgate.plugins.modbus.simulator import Fault
from fieldgate.testing import wait_for_report

from .uaclient import UaClient, require_node_opcua

REGISTRY = load_registry()
NS = "urn:fieldgate:cell"
pytestmark = pytest.mark.asyncio(loop_scope="module")  # one gateway for the module


def topology(port: int, state_dir: str, **opcua: Any) -> dict[str, Any]:
    return {
        "gateway": {"name": "cell", "state_dir": state_dir},
        "fronts": [
            {
                "name": "ua",
                "type": "opcua",
                "listen": f"127.0.0.1:{port}",
                "writable": ["rs485/m4/ao0"],
                "min_sampling_interval_ms": 0,  # every change a sample (the deadband test)
                **opcua,
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 50,
                "timeout_ms": 50,
                "fail_threshold": 2,
                "offline_probe_ms": 200,
                "modules": [
                    {"address": 1, "model": "M-7052D"},
                    {"address": 3, "model": "M-7055D", "counts": {"di": 0}},
                    {"address": 4, "model": "M-7024", "counts": {"ao": 2}},
                    {"address": 5, "model": "M-7017R", "counts": {"ai": 2}},
                ],
            }
        ],
    }


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def gateway(tmp_path_factory):
    require_node_opcua()
    port = free_port()
    state = tmp_path_factory.mktemp("state")
    gw = Gateway.load(topology(port, str(state)), registry=REGISTRY, simulate=True)
    gw.port = port  # type: ignore[attr-defined]
    await gw.start()
    await wait_until(lambda: gw.image["rs485/m5/ai1"].quality is Quality.GOOD)
    try:
        yield gw
    finally:
        await gw.stop()


@pytest_asyncio.fixture(loop_scope="module")
async def client(gateway):
    ua = await UaClient.start()
    await ua.ok("connect", url=f"opc.tcp://127.0.0.1:{gateway.port}/")
    try:
        yield ua
    finally:
        await ua.close()


async def ns(client: UaClient) -> int:
    index = (await client.ok("namespace", uri=NS))["index"]
    assert index > 0
    return int(index)


def iso(ts: str) -> datetime.datetime:
    return datetime.datetime.fromisoformat(ts.replace("Z", "+00:00"))


async def test_browse_finds_a_variable_per_channel_with_its_type_and_description(gateway, client):
    idx = await ns(client)
    nodes = (await client.ok("browse"))["nodes"]
    by_id = {n["nodeId"]: n for n in nodes}
    channel_ids = [c.id for c in gateway.image]
    for cid in channel_ids:
        node = by_id[f"ns={idx};s={cid}"]
        assert node["nodeClass"] == "Variable" and node["browseName"] == cid.rsplit("/", 1)[1]
        assert node["parent"] == f"ns={idx};s={cid.rsplit('/', 1)[0]}"  # the module's folder
    assert by_id[f"ns={idx};s=rs485/m5"]["nodeClass"] == "Object"
    assert f"ns={idx};s=rs485/m5/health/online" in by_id
    ids = [f"ns={idx};s={cid}" for cid in ("rs485/m1/di0", "rs485/m4/ao0", "rs485/m5/ai0")]
    types = (await client.ok("read", nodeIds=ids, attribute="DataType"))["values"]
    assert [t["value"] for t in types] == ["ns=0;i=1", "ns=0;i=4", "ns=0;i=4"]  # Boolean, Int16
    text = (await client.ok("read", nodeIds=ids[2:], attribute="Description"))["values"][0]["value"]
    assert "analog input 0 of module 5 (M-7017R) on back rs485" in text and "FC4" in text


async def test_read_gives_value_quality_and_acquisition_time(gateway, client):
    idx = await ns(client)
    sim = gateway.bench.simulator("rs485")
    seen: list[float] = []  # the acquisition time of the poll that brought the new value
    gateway.image.subscribe(lambda ch: seen.append(ch.channel.timestamp), ids=["rs485/m5/ai0"])
    sim.set_input("rs485/m5/ai0", 1234)
    await wait_until(lambda: gateway.read("rs485/m5/ai0") == 1234)
    await asyncio.sleep(0.05)  # the front's write task runs after the change
    value = (await client.ok("read", nodeIds=[f"ns={idx};s=rs485/m5/ai0"]))["values"][0]
    assert value["value"] == 1234 and value["status"]["name"] == "Good"
    # the source timestamp is that poll (later polls of the same value do not move it), not the
    # time of the read request; the wall clock offset is the front's, taken at its start
    offset = time.time() - time.monotonic()  # the front's, taken the same way in its child
    assert abs(iso(value["sourceTimestamp"]).timestamp() - (seen[0] + offset)) < 0.002
    assert iso(value["serverTimestamp"]) >= iso(value["sourceTimestamp"])


async def test_subscription_sees_changes_then_stale_then_comm_fault(gateway, client):
    idx = await ns(client)
    inputs = [c.id for c in gateway.image if not c.kind.is_output]
    sub = await client.ok("subscribe", publishingInterval=100)
    assert sub["publishingInterval"] == 100
    items = (await client.ok("monitor", nodeIds=[f"ns={idx};s={cid}" for cid in inputs]))["items"]
    assert all(item["ok"] for item in items) and len(items) == len(inputs)
    node = f"ns={idx};s=rs485/m5/ai1"
    await client.wait_for(lambda c: c["nodeId"] == node and c["status"]["name"] == "Good")
    gateway.bench.simulator("rs485").set_input("rs485/m5/ai1", -300)
    await client.wait_for(lambda c: c["nodeId"] == node and c["value"] == -300)
    gateway.bench.simulator("rs485").inject(5, Fault("no_answer"))
    stale = await client.wait_for(lambda c: c["nodeId"] == node and c["status"]["name"] != "Good")
    assert stale["status"]["name"] == "UncertainLastUsableValue" and stale["value"] == -300
    bad = await client.wait_for(
        lambda c: c["nodeId"] == node and c["status"]["name"] == "BadNoCommunication"
    )
    assert iso(bad["sourceTimestamp"]) > iso(stale["sourceTimestamp"])  # stamped when it happened
    assert gateway.image["rs485/m5/ai1"].quality is Quality.COMM_FAULT
    online = (await client.ok("read", nodeIds=[f"ns={idx};s=rs485/m5/health/online"]))["values"][0]
    assert online["value"] is False
    gateway.bench.simulator("rs485").clear_faults()
    await client.wait_for(
        lambda c: (
            c["nodeId"] == node
            and c["status"]["name"] == "Good"
            and c["t"] / 1000 > iso(bad["sourceTimestamp"]).timestamp()
        )
    )
    # the other modules' points never left Good
    other = f"ns={idx};s=rs485/m1/di0"
    assert {c["status"]["name"] for c in client.changes if c["nodeId"] == other} == {"Good"}


async def test_writes_reach_writable_outputs_only(gateway, client):
    idx = await ns(client)
    sim = gateway.bench.simulator("rs485")
    done = await client.ok(
        "write", nodeId=f"ns={idx};s=rs485/m4/ao0", dataType="Int16", value=-1234
    )
    assert done["status"]["name"] == "Good"
    assert (
        gateway.read("rs485/m4/ao0") == -1234 and gateway.image["rs485/m4/ao0"].written_by == "ua"
    )
    await wait_until(lambda: sim.get_output("rs485/m4/ao0") == -1234)
    for nodeid, dtype, value in (
        ("rs485/m4/ao1", "Int16", 5),  # an output not in writable
        ("rs485/m5/ai0", "Int16", 5),  # an input
        ("rs485/m3/do0", "Boolean", True),
    ):
        refused = await client.ok(
            "write", nodeId=f"ns={idx};s={nodeid}", dataType=dtype, value=value
        )
        assert refused["status"]["name"] in ("BadUserAccessDenied", "BadNotWritable"), nodeid
    assert gateway.read("rs485/m4/ao1") == 0 and gateway.read("rs485/m3/do0") is False
    wrong = await client.ok(
        "write", nodeId=f"ns={idx};s=rs485/m4/ao0", dataType="Double", value=1.5
    )
    assert wrong["status"]["name"] == "BadTypeMismatch" and gateway.read("rs485/m4/ao0") == -1234
    status = await wait_for_report(gateway, "ua", lambda s: s["counters"]["writes"] == 1)
    assert status["counters"]["writes"] == 1 and len(status["clients"]) == 1
    assert status["clients"][0]["user"] == "anonymous"


async def test_absolute_deadband_compares_with_the_last_reported_value(gateway, client):
    idx = await ns(client)
    node = f"ns={idx};s=rs485/m5/ai0"
    sim = gateway.bench.simulator("rs485")
    sim.set_input("rs485/m5/ai0", 0)
    await wait_until(lambda: gateway.read("rs485/m5/ai0") == 0)
    await client.ok("subscribe", publishingInterval=50)
    item = (
        await client.ok(
            "monitor",
            nodeIds=[node],
            samplingInterval=0,
            deadband={"type": "Absolute", "value": 100},
        )
    )["items"][0]
    assert item["ok"]
    await client.wait_for(lambda c: c["nodeId"] == node)
    first = len([c for c in client.changes if c["nodeId"] == node])
    for value in (60, 120, 180):  # a drift of 60 a step: asyncua alone never reports it
        sim.set_input("rs485/m5/ai0", value)
        await wait_until(lambda v=value: gateway.read("rs485/m5/ai0") == v)
    change = await client.wait_for(lambda c: c["nodeId"] == node and c["value"] != 0)
    assert change["value"] == 120  # 120 - 0 > 100; 60 was within the band
    await asyncio.sleep(0.3)
    values = [c["value"] for c in client.changes if c["nodeId"] == node][first:]
    assert values == [120]  # 180 - 120 is within the band again
    refused = (
        await client.ok("monitor", nodeIds=[node], deadband={"type": "Percent", "value": 5})
    )["items"][0]
    assert (
        not refused["ok"] and "FilterUnsupported" in refused["error"]
    )  # no EURange on a raw AI of Modbus


async def test_status_and_metrics_show_the_client(gateway, client):
    status = await wait_for_report(gateway, "ua", lambda s: len(s["clients"]) == 1)
    assert status["endpoint"] == f"opc.tcp://127.0.0.1:{gateway.port}/"
    assert status["clients"][0]["peer"].startswith("127.0.0.1:")
    rows = {row[0]: row for row in gateway.component("ua").metrics()}
    assert rows["opcua_clients"][3] == 1 and rows["opcua_value_updates_total"][3] > 0
