"""A running gateway on a real CAN controller driver: two SJA1000s (QEMU's kvaser_pci, the kernel's
kvaser_pci + sja1000 drivers) on one QEMU can-bus, the gateway's front on the first, the test's
master on the second (docs/can-link.md, "Tested against real kernel drivers").

* the CANopen front applies its configured bit rate and restart-ms to can0 at start (the
  interface was at another rate), answers SDO at that rate; an LSS master on can1 configures
  and activates another bit timing: can0 is at the new rate after the switch delay and the node
  answers there; an interface restart (down/up, as after bus-off on a driver without a restart
  of its own) is recovered;
* the DeviceNet front: a baud rate Set over the network and an Identity Reset put can0 at the
  new rate before the duplicate MAC ID check, which the master then hears at the new rate, and
  the node serves an allocation there.

QEMU's can-bus carries frames whatever the controllers' rates, so "at the new rate" is asserted
the way the auto-baud test does it: the test's side switches its own controller, reads the
gateway's controller from the kernel, and only then sends. Bus-off itself (QEMU's SJA1000 never
counts errors) is driven through slcan: tests/socketcan/test_socketcan_slcan.py.

Run by `.ci/socketcan/run --can-controllers python -m pytest -m can_controller ...`.
"""

from __future__ import annotations

import asyncio
import subprocess
import time

import can
from socketcan_guest import scaled, with_controllers

from fieldgate import Gateway, load_registry
from fieldgate.can import link as canlink
from fieldgate.can.link import LinkSettings

pytestmark = with_controllers(2)
NODE, MAC = 5, 5


def canopen_topology(state_dir, channel: str, **front) -> dict:
    return {
        "gateway": {"name": "controllers", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "socketcan",
                "channel": channel,
                "node_id": NODE,
                **front,
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }


class Side:
    """The test's controller and a socket on it, opened again after each rate change (a
    socket bound to an interface that went down reports ENETDOWN at its next send)."""

    def __init__(self, name: str, bitrate: int):
        self.name = name
        canlink.apply_settings(name, LinkSettings(bitrate))
        self.bus = can.Bus(interface="socketcan", channel=name)

    def switch(self, bitrate: int) -> None:
        self.bus.shutdown()
        canlink.apply_settings(self.name, LinkSettings(bitrate))
        self.bus = can.Bus(interface="socketcan", channel=self.name)

    def send(self, can_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    def close(self) -> None:
        self.bus.shutdown()


async def frame(side: Side, can_id: int, timeout: float = 5.0) -> bytes:
    bus = side.bus
    end = time.monotonic() + scaled(timeout)
    while time.monotonic() < end:
        msg = await asyncio.to_thread(bus.recv, 0.1)
        if msg is not None and msg.arbitration_id == can_id and not msg.is_error_frame:
            return bytes(msg.data)
    raise AssertionError(f"no frame {can_id:03X} on {bus.channel_info}")


async def sdo_read_device_type(side: Side) -> bytes:
    side.send(0x600 + NODE, bytes.fromhex("4000100000000000"))
    return (await frame(side, 0x580 + NODE))[:4]


def lss(side: Side, cs: int, *data: int) -> None:
    side.send(0x7E5, bytes([cs, *data]).ljust(8, b"\0"))


async def test_canopen_bit_rate_at_start_then_by_lss_then_an_interface_restart(pair, tmp_path):
    gw_side, master_side = pair
    canlink.apply_settings(gw_side, LinkSettings(500_000, restart_ms=0))  # as someone left it
    master = Side(master_side, 250_000)  # the bus's rate
    gateway = Gateway.load(
        canopen_topology(tmp_path, gw_side, bitrate=250_000, restart_ms=100),
        registry=load_registry(),
    )
    await gateway.start()
    try:
        front = gateway.component("can")
        # applied at start: the kernel holds the configured rate and restart-ms
        held = canlink.read_link(gw_side)
        assert (held.bitrate, held.restart_ms, held.state) == (250_000, 100, "error-active")
        assert front.status()["bus"]["link"]["error"] is None
        assert await frame(master, 0x700 + NODE) == b"\x00"  # boot-up
        assert await sdo_read_device_type(master) == bytes.fromhex("43001000")

        # LSS: configure bit timing (CiA 305 table index 4 = 125 kbit/s), activate with 200 ms
        lss(master, 0x04, 1)
        lss(master, 0x13, 0, 4)
        assert (await frame(master, 0x7E4))[:2] == b"\x13\x00"
        lss(master, 0x15, 200, 0)
        # CiA 305: the master switches in the first delay too; the slave is silent until
        # the second has passed
        master.switch(125_000)
        end = time.monotonic() + scaled(10)
        moved = canlink.read_link(gw_side)
        # the kernel takes a new bit timing only while the link is down: the rate is written
        # a moment before the link comes up again, so wait for both
        while (moved.bitrate, moved.up) != (125_000, True) and time.monotonic() < end:
            await asyncio.sleep(0.05)
            moved = canlink.read_link(gw_side)
        assert (moved.bitrate, moved.up) == (125_000, True)
        await asyncio.sleep(scaled(0.4))  # the second delay: the node may transmit again
        lss(master, 0x04, 0)  # back to waiting
        assert await sdo_read_device_type(master) == bytes.fromhex("43001000")
        assert front.adapter.counters["bit_timing_switches"] == 1
        assert front.status()["bus"]["link"]["bitrate"] == 125_000

        # an interface restart (down/up): the front hears the bus again and answers
        subprocess.run(["ip", "link", "set", gw_side, "down"], check=True)
        subprocess.run(["ip", "link", "set", gw_side, "up"], check=True)
        await asyncio.sleep(scaled(0.5))
        assert await sdo_read_device_type(master) == bytes.fromhex("43001000")
    finally:
        await gateway.stop()
        master.close()


def devicenet_topology(state_dir, channel: str) -> dict:
    return {
        "gateway": {"name": "controllers-dnet", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "dnet",
                "type": "devicenet",
                "interface": "socketcan",
                "channel": channel,
                "mac_id": MAC,
                "bitrate": 125_000,
                "dup_mac_timeout_ms": 200,
                "identity": {"vendor_id": 803, "serial": 42},
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 3, "digital": 8}]}],
    }


