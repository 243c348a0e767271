"""CAN controller health: error warning / passive and overruns as the seeds' EMCYs (with the
error reset), in the front's status, /metrics and the event hub.

SocketCAN error frames are sent on python-can's virtual bus as SocketCAN delivers them (the
adapter reads them the same way); the node's reaction is also checked on a fake clock.
"""

from __future__ import annotations

import asyncio
import errno
import uuid

import can
import pytest
from canopen_dut import topology
from test_canopen_front import Peer
from test_canopen_profiles import Dut

from fieldgate import Gateway, load_registry
from fieldgate.can.controller import CAN_ERR_CNT, CAN_ERR_CRTL, CAN_ERR_RESTARTED

NODE = 5
EMCY = 0x80 + NODE
CRTL_RX_WARNING, CRTL_RX_PASSIVE, CRTL_ACTIVE, CRTL_RX_OVERFLOW = 0x04, 0x10, 0x40, 0x01


def crtl(bits: int) -> bytes:
    return bytes([0, bits, 0, 0, 0, 0, 0, 0])


@pytest.fixture
async def gw(tmp_path):
    channel = f"health-{uuid.uuid4().hex[:8]}"
    peer = Peer(channel)
    topo = topology(tmp_path / "state", NODE)
    topo["fronts"][0]["channel"] = channel
    gateway = Gateway.load(topo, registry=load_registry())
    await gateway.start()
    assert await peer.expect(0x700 + NODE) == b"\x00"
    # SocketCAN delivers error frames beside the acceptance filters (CAN_RAW_ERR_FILTER);
    # python-can's own filtering on the virtual bus would drop them: open it up here.
    gateway.component("plc").adapter.bus.set_filters(None)
    yield gateway, peer
    await gateway.stop()
    peer.bus.shutdown()


async def test_warning_passive_and_back_to_active_icpdas(gw):
    gateway, peer = gw
    front = gateway.component("plc")
    events = []
    gateway.context.events.subscribe(events.append)
    peer.send(CAN_ERR_CRTL, crtl(CRTL_RX_WARNING), error=True)
    assert await peer.expect(EMCY) == bytes.fromhex("0010810100000000")  # CAN controller error
    assert front.status()["bus"]["controller"] == "warning"
    peer.send(CAN_ERR_CRTL, crtl(CRTL_RX_PASSIVE), error=True)  # the same I-7232D error
    await asyncio.sleep(0.1)
    assert front.status()["bus"]["controller"] == "passive"
    peer.send(CAN_ERR_CRTL, crtl(CRTL_ACTIVE), error=True)
    assert await peer.expect(EMCY) == bytes(8)  # error reset
    assert [e.data.get("state") for e in events if e.kind == "can-state"] == [
        "warning",
        "passive",
        "error-active",
    ]
    samples = {(s[0], tuple(sorted(s[4].items()))): s[3] for s in front.metrics()}
    assert samples[("can_controller_state", (("state", "error-active"),))] == 1
    assert samples[("can_controller_state", (("state", "passive"),))] == 0


async def test_error_counters_give_the_state_without_crtl_bits(gw):
    gateway, peer = gw
    front = gateway.component("plc")
    peer.send(CAN_ERR_CNT, bytes([0, 0, 0, 0, 0, 0, 130, 12]), error=True)  # TX counter 130
    assert await peer.expect(EMCY) == bytes.fromhex("0010810100000000")
    assert front.status()["bus"]["controller"] == "passive"
    peer.send(CAN_ERR_RESTARTED, bytes(8), error=True)
    assert await peer.expect(EMCY) == bytes(8)


async def test_controller_overrun_is_an_emcy_until_quiet(gw):
    gateway, peer = gw
    front = gateway.component("plc")
    peer.send(CAN_ERR_CRTL, crtl(CRTL_RX_OVERFLOW), error=True)
    assert await peer.expect(EMCY) == bytes.fromhex("1081110600000000")
    assert front.status()["bus"]["overruns"]["controller"] == 1
    assert gateway.component("plc").node.emcy.register == 0x11
    assert await peer.expect(EMCY, timeout=2.0) == bytes(8)  # 1 s without another: reset
    samples = {(s[0], tuple(sorted(s[4].items()))): s[3] for s in front.metrics()}
    assert samples[("can_overruns_total", (("kind", "controller"),))] == 1


async def test_a_full_transmit_queue_is_a_tx_overrun(gw):
    gateway, peer = gw
    adapter = gateway.component("plc").adapter
    real_send = adapter.bus.send

    def full(msg, timeout=None):
        raise can.CanOperationError("No buffer space available", errno.ENOBUFS)

    adapter.bus.send = full
    adapter.pump(lambda: gateway.component("plc").node.emcy.signal(0x1234, 0x01))
    adapter.bus.send = real_send
    assert await peer.expect(EMCY) == bytes.fromhex("1081110500000000")
    assert adapter.status()["overruns"]["tx"] >= 1


def test_node_reaction_on_a_fake_clock_na9161():
    dut = Dut({"node_id": 5, "style": "na9161"})
    health = dut.node.service("can_health")
    dut.start()
    health.controller("warning", dut.rig.now)
    assert dut.emcys(show_flush(dut)) == ["00 81 11 80 00 00 00 00"]
    health.controller("passive", dut.rig.now)  # another code: the warning ends, passive starts
    assert dut.emcys(show_flush(dut)) == ["20 81 11 80 00 00 00 00", "00 00 11 00 00 00 00 00"]
    health.controller("error-active", dut.rig.now)
    assert dut.emcys(show_flush(dut)) == ["00 00 00 00 00 00 00 00"]
    health.overrun("rx", dut.rig.now)
    assert dut.emcys(show_flush(dut)) == ["10 81 11 10 00 00 00 00"]
    assert dut.emcys(dut.rig.advance(0.9)) == []
    health.overrun("controller", dut.rig.now)  # the same code: one error, its quiet time restarts
    assert dut.emcys(show_flush(dut)) == []
    assert dut.emcys(dut.rig.advance(0.9)) == []
    assert dut.emcys(dut.rig.advance(0.2)) == ["00 00 00 00 00 00 00 00"]
    assert health.status()["overruns"] == {"rx": 1, "controller": 1}


def show_flush(dut) -> list[str]:
    from canopen_rig import show

    return show(dut.node.flush())
