"""The canopen library as master: a monitoring error ends when the master switches the
monitoring off or resets communication, on the bus (EMCY, 0x1001) and in the gateway
(``masters.is_ok``). The engine-level rules are in test_canopen_errctl_clear.py."""

from __future__ import annotations

import struct
import time

import pytest
from canopen_dut import BOOT_TIMEOUT, FRONT, bus_under_test, make_dut, topology
from test_canopen_master import NODE, Master

EMCY = 0x80 + NODE


@pytest.fixture
def rig(tmp_path):
    interface, channel, external = bus_under_test()
    master = Master(interface, channel)
    dut = make_dut(
        topology(tmp_path / "state", NODE, heartbeat_consumers=1),
        interface,
        channel,
        external,
        tmp_path,
    )
    dut.start()
    assert master.wait_frame(0x700 + NODE, 1, BOOT_TIMEOUT)[:1] == [b"\x00"], "no boot-up"
    yield master, dut
    dut.stop()
    master.close()


def master_ok(dut) -> bool | None:
    """The gateway's view (in-process runs only)."""
    return dut.call(lambda: dut.gateway.masters.is_ok(FRONT)) if dut.gateway is not None else None


def test_guard_time_0_ends_the_life_guarding_error(rig):
    master, dut = rig
    sdo = master.node.sdo
    sdo.download(0x100C, 0, struct.pack("<H", 100))
    sdo.download(0x100D, 0, b"\x02")
    assert master.guard() == 0x7F
    assert master.wait_frame(EMCY, 1, 1.5)[0] == bytes.fromhex("3081110700000000")
    assert sdo.upload(0x1001, 0) == b"\x11"
    assert master_ok(dut) in (False, None)
    sdo.download(0x100C, 0, b"\0\0")  # guarding off
    assert master.wait_frame(EMCY, 2, 1.0)[1] == bytes(8)
    assert sdo.upload(0x1001, 0) == b"\x00"
    assert master_ok(dut) in (True, None)


def test_reset_communication_ends_the_heartbeat_consumer_error(rig):
    master, dut = rig
    beat = master.network.send_periodic(0x77F, b"\x05", 0.05)
    try:
        master.node.sdo.download(0x1016, 1, struct.pack("<I", (0x7F << 16) | 200))
        time.sleep(0.2)
    finally:
        beat.stop()
    assert master.wait_frame(EMCY, 1, 1.0)[0] == bytes.fromhex("308111077F000000")
    assert master_ok(dut) in (False, None)
    master.clear()
    master.node.nmt.send_command(0x82)
    assert master.wait_frame(0x700 + NODE, 1, 1.0)[0] == b"\x00"
    # the icpdas style announces the reset request first (I-7232D: 00 FF 80 0A), then the
    # reset ends the heartbeat error after the boot-up
    assert master.wait_frame(EMCY, 2, 1.0) == [bytes.fromhex("00FF800A00000000"), bytes(8)]
    assert master.node.sdo.upload(0x1001, 0) == b"\x00"
    assert master_ok(dut) in (True, None)
    time.sleep(0.4)  # 0x1016 reloaded (0): nothing watched, no new error
    assert master.frames.get(EMCY, []) == [bytes.fromhex("00FF800A00000000"), bytes(8)]
