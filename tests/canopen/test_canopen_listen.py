"""The CANopen front's listen set and acceptance filters, on python-can's virtual bus.

The node states the CAN-IDs it takes frames on (``Node.listen_ids``); the adapter gives them
to ``bus.set_filters`` (python-can filters in ``recv`` on the virtual bus, the kernel on
SocketCAN). Every configuration change is checked: SDO writes to a PDO COB-ID, 0x1005,
0x1012, 0x1016 and an SDO channel, NMT reset communication, an LSS node-ID switch; and a
frame outside the set never reaches the node. (Over real vcan: tests/socketcan/test_socketcan_can_load.py.)
"""

from __future__ import annotations

import asyncio
import uuid

import can
import pytest

from fieldgate import Gateway, load_registry
from fieldgate.can.filters import matches

NODE = 3


def channel() -> str:
    return f"listen-{uuid.uuid4().hex[:10]}"


async def expect(master: can.BusABC, can_id: int, timeout: float = 3.0) -> can.Message:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while loop.time() < end:
        msg = await asyncio.to_thread(master.recv, 0.05)
        if msg is not None and msg.arbitration_id == can_id:
            return msg
    raise AssertionError(f"no frame on 0x{can_id:03X}")


def send(master: can.BusABC, can_id: int, data: bytes, rtr: bool = False) -> None:
    master.send(
        can.Message(
            arbitration_id=can_id,
            data=data,
            is_extended_id=False,
            is_remote_frame=rtr,
            dlc=len(data) if not rtr else 1,
        )
    )


async def sdo_write(master: can.BusABC, index: int, sub: int, value: int, node: int = NODE) -> None:
    send(
        master,
        0x600 + node,
        bytes([0x23, index & 0xFF, index >> 8, sub]) + value.to_bytes(4, "little"),
    )
    answer = await expect(master, 0x580 + node)
    assert answer.data[0] == 0x60, answer.data.hex()


async def sdo_read(master: can.BusABC, index: int, sub: int, node: int = NODE) -> bytes:
    send(master, 0x600 + node, bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]))
    return bytes((await expect(master, 0x580 + node)).data)


@pytest.fixture
async def rig(tmp_path):
    ch = channel()
    topology = {
        "gateway": {"name": "listen", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "virtual",
                "channel": ch,
                "node_id": NODE,
                "sdo_servers": 2,
                "heartbeat_consumers": 2,
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": 1, "digital": 8, "analog": 1, "error_mode": {"value": 0}}],
            }
        ],
    }
    gw = Gateway.load(topology, registry=load_registry())
    await gw.start()
    master = can.Bus(interface="virtual", channel=ch)
    front = gw.component("can")
    await asyncio.sleep(0)
    try:
        yield gw, front, master
    finally:
        master.shutdown()
        await gw.stop()


def applied(front) -> list[tuple[int, int]]:
    """The filters python-can holds for the front's bus, as (id, mask)."""
    return [(f["can_id"], f["can_mask"]) for f in front.adapter.bus.filters]


def hears(front, can_id: int) -> bool:
    """The node lists ``can_id`` and the bus's filters admit it."""
    return can_id in front.node.listen_ids() and matches(applied(front), can_id)


def deaf_to(front, can_id: int) -> bool:
    return can_id not in front.node.listen_ids() and not matches(applied(front), can_id)


async def test_the_default_listen_set_is_exactly_what_the_node_serves(rig):
    _, front, _ = rig
    assert front.node.listen_ids() == {
        0x000,  # NMT
        0x080,  # SYNC (0x1005)
        0x100,  # TIME (0x1012, consumed by default)
        0x600 + NODE,  # SDO server 0x1200
        0x700 + NODE,  # guarding RTR
        0x7E5,  # LSS
        *(base + NODE for base in (0x180, 0x280, 0x380, 0x480)),  # TPDO1-4 (remote requests)
        *(base + NODE for base in (0x200, 0x300, 0x400, 0x500)),  # RPDO1-4
    }
    assert front.adapter.listen == front.node.listen_ids()
    for can_id in front.node.listen_ids():
        assert matches(applied(front), can_id)
    for foreign in (0x181, 0x201, 0x585, 0x601, 0x77F, 0x7E4):
        assert deaf_to(front, foreign)
    assert all(f["extended"] is False for f in front.adapter.bus.filters)
    assert len(front.adapter.filters) <= front.adapter.max_filters


