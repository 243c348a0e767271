"""The canopen library as master against the gateway's CANopen front, over a real bus.

The device under test starts through the ``dut`` fixture (see canopen_dut.py): in-process
on a virtual bus here, as a ``fieldgate run`` process over vcan0 inside User-Mode Linux.
"""

from __future__ import annotations

import struct
import threading
import time

import can
import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from canopen_dut import BOOT_TIMEOUT, bus_under_test, make_dut, topology

NODE = 5


class Master:
    def __init__(self, interface: str, channel: str):
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.05  # quick disconnect
        self.network.connect(interface=interface, channel=channel)
        self.node = self.network.add_node(canopen.RemoteNode(NODE, canopen.ObjectDictionary()))
        self.node.sdo.RESPONSE_TIMEOUT = 1.0
        self.frames: dict[int, list[bytes]] = {}
        self._cv = threading.Condition()
        for cob in (0x700 + NODE, 0x80 + NODE):
            self.network.subscribe(cob, self._record)

    def _record(self, can_id, data, timestamp):
        with self._cv:
            self.frames.setdefault(can_id, []).append(bytes(data))
            self._cv.notify_all()

    def wait_frame(self, can_id: int, count: int = 1, timeout: float = 3.0) -> list[bytes]:
        with self._cv:
            self._cv.wait_for(lambda: len(self.frames.get(can_id, [])) >= count, timeout)
            return list(self.frames.get(can_id, []))

    def clear(self) -> None:
        with self._cv:
            self.frames.clear()

    def guard(self, timeout: float = 1.0) -> int:
        before = len(self.frames.get(0x700 + NODE, []))
        self.network.bus.send(
            can.Message(
                arbitration_id=0x700 + NODE, is_remote_frame=True, is_extended_id=False, dlc=1
            )
        )
        got = self.wait_frame(0x700 + NODE, before + 1, timeout)
        assert len(got) > before, "no guarding answer"
        assert len(got[-1]) == 1
        return got[-1][0]

    def close(self) -> None:
        self.network.disconnect()


@pytest.fixture
def bus():
    return bus_under_test()


@pytest.fixture
def rig(bus, tmp_path):
    interface, channel, external = bus
    master = Master(interface, channel)
    topo = topology(
        tmp_path / "state", NODE, guard_time_ms=0, heartbeat_ms=0, heartbeat_consumers=1
    )
    dut = make_dut(topo, interface, channel, external, tmp_path)
    dut.start()
    assert master.wait_frame(0x700 + NODE, 1, BOOT_TIMEOUT)[:1] == [b"\x00"], "no boot-up"
    yield master, dut
    dut.stop()
    master.close()


def test_boot_up_and_identity(rig):
    master, _ = rig
    sdo = master.node.sdo
    assert struct.unpack("<I", sdo.upload(0x1018, 1))[0] == 0xABCD
    assert struct.unpack("<I", sdo.upload(0x1018, 4))[0] == 42
    assert sdo.upload(0x1008, 0) == b"fieldgate test node"
    assert struct.unpack("<I", sdo.upload(0x1200, 1))[0] == 0x600 + NODE
    assert struct.unpack("<I", sdo.upload(0x1014, 0))[0] == 0x80 + NODE


def test_expedited_and_segmented_up_and_down(rig):
    master, _ = rig
    sdo = master.node.sdo
    sdo.download(0x1017, 0, struct.pack("<H", 0))
    sdo.download(0x100C, 0, struct.pack("<H", 300))
    assert sdo.upload(0x100C, 0) == struct.pack("<H", 300)
    with pytest.raises(SdoAbortedError) as err:
        sdo.download(0x100C, 0, b"\x01")
    assert err.value.code == 0x06070013
    with pytest.raises(SdoAbortedError) as err:
        sdo.upload(0x1008, 1)
    assert err.value.code == 0x06090011
    with pytest.raises(SdoAbortedError) as err:
        sdo.download(0x1000, 0, b"\0\0\0\0")
    assert err.value.code == 0x06010002
    # segmented upload of the 19-byte device name, forced segmented download of a U32
    assert sdo.upload(0x1008, 0) == b"fieldgate test node"
    with sdo.open(0x1016, 1, "wb", size=4, force_segment=True) as f:
        f.write(struct.pack("<I", (0x7F << 16) | 500))
    assert struct.unpack("<I", sdo.upload(0x1016, 1))[0] == (0x7F << 16) | 500


