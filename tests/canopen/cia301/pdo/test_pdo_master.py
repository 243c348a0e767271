"""canopen's own master against the gateway's PDOs, with the OD from `fieldgate eds`.

Runs in-process on a virtual bus, and over vcan0 against a `fieldgate run` process inside
User-Mode Linux (the dut fixture of canopen_dut.py). The master configures PDOs with
canopen's PdoMap API (the DS301 sequence: invalidate, clear mapping, entries, count,
enable), so this is also an interoperability check of the mapping rules.
"""

from __future__ import annotations

import time

import canopen
import pytest
from canopen_dut import BOOT_TIMEOUT, bus_under_test, make_dut, topology, write_eds

NODE = 5


@pytest.fixture
def master_and_dut(tmp_path):
    interface, channel, external = bus_under_test()
    topo = topology(tmp_path / "state", NODE)
    eds = write_eds(topo, tmp_path)
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface=interface, channel=channel)
    node = network.add_node(canopen.RemoteNode(NODE, str(eds)))
    node.sdo.RESPONSE_TIMEOUT = 1.0
    dut = make_dut(topo, interface, channel, external, tmp_path)
    dut.start()
    try:
        deadline = time.monotonic() + BOOT_TIMEOUT
        while True:  # wait until the node answers SDO (a process needs a moment)
            try:
                node.sdo.upload(0x1000, 0)
                break
            except canopen.SdoCommunicationError:
                assert time.monotonic() < deadline, "the device does not answer"
        yield network, node
    finally:
        dut.stop()
        network.disconnect()


def test_master_reads_the_default_mapping_and_exchanges_pdos(master_and_dut):
    network, node = master_and_dut
    node.tpdo.read()
    node.rpdo.read()
    assert [(v.index, v.subindex) for v in node.tpdo[1].map] == [(0x6000, 1)]
    assert [(v.index, v.subindex) for v in node.tpdo[2].map] == [(0x6401, 1), (0x6401, 2)]
    assert [(v.index, v.subindex) for v in node.rpdo[1].map] == [(0x6200, 1)]
    assert node.tpdo[1].cob_id == 0x185 and node.rpdo[2].cob_id == 0x305
    node.nmt.state = "OPERATIONAL"
    time.sleep(0.1)
    node.rpdo[1].map[0].raw = 0x5A
    node.rpdo[1].transmit()  # DO byte -> loopback -> DI byte -> TPDO1 (type 255)
    deadline = time.monotonic() + 3
    while node.tpdo[1].map[0].raw != 0x5A and time.monotonic() < deadline:
        node.tpdo[1].wait_for_reception(0.5)
    assert node.tpdo[1].map[0].raw == 0x5A


def test_master_remaps_a_tpdo_to_synchronous_and_gets_it_at_sync(master_and_dut):
    network, node = master_and_dut
    node.tpdo.read()
    node.rpdo.read()
    tpdo = node.tpdo[3]
    tpdo.clear()
    tpdo.add_variable(0x6000, 1)
    tpdo.add_variable(0x6401, 2)
    tpdo.cob_id = 0x190
    tpdo.trans_type = 2
    tpdo.enabled = True
    tpdo.save()
    assert node.sdo.upload(0x1A02, 0) == b"\x02" and node.sdo.upload(0x1802, 2) == b"\x02"
    node.nmt.state = "OPERATIONAL"
    time.sleep(0.1)
    node.rpdo[2].map[1].raw = 1234  # AO2 -> loopback -> AI2
    node.rpdo[2].transmit()
    time.sleep(0.1)
    received = []
    tpdo.add_callback(lambda m: received.append((m[0].raw, m[1].raw)))
    for _ in range(4):
        network.sync.transmit()
        time.sleep(0.05)
    assert received == [(0, 1234), (0, 1234)]  # every 2nd SYNC