async def test_a_foreign_frame_never_reaches_the_node(rig):
    _, front, master = rig
    node, adapter = front.node, front.adapter
    before_node, before_bus = node.frames_received, adapter.rx_frames
    ignored = node.counters["ignored"]
    for can_id in (0x181, 0x1FF, 0x281, 0x382, 0x585, 0x601, 0x77F):
        send(master, can_id, bytes(8))
    assert (await sdo_read(master, 0x1000, 0))[0] == 0x43
    assert node.frames_received == before_node + 1  # the SDO read only
    assert adapter.rx_frames == before_bus + 1
    assert node.counters["ignored"] == ignored
    assert adapter.status()["rx_ignored"] == 0


async def test_a_pdo_cob_id_rewritten_by_sdo_is_heard_at_once_and_the_old_one_no_more(rig):
    gw, front, master = rig
    old, new = 0x200 + NODE, 0x321
    assert hears(front, old)
    await sdo_write(master, 0x1400, 1, 0x8000_0000 | old)  # invalid first (CiA 301)
    assert deaf_to(front, old)
    await sdo_write(master, 0x1400, 1, new)
    assert hears(front, new) and deaf_to(front, old)
    send(master, 0x000, bytes([0x01, NODE]))
    assert (await sdo_read(master, 0x1000, 0))[0] == 0x43  # Operational (no TPDO at Start)
    send(master, new, b"\x81")  # the answer to the SDO write is out: the new ID is heard
    await expect(master, 0x180 + NODE)
    assert [gw.read(f"io/m1/do{i}") for i in range(8)] == [True] + [False] * 6 + [True]
    received = front.node.frames_received
    send(master, old, b"\xff")  # the old ID: filtered out
    assert (await sdo_read(master, 0x1000, 0))[0] == 0x43
    assert front.node.frames_received == received + 1
    assert gw.read("io/m1/do1") is False


async def test_sync_time_heartbeat_consumer_and_sdo_channel_writes_move_the_filters(rig):
    _, front, master = rig
    await sdo_write(master, 0x1005, 0, 0x81)
    assert hears(front, 0x81) and deaf_to(front, 0x80)
    await sdo_write(master, 0x1012, 0, 0x100)  # bit 31 clear: TIME not consumed
    assert deaf_to(front, 0x100)
    await sdo_write(master, 0x1012, 0, 0x8000_00FE)
    assert hears(front, 0x0FE)
    await sdo_write(master, 0x1016, 2, (0x22 << 16) | 500)  # consume node 0x22's heartbeat
    assert hears(front, 0x722)
    await sdo_write(master, 0x1016, 2, 0)
    assert deaf_to(front, 0x722)
    await sdo_write(master, 0x1201, 2, 0x6C0)  # SDO channel 2: valid once both are written
    await sdo_write(master, 0x1201, 1, 0x6A0)
    assert hears(front, 0x6A0)
    send(master, 0x6A0, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))
    assert (await expect(master, 0x6C0)).data[0] == 0x43
    await sdo_write(master, 0x1201, 1, 0x8000_0640)
    assert deaf_to(front, 0x6A0)


async def test_nmt_reset_communication_restores_the_default_filters(rig):
    _, front, master = rig
    default = front.node.listen_ids()
    await sdo_write(master, 0x1005, 0, 0x81)
    await sdo_write(master, 0x1400, 1, 0x8000_0000 | (0x200 + NODE))
    assert front.node.listen_ids() != default
    send(master, 0x000, bytes([0x82, NODE]))
    await expect(master, 0x700 + NODE)  # boot-up
    assert front.node.listen_ids() == default == front.adapter.listen
    assert hears(front, 0x80) and hears(front, 0x200 + NODE) and deaf_to(front, 0x81)


async def test_an_lss_node_id_switch_moves_the_sdo_and_guarding_filters(rig):
    _, front, master = rig
    new = 9
    send(master, 0x7E5, bytes.fromhex("0401000000000000"))  # switch state global: configuration
    send(master, 0x7E5, bytes([0x11, new, 0, 0, 0, 0, 0, 0]))  # configure node-ID
    assert (await expect(master, 0x7E4)).data[:2] == b"\x11\x00"
    send(master, 0x7E5, bytes.fromhex("0400000000000000"))  # waiting
    assert hears(front, 0x600 + NODE)  # pending until reset communication
    send(master, 0x000, bytes([0x82, NODE]))
    await expect(master, 0x700 + new)  # boot-up under the new node-ID
    assert hears(front, 0x600 + new) and hears(front, 0x700 + new) and hears(front, 0x200 + new)
    assert deaf_to(front, 0x600 + NODE) and deaf_to(front, 0x700 + NODE)
    assert (await sdo_read(master, 0x1000, 0, node=new))[0] == 0x43
