"""Field power (audit 004 #36, #39): a DI wired to the 24 V field supply (``field_power``) makes
the NA-9161's 0x4500:1 byte 3 = 0x80 while it reads false or its module is offline, an EMCY
``00 33 05`` (CiA 301 output voltage) with its reset, and the status API / metrics show it."""

from __future__ import annotations

import asyncio
import uuid

import pytest
from canopen_dut import topology
from test_canopen_front import Peer

from fieldgate import Gateway, Quality, load_registry
from fieldgate.topology import TopologyError, load_topology

NODE = 5
EMCY = 0x80 + NODE
SENSE = "io/m3/di7"


async def read_4500_1(peer: Peer) -> bytes:
    peer.send(0x600 + NODE, bytes.fromhex("4000450100000000"))
    return (await peer.expect(0x580 + NODE))[4:]


async def test_field_power_missing_and_back(tmp_path):
    channel = f"power-{uuid.uuid4().hex[:8]}"
    peer = Peer(channel)
    topo = topology(tmp_path, NODE, style="na9161", field_power=SENSE)
    topo["fronts"][0]["channel"] = channel
    gateway = Gateway.load(topo, registry=load_registry())
    await gateway.start()
    try:
        assert await peer.expect(0x700 + NODE) == b"\x00"
        front = gateway.component("plc")
        gateway.image.update_input(SENSE, True)
        await asyncio.sleep(0.05)
        assert front.status()["field_power"] is True
        assert await read_4500_1(peer) == bytes(4)
        gateway.image.update_input(SENSE, False)  # the supply is gone
        assert await peer.expect(EMCY) == bytes.fromhex("0033050000000000")
        assert await read_4500_1(peer) == bytes([0, 0, 0, 0x80])
        assert front.status()["field_power"] is False
        samples = {s[0]: s[3] for s in front.metrics()}
        assert samples["canopen_field_power"] == 0
        gateway.image.update_input(SENSE, True)
        assert await peer.expect(EMCY) == bytes(8)
        gateway.image.set_quality([SENSE], Quality.COMM_FAULT)  # the sensing module offline
        assert await peer.expect(EMCY) == bytes.fromhex("0033050000000000")
    finally:
        await gateway.stop()
        peer.bus.shutdown()


def test_field_power_must_name_an_input(tmp_path):
    with pytest.raises(TopologyError, match="no input channel"):
        load_topology(topology(tmp_path, NODE, field_power="io/m3/do0"), load_registry())
