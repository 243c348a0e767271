"""The modbus-tcp-client back on real loopback sockets, its devices simulated: connections shared
per host, the cap, pipelining only where configured, connect back-off, a dead device or host
that never holds up the others; its scan and ``fieldgate simulate``."""

from __future__ import annotations

import asyncio
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from netkit import free_port

from fieldgate import Quality, load_registry
from fieldgate.plugin import GatewayContext
from fieldgate.plugins.modbus import Fault, ModbusTcpClientBack, ModbusTcpSimulator
from fieldgate.testing import wait_for_channel, wait_until
from fieldgate.topology import load_topology

AI = {"kind": "ai", "table": "input_registers", "address": 0}


def topology(devices: list[dict], **back: Any) -> dict:
    return {
        "gateway": {"name": "t"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "net",
                "type": "modbus-tcp-client",
                "poll_ms": 50,
                "timeout_ms": 300,
                "offline_probe_ms": 500,
                "fail_threshold": 1,
                "modules": devices,
                **back,
            }
        ],
    }


def device(address: int, host: str, **more: Any) -> dict:
    return {"address": address, "host": host, "channels": [AI], **more}


@asynccontextmanager
async def running(
    topo: dict, *, before_start: Any = None
) -> AsyncIterator[tuple[ModbusTcpClientBack, ModbusTcpSimulator, GatewayContext]]:
    loaded = load_topology(topo, load_registry())
    config = loaded.back("net")
    sim = ModbusTcpSimulator(config)
    await sim.start()  # points the back's devices at its loopback listeners
    if before_start is not None:
        await before_start(sim)
    context = GatewayContext.build(loaded)
    back = ModbusTcpClientBack(config, context)
    await back.start()
    task = asyncio.ensure_future(back.run())
    try:
        yield back, sim, context
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await back.stop()
        await sim.stop()


def polls(sim: ModbusTcpSimulator, address: int, unit: int) -> int:
    return sum(1 for seen in sim.requests(address) if seen.unit == unit)


async def test_the_units_of_a_host_share_one_connection():
    topo = topology([device(a, "10.0.0.1") for a in (1, 2, 3)])
    async with running(topo) as (back, sim, context):
        for a in (1, 2, 3):
            sim.set_input(f"net/m{a}/ai0", 100 + a)
        for a in (1, 2, 3):
            await wait_for_channel(context.image, f"net/m{a}/ai0", 100 + a)
        host = sim.host_of(1)
        assert host.connections == 1
        assert {seen.unit for seen in host.log} == {1, 2, 3}
        assert max(seen.outstanding for seen in host.log) == 1  # pipeline 1: one at a time
        (status,) = back.status()["hosts"].values()
        assert [c["connects"] for c in status["connections"]] == [1]


async def test_the_connection_cap_and_pipelining_only_where_configured():
    topo = topology(
        [device(a, "10.0.0.1") for a in (1, 2, 3, 4)] + [device(a, "10.0.0.2") for a in (5, 6, 7)],
        hosts={"10.0.0.1": {"max_connections": 2}, "10.0.0.2": {"pipeline": 3}},
    )

    async def refuse_pipelining(sim: ModbusTcpSimulator) -> None:
        sim.host_of(1).pipelining = False  # this device drops a request sent before an answer
        sim.inject(5, Fault("delay", delay=0.15))  # a slow unit on the pipelining host

    async with running(topo, before_start=refuse_pipelining) as (back, sim, context):
        await wait_until(lambda: all(polls(sim, 1, u) >= 5 for u in (1, 2, 3, 4)), 10)
        await wait_until(lambda: all(polls(sim, 5, u) >= 5 for u in (6, 7)), 10)
        capped, pipelined = sim.host_of(1), sim.host_of(5)
        assert capped.connections == 2
        assert max(seen.outstanding for seen in capped.log) == 1
        assert all(h.error_counter == 0 for h in back.health.values() if h.address <= 4)
        assert pipelined.connections == 1
        assert max(seen.outstanding for seen in pipelined.log) >= 2  # in flight together


async def test_a_dead_host_and_a_dead_unit_never_hold_up_the_other_devices():
    topo = topology(
        [device(1, "10.0.0.1"), device(2, "10.0.0.1"), device(3, "10.0.0.2")],
        hosts={"10.0.0.1": {"pipeline": 2}},
    )

    async def break_them(sim: ModbusTcpSimulator) -> None:
        await sim.kill_host(3)  # a host that refuses connections
        sim.inject(2, Fault("no_answer"))  # a unit behind a gateway that never answers

    async with running(topo, before_start=break_them) as (back, sim, context):
        await wait_for_channel(context.image, "net/m3/ai0", quality=Quality.COMM_FAULT)
        await wait_for_channel(context.image, "net/m2/ai0", quality=Quality.COMM_FAULT)
        before = polls(sim, 1, 1)
        started = asyncio.get_running_loop().time()
        await asyncio.sleep(1.5)
        elapsed = asyncio.get_running_loop().time() - started
        done = polls(sim, 1, 1) - before
        # poll_ms 50 and a 300 ms timeout: a unit waiting for the dead ones would make < 5
        assert done >= 0.5 * elapsed / 0.05, f"{done} polls of the healthy unit in {elapsed:.1f} s"
        assert context.image["net/m1/ai0"].quality is Quality.GOOD


