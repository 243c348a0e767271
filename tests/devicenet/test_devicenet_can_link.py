"""The DeviceNet front and its SocketCAN interface (docs/can-link.md, docs/devicenet.md), on the
host with a fake kernel (tests/fake_can_link.py): the baud rate set over the network applied
through the interface at Identity Reset before the duplicate MAC ID check, a refused change
shown in the Identity status, bus-off handled as the DeviceNet object's BOI says. The real
drivers: tests/socketcan/test_socketcan_can_gateway.py in the QEMU guest."""

from __future__ import annotations

import asyncio
import uuid

import can
import pytest
from dnet_master import Master
from test_devicenet_front import SLAVE, topology

from fieldgate import Gateway, load_registry
from fieldgate.can.controller import CAN_ERR_BUSOFF

DUP_MAC = 0x400 | SLAVE << 3 | 7


@pytest.fixture
async def rig(tmp_path, kernel):
    channel = f"dnet-{uuid.uuid4().hex[:8]}"
    master = Master(channel, SLAVE)
    gateway = Gateway.load(topology(tmp_path, channel), registry=load_registry())
    await gateway.start()
    await master.wait_online()
    gateway.component("dnet").adapter.bus.set_filters(None)  # error frames (see the CANopen test)
    yield gateway, master, kernel
    await gateway.stop()
    master.close()


async def test_the_interface_gets_the_rate_and_restart_ms_0_at_start(rig):
    gateway, _, kernel = rig
    # restart-ms 0: the kernel never restarts the controller by itself, BOI decides
    assert (kernel.bitrate, kernel.restart_ms) == (500_000, 0)
    assert gateway.component("dnet").slave.identity_status & 0x0100 == 0


async def reset_to_125k(master: Master) -> None:
    assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
    assert await master.request(bytes.fromhex("10 03 01 02 00")) == bytes.fromhex("90")
    assert await master.request(bytes.fromhex("05 01 01 00")) == bytes.fromhex("85")


async def test_a_baud_change_reaches_the_interface_before_the_duplicate_mac_check(rig):
    gateway, master, kernel = rig
    order = []
    real_apply = kernel.apply_settings

    def apply(name, wanted):
        order.append(("apply", wanted.bitrate))
        return real_apply(name, wanted)

    kernel.apply_settings = apply
    gateway.component("dnet").interface.ops = kernel.ops
    adapter = gateway.component("dnet").adapter
    real_send = adapter.send

    def sending(frames, now=None):
        order.extend(("send", f.can_id) for f in frames if f.can_id == DUP_MAC)
        real_send(frames, now)

    adapter.send = sending
    await reset_to_125k(master)
    await master.expect(DUP_MAC)
    assert order[:2] == [("apply", 125_000), ("send", DUP_MAC)]
    assert kernel.bitrate == 125_000
    await asyncio.sleep(0.2)
    assert gateway.component("dnet").status()["state"] == "online"


async def test_a_refused_baud_change_is_a_minor_fault_in_the_identity_status(rig):
    gateway, master, kernel = rig
    kernel.refuse = True
    await reset_to_125k(master)
    await master.expect(DUP_MAC)  # the check runs anyway, at the rate the interface kept
    await asyncio.sleep(0.2)
    front = gateway.component("dnet")
    assert kernel.bitrate == 500_000
    assert "CAP_NET_ADMIN" in front.status()["link_fault"]
    assert front.slave.identity_status & 0x0100
    assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
    assert (await master.number(0x01, 1, 5)) & 0x0100


def bus_off(master: Master) -> None:
    master.bus.send(can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, data=bytes(8)))


async def test_bus_off_is_held_with_boi_0_and_recovered_with_boi_1(rig):
    gateway, master, kernel = rig
    front = gateway.component("dnet")
    kernel.go_bus_off()
    bus_off(master)
    await asyncio.sleep(0.4)
    assert not any(kind == "restart" for kind, _ in kernel.calls)  # BOI 0: held (ODVA)
    assert front.status()["bus"]["bus_off"] and front.slave.bus_off_count == 1
    # a fresh bus-off with BOI 1: the front restarts the controller after restart_ms
    kernel.state = "error-active"
    front.adapter.pump(lambda: front.adapter.controller.set_bus_off(False))
    front.slave.bus_off_interrupt = 1
    kernel.go_bus_off()
    bus_off(master)
    await asyncio.sleep(0.5)
    assert ("restart", front.config.channel) in kernel.calls
    assert not front.status()["bus"]["bus_off"] and front.slave.bus_off_count == 2
    assert await master.allocate(0x01) == bytes.fromhex("0A CB 00")
    assert await master.number(0x03, 1, 4) == 2  # the DeviceNet object's bus-off counter