@pytest.mark.parametrize("crc", [False, True])
def test_block_transfers(rig, crc):
    master, _ = rig
    sdo = master.node.sdo
    with sdo.open(0x1008, 0, "rb", block_transfer=True, request_crc_support=crc) as f:
        assert f.read() == b"fieldgate test node"
    with sdo.open(0x1016, 1, "wb", size=4, block_transfer=True, request_crc_support=crc) as f:
        f.write(struct.pack("<I", (0x10 << 16) | 250))
    assert struct.unpack("<I", sdo.upload(0x1016, 1))[0] == (0x10 << 16) | 250


def test_nmt_states_seen_by_guarding_and_heartbeat(rig):
    master, _ = rig
    assert master.guard() == 0x7F
    master.node.nmt.send_command(0x01)
    time.sleep(0.05)
    assert master.guard() == 0x85  # toggle 1, operational
    master.node.nmt.send_command(0x02)
    time.sleep(0.05)
    assert master.guard() == 0x04
    master.node.sdo.RESPONSE_TIMEOUT = 0.3
    with pytest.raises(canopen.SdoCommunicationError):
        master.node.sdo.upload(0x1000, 0)  # no SDO in stopped
    master.node.sdo.RESPONSE_TIMEOUT = 1.0
    master.node.nmt.send_command(0x80)
    time.sleep(0.05)
    master.clear()
    master.node.sdo.download(0x1017, 0, struct.pack("<H", 50))
    beats = master.wait_frame(0x700 + NODE, 3, 2.0)
    assert beats[:3] == [b"\x7f"] * 3
    master.node.nmt.send_command(0x82)  # reset communication: boot-up, 0x1017 back to 0
    time.sleep(0.2)
    master.clear()
    time.sleep(0.2)
    assert master.frames.get(0x700 + NODE, []) == []
    assert master.node.sdo.upload(0x1017, 0) == b"\0\0"


def test_life_guarding_timeout_sends_emcy(rig):
    master, dut = rig
    sdo = master.node.sdo
    sdo.download(0x100C, 0, struct.pack("<H", 100))
    sdo.download(0x100D, 0, b"\x02")
    assert master.guard() == 0x7F
    assert master.wait_frame(0x80 + NODE, 1, 1.5)[0] == bytes.fromhex("3081110700000000")
    if dut.gateway is not None:
        assert dut.call(lambda: dut.gateway.masters.is_ok("plc")) is False
    assert master.guard() & 0x7F == 0x7F
    assert master.wait_frame(0x80 + NODE, 2, 1.0)[1] == bytes(8)
    assert sdo.upload(0x1003, 1) == b"\0\0\0\0"
    assert sdo.upload(0x1003, 2) == bytes.fromhex("30810700")


def test_store_restart_restore(rig, bus, tmp_path):
    master, dut = rig
    sdo = master.node.sdo
    sdo.download(0x100C, 0, struct.pack("<H", 777))
    sdo.download(0x1010, 1, b"save")
    dut.stop()
    master.clear()
    dut.start()
    assert master.wait_frame(0x700 + NODE, 1, BOOT_TIMEOUT)[:1] == [b"\x00"], "no boot-up"
    assert sdo.upload(0x100C, 0) == struct.pack("<H", 777)
    sdo.download(0x1011, 1, b"load")
    master.node.nmt.send_command(0x81)
    time.sleep(0.2)
    assert sdo.upload(0x100C, 0) == b"\0\0"


def test_heartbeat_consumer_watches_the_master(rig):
    """A Delta AS300-style master: heartbeat only, 0x1016 configured by SDO in pre-operational."""
    master, dut = rig
    beat = master.network.send_periodic(0x77F, b"\x05", 0.05)
    try:
        master.node.sdo.download(0x1016, 1, struct.pack("<I", (0x7F << 16) | 200))
        master.node.nmt.send_command(0x01)
        time.sleep(0.4)
        assert master.frames.get(0x80 + NODE, []) == []
    finally:
        beat.stop()
    assert master.wait_frame(0x80 + NODE, 1, 1.0)[0] == bytes.fromhex("308111077F000000")
    beat = master.network.send_periodic(0x77F, b"\x05", 0.05)
    try:
        assert master.wait_frame(0x80 + NODE, 2, 1.0)[1] == bytes(8)
    finally:
        beat.stop()
