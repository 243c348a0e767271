"""The DeviceNet slave's listen set (the adapter's acceptance filters): Group 2 for its MAC
ID (requests, poll, duplicate MAC ID check), the allocated master's bit-strobe, the Offline
Connection Set; it follows a MAC ID change, and a foreign frame never reaches the engine."""

from __future__ import annotations

import asyncio

from dnet_rig import MASTER, SLAVE, Rig

from fieldgate.can.filters import matches
from fieldgate.plugins.devicenet import ids


def own_group2(mac: int) -> set[int]:
    return {0x400 | mac << 3 | message for message in range(8)}


OFFLINE_SET = {0x7EC, 0x7ED, 0x7EE, 0x7EF}


def test_a_slave_without_a_master_listens_to_its_group2_ids_and_the_offline_set():
    rig = Rig()
    assert rig.slave.listen_ids() == own_group2(SLAVE) | OFFLINE_SET
    assert rig.slave.listen_ids() is rig.slave.listen_ids()  # unchanged: the same object


def test_allocation_adds_the_masters_bit_strobe():
    rig = Rig()
    rig.allocate(0x07)  # explicit + poll + strobe
    assert rig.slave.listen_ids() == own_group2(SLAVE) | OFFLINE_SET | {
        ids.group2_id(MASTER, ids.G2_STROBE)
    }


def test_an_offline_mac_change_moves_the_listen_set():
    rig = Rig(online=False, vendor_id=803, serial=1)
    rig.send("44F 80 23 03 02 00 00 00")  # another node answers our check: communication fault
    assert rig.slave.state == "comm-fault"
    assert 0x7ED in rig.slave.listen_ids()
    rig.send("7ED 07 4D 23 03 01 00 00 00")  # the Offline Connection Set moves us to MAC 7
    assert rig.slave.listen_ids() == own_group2(7) | OFFLINE_SET


async def test_the_front_filters_on_its_mac_and_foreign_frames_never_reach_the_engine(tmp_path):
    import uuid

    import can
    from test_devicenet_front import topology

    from fieldgate import Gateway, load_registry

    channel = f"dnet-listen-{uuid.uuid4().hex[:8]}"
    gateway = Gateway.load(topology(tmp_path, channel), registry=load_registry())
    await gateway.start()
    peer = can.Bus(interface="virtual", channel=channel)
    try:
        front = next(c for c in gateway.fronts)
        slave, adapter = front.slave, front.adapter
        loop = asyncio.get_running_loop()
        end = loop.time() + 5
        while slave.state != "online" and loop.time() < end:
            await asyncio.sleep(0.01)
        assert slave.state == "online"
        rx_before = adapter.rx_frames
        applied = [(f["can_id"], f["can_mask"]) for f in adapter.bus.filters]
        mac = slave.mac_id
        assert all(matches(applied, i) for i in own_group2(mac) | OFFLINE_SET)
        assert not any(matches(applied, i) for i in (0x181, 0x3C5, 0x400 | (mac ^ 1) << 3 | 4))
        for can_id in (0x181, 0x3C5, 0x400 | (mac ^ 1) << 3 | 4, 0x7E5):
            peer.send(can.Message(arbitration_id=can_id, data=bytes(8), is_extended_id=False))
        # a duplicate MAC ID request for its MAC: heard and answered
        peer.send(
            can.Message(
                arbitration_id=ids.group2_id(mac, ids.G2_DUP_MAC),
                data=bytes.fromhex("00230302000000"),
                is_extended_id=False,
            )
        )
        end = loop.time() + 5
        while loop.time() < end:
            msg = await asyncio.to_thread(peer.recv, 0.1)
            if (
                msg is not None
                and msg.arbitration_id == ids.group2_id(mac, ids.G2_DUP_MAC)
                and msg.data[0] == 0x80
            ):
                break
        else:
            raise AssertionError("no duplicate MAC ID response")
        assert adapter.rx_frames == rx_before + 1  # only the check arrived
        assert adapter.rx_ignored == 0
        assert slave.counters["rx_unexpected"] == 0
    finally:
        peer.shutdown()
        await gateway.stop()
