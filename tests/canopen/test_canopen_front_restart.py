"""A canopen front restarted by the runtime (dead bus) while its master was lost: the fresh
node keeps the master lost until the master is heard, then reports ok (docs/canopen.md,
"After a front restart"). On python-can's virtual bus, inside a Gateway."""

from __future__ import annotations

import asyncio
import uuid

import can
import pytest
from canopen_dut import topology
from test_canopen_front import NODE, Peer

from fieldgate import Gateway, load_registry

FRONT = "plc"
EMCY = 0x80 + NODE


@pytest.fixture(scope="module")
def registry():
    return load_registry()


async def wait_until(predicate, timeout: float = 2.0) -> bool:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while loop.time() < end:
        if predicate():
            return True
        await asyncio.sleep(0.01)
    return predicate()


async def restarted(gateway: Gateway, peer: Peer) -> None:
    """Kill the front's receiving (as a dead interface does) and wait for the new boot-up."""
    gateway.component(FRONT).adapter.fail(can.CanOperationError("interface went down"))
    assert await peer.expect(0x700 + NODE, 3.0) == b"\x00"
    assert gateway.status()["fronts"][FRONT]["restarts"] == 1


@pytest.fixture
async def running(tmp_path, registry):
    """The gateway with life guarding 100 ms x 2 configured, booted, and the test's bus end."""
    channel = f"restart-{uuid.uuid4().hex[:8]}"
    peer = Peer(channel)
    topo = topology(
        tmp_path / "state",
        NODE,
        channel=channel,
        restart_backoff_s=0.05,
        guard_time_ms=100,
        life_time_factor=2,
    )
    gateway = Gateway.load(topo, registry=registry)
    await gateway.start()
    try:
        assert await peer.expect(0x700 + NODE) == b"\x00"
        yield gateway, peer
    finally:
        await gateway.stop()
        peer.bus.shutdown()


async def test_master_lost_before_a_restart_stays_lost_until_an_nmt_command(running):
    gateway, peer = running
    do0 = "io/m3/do0"
    gateway.write(do0, True)
    peer.send(0x700 + NODE, rtr=True)
    assert await peer.expect(EMCY, 2.0) == bytes.fromhex("3081110700000000")
    assert not gateway.masters.is_ok(FRONT)
    assert gateway.read(do0) is False  # error value applied
    await restarted(gateway, peer)
    await asyncio.sleep(0.3)  # nothing heard yet: still lost, and no EMCY from the new node
    assert not gateway.masters.is_ok(FRONT)
    status = gateway.status()["fronts"][FRONT]
    assert status["master"]["lost"] and status["services"]["error_control"]["master_unheard"]
    assert [m for m in await peer.quiet(0.1) if m.arbitration_id == EMCY] == []
    peer.send(0x000, bytes([0x01, NODE]))  # NMT start: the master is back
    assert await wait_until(lambda: gateway.masters.is_ok(FRONT))
    assert gateway.status()["fronts"][FRONT]["master"]["reason"] == "NMT OPERATIONAL"
    assert gateway.read(do0) is False  # outputs keep their error values until new data


async def test_master_lost_before_a_restart_ends_at_the_first_guard_request(running):
    gateway, peer = running
    peer.send(0x700 + NODE, rtr=True)
    await peer.expect(EMCY, 2.0)
    await restarted(gateway, peer)
    assert not gateway.masters.is_ok(FRONT)
    peer.send(0x700 + NODE, rtr=True)
    assert await peer.expect(0x700 + NODE) == b"\x7f"  # toggle 0: a new node
    assert await wait_until(lambda: gateway.masters.is_ok(FRONT))
    assert await peer.expect(EMCY, 2.0) == bytes.fromhex("3081110700000000")  # guarding runs again
    assert not gateway.masters.is_ok(FRONT)


async def test_restart_with_the_master_present_keeps_it_ok(running):
    gateway, peer = running
    await restarted(gateway, peer)
    assert gateway.masters.is_ok(FRONT)
    assert not gateway.status()["fronts"][FRONT]["services"]["error_control"]["master_unheard"]