async def test_devicenet_baud_set_and_identity_reset_move_the_controller(pair, tmp_path):
    gw_side, master_side = pair
    master = Side(master_side, 125_000)
    g2 = lambda message: 0x400 | MAC << 3 | message  # noqa: E731
    gateway = Gateway.load(devicenet_topology(tmp_path, gw_side), registry=load_registry())
    await gateway.start()
    try:
        assert canlink.read_link(gw_side).bitrate == 125_000
        assert (await frame(master, g2(7)))[0] == 0x00  # duplicate MAC ID check
        await asyncio.sleep(scaled(0.6))  # online

        def explicit(body: bytes) -> None:
            master.send(g2(4), bytes([0x0A]) + body)

        master.send(g2(6), bytes([0x0A, 0x4B, 0x03, 0x01, 0x01, 0x0A]))  # allocate explicit
        assert await frame(master, g2(3)) == bytes.fromhex("0A CB 00")
        explicit(bytes.fromhex("10 03 01 02 01"))  # DeviceNet object baud rate = 1 (250k)
        assert await frame(master, g2(3)) == bytes.fromhex("0A 90")
        assert canlink.read_link(gw_side).bitrate == 125_000  # applied at the next reset
        explicit(bytes.fromhex("05 01 01"))  # Identity Reset
        assert await frame(master, g2(3)) == bytes.fromhex("0A 85")
        master.switch(250_000)
        check = await frame(master, g2(7), timeout=10)  # the check, at the new rate
        assert check[0] == 0x00 and canlink.read_link(gw_side).bitrate == 250_000
        await asyncio.sleep(scaled(0.6))
        master.send(g2(6), bytes([0x0A, 0x4B, 0x03, 0x01, 0x01, 0x0A]))
        assert await frame(master, g2(3)) == bytes.fromhex("0A CB 00")
        status = gateway.component("dnet").status()
        assert status["bitrate"] == 250_000 and status["link_fault"] is None
    finally:
        await gateway.stop()
        master.close()