async def test_connect_back_off_then_recovery():
    topo = topology([device(1, "10.0.0.1")], offline_probe_ms=800)

    async def down(sim: ModbusTcpSimulator) -> None:
        await sim.kill_host(1)

    async with running(topo, before_start=down) as (back, sim, context):
        await wait_for_channel(context.image, "net/m1/ai0", quality=Quality.COMM_FAULT)
        await asyncio.sleep(2.5)
        (link,) = back.links[f"127.0.0.1:{sim.host_of(1).bind[1]}"]
        # 0, 0.1, 0.3, 0.7, 1.5, 2.3 s: doubling from 0.1 s to offline_probe_ms, not a tight loop
        assert 4 <= link.attempts <= 8, link.attempts
        sim.set_input("net/m1/ai0", 77)
        await sim.revive_host(1)
        await wait_for_channel(context.image, "net/m1/ai0", 77, Quality.GOOD, timeout=3)


async def test_a_host_that_drops_its_connection_is_offline_at_once_and_comes_back():
    topo = topology([device(1, "10.0.0.1"), device(2, "10.0.0.1")], fail_threshold=3)
    async with running(topo) as (back, sim, context):
        sim.set_input("net/m1/ai0", 5)
        await wait_for_channel(context.image, "net/m1/ai0", 5)
        await sim.kill_host(1)
        # the connection's loss takes every device of the host offline at once, not after
        # fail_threshold timeouts each
        for a in (1, 2):
            await wait_for_channel(
                context.image, f"net/m{a}/ai0", quality=Quality.COMM_FAULT, timeout=1
            )
        sim.set_input("net/m2/ai0", 6)
        await sim.revive_host(1)
        await wait_for_channel(context.image, "net/m2/ai0", 6, Quality.GOOD, timeout=3)
        assert back.status()["hosts"]


async def test_scan_finds_the_units_of_a_host_and_prints_a_topology():
    topo = topology([device(1, "10.0.0.1"), device(5, "10.0.0.1")])
    loaded = load_topology(topo, load_registry())
    sim = ModbusTcpSimulator(loaded.back("net"))
    await sim.start()
    try:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "fieldgate", "scan", "modbus-tcp-client",
            "--port", sim.host_of(1).endpoint, "--addresses", "1-8", "--timeout-ms", "200",
            "--name", "meters",
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        out, err = await asyncio.wait_for(proc.communicate(), 60)
    finally:
        await sim.stop()
    assert proc.returncode == 0, err.decode()
    text = out.decode()
    assert "type: modbus-tcp-client" in text and f"host: {sim.host_of(1).endpoint}" in text
    assert "- address: 1  # answered FC3 register 0" in text
    assert "- address: 5  # answered" in text and "address: 2" not in text


async def test_simulate_serves_modules_on_a_loopback_port():
    from pymodbus.client import AsyncModbusTcpClient

    port = free_port()
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "fieldgate", "simulate", "modbus-tcp-client",
        "--module", "3:M-7017R", "--listen", f"127.0.0.1:{port}", "--input", "net/m3/ai2=1234",
        "--name", "net",
        stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stdin is not None
    first = (await asyncio.wait_for(proc.stdout.readline(), 30)).decode()
    assert first.startswith(f"host 127.0.0.1:{port} served on 127.0.0.1:{port}: units 3"), first
    banner = (await asyncio.wait_for(proc.stdout.readline(), 30)).decode()
    assert banner.startswith("simulating back net (modbus-tcp-client)"), banner
    client = AsyncModbusTcpClient("127.0.0.1", port=port)
    try:
        await client.connect()
        reply = await client.read_input_registers(0, count=8, device_id=3)
        assert reply.registers[2] == 1234
        gone = await client.read_input_registers(0, count=1, device_id=9)
        assert gone.isError() and gone.exception_code == 0x0B  # nobody at unit 9
    finally:
        client.close()
        proc.stdin.write(b"quit\n")
        await proc.stdin.drain()
        assert await asyncio.wait_for(proc.wait(), 30) == 0


async def test_a_host_that_accepts_and_drops_at_once_is_retried_with_back_off():
    """A TCP/RTU gateway whose serial side is gone may accept a connection and close it at
    once: the back must not reconnect in a tight loop (it did: a connection per loop turn)."""
    accepted = 0

    async def drop(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        nonlocal accepted
        accepted += 1
        writer.close()

    port = free_port()
    server = await asyncio.start_server(drop, "127.0.0.1", port)
    loaded = load_topology(
        topology([device(1, f"127.0.0.1:{port}")], offline_probe_ms=800), load_registry()
    )
    context = GatewayContext.build(loaded)
    back = ModbusTcpClientBack(loaded.back("net"), context)
    await back.start()
    task = asyncio.ensure_future(back.run())
    try:
        await asyncio.sleep(2.5)
        # 0, 0.1, 0.3, 0.7, 1.5, 2.3 s: doubling from 0.1 s to offline_probe_ms
        assert 3 <= accepted <= 10, accepted
        assert context.image["net/m1/ai0"].quality is Quality.COMM_FAULT
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await back.stop()
        server.close()
        await server.wait_closed()
