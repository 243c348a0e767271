"""canopen's master against examples/na9161-style.yaml over simulated Modbus modules: it maps
the counter's special bytes (0x3000/0x3200) and single digital channels (0x6020-/0x6220-,
dummy entries) with its PdoMap API, reading the OD from the front's EDS, and the data
travel between the simulated modules and the bus (in-process, virtual bus; the
``fieldgate_thread`` and ``canopen_master`` test fixtures)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from ruamel.yaml import YAML

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "na9161-style.yaml"
NODE = 5  # the example's node-ID


def until(predicate, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


@pytest.fixture
def na9161(tmp_path, fieldgate_thread, canopen_master):
    """The example in a gateway thread (simulated modules), and canopen's master with the OD of
    its EDS: the test fixtures fieldgate and its canopen plugin ship."""
    topo = YAML(typ="safe").load(EXAMPLE.read_text())
    topo["gateway"]["state_dir"] = str(tmp_path / "state")
    channel = f"fg-na9161-{tmp_path.name[-12:]}"
    topo["fronts"][0].update(
        bit_mapping=True, guard_time_ms=0, life_time_factor=0, interface="virtual", channel=channel
    )
    topo["backs"][0]["poll_ms"] = 5
    master = canopen_master(topo)
    dut = fieldgate_thread(topo)
    master.wait_answering()
    yield master.network, master.node, dut, dut.simulator("rs485")


def test_master_maps_the_counter_bytes_and_exchanges_them(na9161):
    network, node, dut, sim = na9161
    node.tpdo.read()
    node.rpdo.read()
    assert not any(v.index == 0x3000 for p in node.tpdo.map.values() for v in p.map)
    tpdo, rpdo = node.tpdo[3], node.rpdo[3]
    tpdo.clear()
    for sub in range(1, 7):
        tpdo.add_variable(0x3000, sub)
    tpdo.cob_id, tpdo.trans_type, tpdo.inhibit_time, tpdo.enabled = 0x381, 255, 0, True
    tpdo.save()
    rpdo.clear()
    rpdo.add_variable(0x3200, 1)
    rpdo.add_variable(0x3200, 2)
    rpdo.cob_id, rpdo.trans_type, rpdo.enabled = 0x401, 255, True
    rpdo.save()
    assert node.sdo.upload(0x1A02, 0) == b"\x06" and node.sdo.upload(0x1602, 1) == bytes.fromhex(
        "08010032"
    )
    node.nmt.state = "OPERATIONAL"
    for i, byte in enumerate((0x10, 0x27, 0, 0, 0x01, 0x02)):
        dut.call(lambda i=i, byte=byte: sim.set_input(f"rs485/m5/si{i}", byte))
    assert until(lambda: [v.raw for v in tpdo.map] == [0x10, 0x27, 0, 0, 1, 2]), [
        v.raw for v in tpdo.map
    ]
    rpdo.map[0].raw, rpdo.map[1].raw = 0xE8, 0x03
    rpdo.transmit()
    assert until(
        lambda: (
            dut.call(lambda: (sim.get_output("rs485/m5/so0"), sim.get_output("rs485/m5/so1")))
            == (0xE8, 3)
        )
    )
    # byte_order little: the control word 0x03E8 sits in holding register 0 as it is on CAN
    module, point = sim.channels["rs485/m5/so0"]
    assert module.tables[point.table][0] == 0x03E8


def test_master_maps_single_digital_channels_with_dummies(na9161):
    network, node, dut, sim = na9161
    assert node.object_dictionary.device_information.granularity  # Granularity=1 read back
    node.tpdo.read()
    node.rpdo.read()
    tpdo, rpdo = node.tpdo[4], node.rpdo[4]
    tpdo.clear()
    tpdo.add_variable(0x6020, 3, 1)  # DI 3 (slot 1 DI 2)
    tpdo.add_variable(0x6020, 9, 1)  # DI 9 (slot 2 DI 1: the 8th bit is slot 2's DI 0)
    tpdo.cob_id, tpdo.trans_type, tpdo.inhibit_time, tpdo.enabled = 0x481, 255, 0, True
    tpdo.save()
    rpdo.clear()
    rpdo.add_variable(0x0005, 0, 8)  # skip a byte (UNSIGNED8 dummy)
    rpdo.add_variable(0x6220, 10, 1)  # DO 10 = slot 2 relay 1 (slot 1 has 8 DO)
    rpdo.cob_id, rpdo.trans_type, rpdo.enabled = 0x501, 255, True
    rpdo.save()
    assert node.sdo.upload(0x1A03, 1) == bytes.fromhex("01032060")
    node.nmt.state = "OPERATIONAL"
    received: list[tuple[int, int]] = []
    tpdo.add_callback(lambda m: received.append((m[0].raw, m[1].raw)))
    dut.call(lambda: sim.set_input("rs485/m1/di2", True))
    dut.call(lambda: sim.set_input("rs485/m2/di1", True))
    assert until(lambda: (True, True) in [(bool(a), bool(b)) for a, b in received]), received
    rpdo.map[1].raw = True
    rpdo.transmit()
    assert until(lambda: dut.call(lambda: sim.get_output("rs485/m2/do1")) is True)
    assert dut.call(lambda: (sim.get_output("rs485/m2/do0"), sim.get_output("rs485/m1/do7"))) == (
        False,
        False,
    )
