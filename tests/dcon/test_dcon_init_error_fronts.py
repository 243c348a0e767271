"""A ``modules: auto`` DCON back that found no module (no port, no earlier scan, no scan file:
an empty image) reports "DCON modules init error" through core's protocol-neutral back error
(``HealthRegistry.back_error``), and each front shows it the way its device does (audit 001
#35, 003 #39): the I-7231D-style CANopen node boots and sends EMCY ``00 50 81 04`` (0x1001 set)
beside the COM port EMCY; the I-7241D-style DeviceNet node comes online with the Identity
status's major recoverable fault, object 0x64's operation state ``1`` and the 7-segment display
``1`` in its status; the gateway status lists the back's error (docs/dcon.md)."""

from __future__ import annotations

import asyncio
import uuid
from pathlib import Path

import can
import pytest

from fieldgate import Gateway, load_registry


def topology(tmp_path: Path, front: dict) -> dict:
    return {
        "gateway": {"name": "init-error", "state_dir": str(tmp_path / "state")},
        "fronts": [front],
        "backs": [
            {
                "name": "rs485",
                "type": "dcon",
                "port": str(tmp_path / "ttyUSB0"),  # not there
                "modules": "auto",
                "scan": {"addresses": "1-3"},
            }
        ],
    }


async def recv(bus: can.BusABC, can_id: int, timeout: float = 3.0) -> bytes:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while loop.time() < end:
        msg = await asyncio.to_thread(bus.recv, 0.05)
        if msg is not None and msg.arbitration_id == can_id:
            return bytes(msg.data)
    raise AssertionError(f"no frame {can_id:03X}")


@pytest.fixture
def channel():
    return f"init-{uuid.uuid4().hex[:8]}"


async def test_the_canopen_node_boots_and_sends_the_init_error_emcy(tmp_path, channel):
    front = {
        "name": "can",
        "type": "canopen",
        "interface": "virtual",
        "channel": channel,
        "node_id": 3,
    }
    peer = can.Bus(interface="virtual", channel=channel)
    gateway = Gateway.load(topology(tmp_path, front), registry=load_registry())
    try:
        await gateway.start()
        assert await recv(peer, 0x703) == b"\x00"  # boot-up: on the bus with no module
        emcys = {await recv(peer, 0x83), await recv(peer, 0x83)}
        assert emcys == {
            bytes.fromhex("0050810300000000"),  # COM port access error (the port is missing)
            bytes.fromhex("0050810400000000"),  # DCON modules init error (ours)
        }
        node = gateway.component("can").node
        assert node.emcy.register == 0x81 and node.emcy.is_active(0x5000)
        status = gateway.status()
        assert status["back_errors"]["rs485"].startswith("DCON modules init error: ")
        assert status["backs"]["rs485"]["start_scan"]["modules"] == []
        # the error ends with the back's own (here: told by hand, as _init_check does)
        gateway.health.back_error("rs485", None)
        gateway.health.port_state("rs485", True)
        await asyncio.sleep(0.1)
        assert not node.emcy.is_active(0x5000) and node.emcy.register == 0
    finally:
        await gateway.stop()
        peer.shutdown()


async def test_the_devicenet_node_is_online_with_the_7_segment_1(tmp_path, channel):
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "devicenet"))
    from dnet_master import Master

    front = {
        "name": "dnet",
        "type": "devicenet",
        "interface": "virtual",
        "channel": channel,
        "mac_id": 1,
        "dup_mac_timeout_ms": 50,
    }
    master = Master(channel, 1)
    gateway = Gateway.load(topology(tmp_path, front), registry=load_registry())
    try:
        await gateway.start()
        await master.wait_online()
        status = gateway.component("dnet").status()
        assert status["state"] == "online" and status["display"] == "10103"
        assert (
            status["identity_status"] & 0x0400 and "DCON modules init error" in status["back_fault"]
        )
        assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
        assert (await master.number(0x01, 1, 5)) & 0x0400  # Identity status: major recoverable
        assert await master.get(0x64, 0, 5) == b"1"  # object 0x64: the operation state
        assert await master.number(0x64, 0, 2) == 0  # no module instance
        gateway.health.back_error("rs485", None)
        assert gateway.component("dnet").status()["display"].startswith("n")
        assert await master.get(0x64, 0, 5) == b"n"
    finally:
        await gateway.stop()
        master.close()
