"""The CANopen front and its SocketCAN interface (docs/can-link.md), on the host with a fake
kernel (tests/fake_can_link.py): the configured bit rate applied at start, the LSS bit-rate
switch applied at its delay, EMCY 00 81 11 0D when the interface cannot be set, bus-off
recovered by the kernel or by the front. The real drivers: the SocketCAN stage's QEMU guest
(tests/socketcan/test_socketcan_can_gateway.py)."""

from __future__ import annotations

import asyncio
import logging
import uuid

import pytest
from canopen_dut import topology
from test_canopen_front import Peer

from fieldgate import Gateway, load_registry
from fieldgate.can.controller import CAN_ERR_BUSOFF, CAN_ERR_RESTARTED

NODE = 5
EMCY = 0x80 + NODE
LINK_EMCY = bytes.fromhex("0081110d00000000")
LSS_REQUEST, LSS_RESPONSE = 0x7E5, 0x7E4


@pytest.fixture
async def start(tmp_path):
    made = []

    async def starting(**front):
        channel = f"link-{uuid.uuid4().hex[:8]}"
        peer = Peer(channel)
        topo = topology(tmp_path / "state", NODE, **front)
        topo["fronts"][0].update(channel=channel, interface="virtual")
        gateway = Gateway.load(topo, registry=load_registry())
        await gateway.start()
        made.append((gateway, peer))
        assert await peer.expect(0x700 + NODE) == b"\x00"
        # error frames come beside the acceptance filters on SocketCAN; open the virtual bus up
        gateway.component("plc").adapter.bus.set_filters(None)
        return gateway, peer

    yield starting
    for gateway, peer in made:
        await gateway.stop()
        peer.bus.shutdown()


async def test_the_configured_bit_rate_is_applied_at_start_and_what_differed_is_logged(
    start, kernel, caplog
):
    kernel.restart_ms = 0
    caplog.set_level(logging.INFO, "fieldgate.can.interface")
    gateway, peer = await start(bitrate=125_000, sample_point=0.875)
    assert (kernel.bitrate, kernel.restart_ms) == (125_000, 100)
    assert "bit rate 250000 -> 125000; restart-ms 0 -> 100" in caplog.text
    link = gateway.component("plc").status()["bus"]["link"]
    assert (link["bitrate"], link["restart_ms"], link["error"], link["applied"]) == (
        125_000,
        100,
        None,
        1,
    )
    assert await peer.quiet(0.2) == []  # no EMCY: the interface is as configured


async def test_without_the_capability_the_node_runs_on_and_shows_an_emcy(start, kernel, caplog):
    kernel.refuse = True
    gateway, peer = await start(bitrate=125_000)
    assert await peer.expect(EMCY) == LINK_EMCY  # after the boot-up, 0x1001 = 0x11
    front = gateway.component("plc")
    assert front.node.emcy.register == 0x11
    problem = front.status()["bus"]["link"]["error"]
    assert "CAP_NET_ADMIN" in problem and "bit rate 250000 -> 125000" in problem
    assert sum("CAP_NET_ADMIN" in r.message for r in caplog.records) == 1  # one line
    assert kernel.bitrate == 250_000  # left as it is


async def test_configure_interface_false_leaves_the_interface_alone_and_says_so(start, kernel):
    gateway, peer = await start(bitrate=125_000, configure_interface=False)
    assert kernel.calls == [] and kernel.bitrate == 250_000
    assert await peer.expect(EMCY) == LINK_EMCY  # the rate asked is not the interface's
    assert "configure_interface: false" in gateway.component("plc").status()["bus"]["link"]["error"]


def lss(cs: int, *data: int) -> bytes:
    return bytes([cs, *data]).ljust(8, b"\0")


async def lss_bit_rate_switch(peer: Peer, table_index: int, delay_ms: int = 20) -> None:
    peer.send(LSS_REQUEST, lss(0x04, 1))  # switch state global: configuration
    peer.send(LSS_REQUEST, lss(0x13, 0, table_index))  # configure bit timing, CiA table
    assert (await peer.expect(LSS_RESPONSE))[:2] == b"\x13\x00"
    peer.send(LSS_REQUEST, lss(0x15, delay_ms & 0xFF, delay_ms >> 8))  # activate bit timing


async def test_an_lss_bit_rate_switch_reaches_the_interface_at_its_delay(start, kernel):
    gateway, peer = await start(bitrate=125_000)
    await lss_bit_rate_switch(peer, 2)  # CiA 305 table index 2: 500 kbit/s
    await asyncio.sleep(0.15)
    assert kernel.applied_rates() == [125_000, 500_000] and kernel.bitrate == 500_000
    front = gateway.component("plc")
    assert front.adapter.counters["bit_timing_switches"] == 1
    peer.send(0x600 + NODE, bytes.fromhex("4000100000000000"))  # the node answers after it
    assert (await peer.expect(0x580 + NODE))[:4] == bytes.fromhex("43001000")


async def test_an_lss_switch_the_interface_refuses_is_an_emcy(start, kernel):
    gateway, peer = await start(bitrate=125_000)
    kernel.refuse = True
    await lss_bit_rate_switch(peer, 2)
    assert await peer.expect(EMCY, timeout=1.0) == LINK_EMCY
    front = gateway.component("plc")
    assert front.adapter.counters["bit_timing_failures"] == 1
    assert "500000" in front.status()["bus"]["link"]["error"]
    # a later switch that works ends it
    kernel.refuse = False
    await lss_bit_rate_switch(peer, 4)  # 125 kbit/s again
    assert await peer.expect(EMCY, timeout=1.0) == bytes(8)


async def test_bus_off_with_restart_ms_0_is_recovered_by_the_front(start, kernel):
    gateway, peer = await start(bitrate=250_000, restart_ms=0)
    front = gateway.component("plc")
    kernel.go_bus_off()
    peer.send(CAN_ERR_BUSOFF, bytes(8), error=True)
    # the kernel does not restart it (restart-ms 0): the front does, then EMCY 0x8140
    assert await peer.expect(EMCY, timeout=2.0) == bytes.fromhex("4081110800000000")
    assert ("restart", front.config.channel) in kernel.calls
    status = front.status()["bus"]
    assert (status["bus_off"], status["bus_off_events"], status["bus_off_recoveries"]) == (
        False,
        1,
        1,
    )
    assert (status["link"]["restarts_by_fieldgate"], status["link"]["state"]) == (
        1,
        "error-active",
    )
    samples = {(s[0], tuple(sorted(s[4].items()))): s[3] for s in front.metrics()}
    assert samples[("can_controller_restarts_by_fieldgate_total", ())] == 1
    assert samples[("can_controller_restarts_total", ())] == 1  # the kernel counts every restart
    assert samples[("can_error_counter", (("direction", "tx"),))] == 0


async def test_bus_off_with_restart_ms_set_is_left_to_the_kernel(start, kernel):
    gateway, peer = await start(bitrate=250_000, restart_ms=100)
    kernel.go_bus_off()
    peer.send(CAN_ERR_BUSOFF, bytes(8), error=True)
    await asyncio.sleep(0.3)
    assert not any(kind == "restart" for kind, _ in kernel.calls)
    assert gateway.component("plc").status()["bus"]["link"]["bus_off"] == 1
    kernel.state = "error-active"  # the kernel's restart, and its error frame
    peer.send(CAN_ERR_RESTARTED, bytes(8), error=True)
    assert await peer.expect(EMCY, timeout=2.0) == bytes.fromhex("4081110800000000")
