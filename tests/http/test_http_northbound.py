"""The northbound server fronts (opcua, modbus-tcp) in /api/v1/status, /metrics and the live
page: their endpoint, their clients and their counters, through the existing status hooks
(each front's status() and metrics()), beside the Sparkplug front."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from httpkit import EXAMPLES, Running, start
from netkit import free_port
from prometheus_client.parser import text_string_to_metric_families
from pymodbus.client import AsyncModbusTcpClient
from test_http_browser import driver, wait_js  # noqa: F401  # the headless Chromium fixture

from fieldgate import Gateway


def plant(tmp_path: Any) -> tuple[Gateway, int, int]:
    ua, mb = free_port(), free_port()
    overrides = {
        "gateway.state_dir": str(tmp_path / "state"),
        "gateway.http.listen": "127.0.0.1:0",
        "fronts.can.channel": f"http-northbound-{ua}",
        "fronts.opcua.listen": f"127.0.0.1:{ua}",
        "fronts.modbus.listen": f"127.0.0.1:{mb}",
        "fronts.plant.brokers.0.port": free_port(),
    }
    return (
        Gateway.load(EXAMPLES / "plant-northbound.yaml", overrides=overrides, simulate=True),
        ua,
        mb,
    )


@pytest.fixture
async def northbound(tmp_path):
    from asyncua import Client  # a client to be listed (the OPC UA tests use node-opcua)

    gw, ua_port, mb_port = plant(tmp_path)
    running = await start(gw)
    ua = Client(f"opc.tcp://127.0.0.1:{ua_port}/")
    await ua.connect()
    mb = AsyncModbusTcpClient("127.0.0.1", port=mb_port)
    await mb.connect()
    assert not (await mb.read_coils(0, count=8, device_id=1)).isError()
    try:
        yield running, ua_port, mb_port
    finally:
        mb.close()
        await ua.disconnect()
        await gw.stop()


async def test_status_and_metrics_show_each_server_fronts_clients_and_counters(northbound):
    running, ua_port, mb_port = northbound

    # each server front runs in a child process that reports its status once a second, and
    # the status server (in a child of its own) gets the gateway's once a second
    async def reported() -> dict:
        status = (await running.get("/api/v1/status")).json()
        fronts = status["fronts"]
        return (
            status
            if len(fronts["opcua"].get("clients", [])) == 1
            and fronts["modbus"].get("counters", {}).get("reads") == 1
            else {}
        )

    status: dict = {}
    async with asyncio.timeout(15):
        while not (status := await reported()):
            await asyncio.sleep(0.2)
    ua = status["fronts"]["opcua"]
    assert ua["endpoint"] == f"opc.tcp://127.0.0.1:{ua_port}/" and ua["state"] == "listening"
    assert [c["peer"].split(":")[0] for c in ua["clients"]] == ["127.0.0.1"]
    assert ua["counters"]["value_updates"] > 0
    mb = status["fronts"]["modbus"]
    assert mb["endpoint"] == f"modbus://127.0.0.1:{mb_port}" and len(mb["clients"]) == 1
    assert mb["counters"]["reads"] == 1
    assert "journaled_samples" in status["fronts"]["plant"]  # the Sparkplug front beside them
    text = (await running.get("/metrics")).text
    found = {
        (s.name, s.labels.get("front")): s.value
        for f in text_string_to_metric_families(text)
        for s in f.samples
        if s.name.startswith(("fieldgate_opcua", "fieldgate_modbus_tcp"))
    }
    assert found[("fieldgate_opcua_clients", "opcua")] == 1
    assert found[("fieldgate_modbus_tcp_clients", "modbus")] == 1
    assert found[("fieldgate_modbus_tcp_reads_total", "modbus")] == 1
    assert found[("fieldgate_opcua_value_updates_total", "opcua")] > 0
    point = (await running.get("/api/v1/points/rs485/m6/do0")).json()
    served = {(s["component"], s["at"]) for s in point["served_by"]}
    assert ("modbus", "coil 8") in served and (
        "opcua",
        "ns=urn:fieldgate:line4;s=rs485/m6/do0",
    ) in served


@pytest.mark.browser
async def test_the_live_page_lists_the_clients(northbound, driver):  # noqa: F811
    running: Running = northbound[0]
    await asyncio.to_thread(driver.get, f"http://127.0.0.1:{running.port}/")
    await asyncio.to_thread(
        wait_js,
        driver,
        "return [...document.querySelectorAll('[data-front=\"modbus\"] dd')].some(d => d.textContent.startsWith('1: 127.0.0.1:'))",
        10,
    )
    facts = await asyncio.to_thread(
        driver.execute_script,
        "return [...document.querySelectorAll('[data-front=\"opcua\"] dt')].map(d => d.textContent)",
    )
    assert (
        facts[:3] == ["state", "endpoint", "clients"]
        and "counters" in facts
        and "master" not in facts
    )
    # the processes: the fieldbus process and each north-facing front's child
    await asyncio.to_thread(
        wait_js,
        driver,
        "return document.querySelectorAll('#processes tr[data-process]').length >= 4",
        10,
    )
    rows = await asyncio.to_thread(
        driver.execute_script,
        "return [...document.querySelectorAll('#processes tr[data-process]')].map(r => [r.dataset.process, r.dataset.state])",
    )
    assert rows[0] == ["fieldbus", "running"]
    assert {name for name, state in rows[1:] if state == "running"} >= {"opcua", "modbus", "plant"}
