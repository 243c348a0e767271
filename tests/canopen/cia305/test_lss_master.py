"""The gateway's LSS slave against canopen's LssMaster, over a real bus.

The device under test is the gateway's CANopen front, started through canopen_dut (in
process on a virtual bus; as a ``fieldgate run`` process over vcan0 inside User-Mode
Linux). The tests only use LssMaster, watch frames, and read the LSS store file.
"""

from __future__ import annotations

import json
import queue
import time
import types

import canopen
import canopen.lss
import pytest
from canopen.lss import LssError
from canopen_dut import BOOT_TIMEOUT, FRONT, bus_under_test, make_dut, topology

from fieldgate.plugins.canopen.cia305.lss import LssAddress

# Few 1 bits: fastscan pays one response timeout per 1 bit.
IDENTITY = LssAddress(vendor=0x00000001, product=0x00000232, revision=0x00010000, serial=0x00000010)


@pytest.fixture
def fast_master(monkeypatch):
    """LssMaster pauses 0.2 s after every address frame for slow devices; ours needs none."""
    monkeypatch.setattr(canopen.lss, "time", types.SimpleNamespace(sleep=lambda s: None))


@pytest.fixture
def bus():
    return bus_under_test()


@pytest.fixture
def network(bus, fast_master):
    interface, channel, _ = bus
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05  # quick shutdown
    net.connect(interface=interface, channel=channel)
    yield net
    net.disconnect()


@pytest.fixture
def boot_ups(network):
    seen: queue.Queue[tuple[int, bytes]] = queue.Queue()
    for node_id in range(1, 128):
        network.subscribe(0x700 + node_id, lambda can_id, data, ts: seen.put((can_id, bytes(data))))
    return seen


@pytest.fixture
def state_dir(tmp_path):
    return tmp_path / "state"


def wait_unconfigured_ready(lss, timeout=BOOT_TIMEOUT) -> None:
    """An unconfigured node sends nothing by itself: ask until it answers 0x4C with 0x50."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        lss.send_identify_non_configured_remote_slave()
        try:
            if lss.responses.get(timeout=0.2)[0] == 0x50:
                return
        except queue.Empty:
            pass
    raise AssertionError("the unconfigured node never answered identify non-configured")


@pytest.fixture
def device(bus, network, boot_ups, state_dir, tmp_path):
    """``device(node_id=..., **front)`` starts the gateway and waits until it is on the bus.

    A configured node is ready at its boot-up (returned); an unconfigured one when it
    answers "identify non-configured remote slave". Start again after ``stop()``: power cycle.
    """
    interface, channel, external = bus
    running = []

    def start(node_id=None, expect_boot_up=None, **front):
        identity = {
            "vendor_id": IDENTITY.vendor,
            "product_code": IDENTITY.product,
            "revision": IDENTITY.revision,
            "serial": IDENTITY.serial,
        }
        topo = topology(state_dir, node_id, identity=identity, **front)
        dut = make_dut(topo, interface, channel, external, tmp_path)
        dut.start()
        running.append(dut)
        expected = expect_boot_up or node_id
        if expected is None:
            wait_unconfigured_ready(network.lss)
        else:
            assert boot_ups.get(timeout=BOOT_TIMEOUT) == (0x700 + expected, b"\x00")
        return dut

    yield start
    for dut in running:
        dut.stop()


def lss_store(state_dir) -> dict:
    return json.loads((state_dir / f"{FRONT}.lss.json").read_text())


def test_inquire_identity_and_node_id(network, device):
    device(node_id=0x21)
    lss = network.lss
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    assert lss.inquire_lss_address(canopen.lss.CS_INQUIRE_VENDOR_ID) == IDENTITY.vendor
    assert lss.inquire_lss_address(canopen.lss.CS_INQUIRE_PRODUCT_CODE) == IDENTITY.product
    assert lss.inquire_lss_address(canopen.lss.CS_INQUIRE_REVISION_NUMBER) == IDENTITY.revision
    assert lss.inquire_lss_address(canopen.lss.CS_INQUIRE_SERIAL_NUMBER) == IDENTITY.serial
    assert lss.inquire_node_id() == 0x21


def test_inquiry_is_refused_in_waiting_state(network, device):
    device(node_id=0x21)
    network.lss.RESPONSE_TIMEOUT = 0.3
    with pytest.raises(LssError, match="No LSS response"):
        network.lss.inquire_node_id()


def test_switch_state_selective_matches_only_the_exact_address(network, device):
    device(node_id=4)
    lss = network.lss
    lss.RESPONSE_TIMEOUT = 0.3
    with pytest.raises(LssError, match="No LSS response"):
        lss.send_switch_state_selective(
            IDENTITY.vendor, IDENTITY.product, IDENTITY.revision, IDENTITY.serial + 1
        )
    assert lss.send_switch_state_selective(
        IDENTITY.vendor, IDENTITY.product, IDENTITY.revision, IDENTITY.serial
    )
    assert lss.inquire_node_id() == 4  # now in configuration state


def test_configure_node_id_with_error_for_invalid_ids(network, device, boot_ups):
    device(node_id=4)
    lss = network.lss
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    for bad in (0, 128, 0xFE):
        with pytest.raises(LssError, match="LSS Error: 1"):
            lss.configure_node_id(bad)
    lss.configure_node_id(0x0A)
    assert lss.inquire_node_id() == 4  # the new ID waits for reset communication
    lss.send_switch_state_global(lss.WAITING_STATE)
    with pytest.raises(queue.Empty):
        boot_ups.get(timeout=0.3)  # a configured node does not reboot on its own
    network.send_message(0x000, bytes([0x82, 4]))  # NMT reset communication
    assert boot_ups.get(timeout=2) == (0x70A, b"\x00")


def test_unconfigured_node_is_silent_until_given_an_id_then_boots_up(network, device, boot_ups):
    device()  # no node-ID
    network.send_message(0x000, bytes([0x81, 0]))  # NMT reset all nodes: not for it
    with pytest.raises(queue.Empty):
        boot_ups.get(timeout=0.3)
    lss = network.lss
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    assert lss.inquire_node_id() == 0xFF
    lss.configure_node_id(0x05)
    lss.send_switch_state_global(lss.WAITING_STATE)
    assert boot_ups.get(timeout=2) == (0x705, b"\x00")
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    assert lss.inquire_node_id() == 0x05


def test_bit_timing_store_and_power_cycle(network, device, state_dir):
    dut = device(node_id=4, bitrate=500_000)
    lss = network.lss
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    with pytest.raises(LssError, match="LSS Error: 1"):
        lss.configure_bit_timing(9)  # auto bit rate is not offered
    lss.configure_bit_timing(4)  # CiA table: 125 kbit/s
    lss.configure_node_id(0x30)
    lss.store_configuration()
    assert lss_store(state_dir) == {
        "format": "fieldgate-lss/1",
        "node_id": 0x30,
        "bitrate": 125_000,
    }
    lss.activate_bit_timing(20)
    time.sleep(0.3)  # silent 20 ms, switch, silent 20 ms
    assert lss.inquire_node_id() == 4  # still on the bus after the switch
    dut.stop()
    device(node_id=4, bitrate=500_000, expect_boot_up=0x30)  # power cycle: the stored settings win
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    assert lss.inquire_node_id() == 0x30


def test_store_that_cannot_be_written_answers_error_2(network, device, state_dir):
    state_dir.mkdir(parents=True)
    (state_dir / "blocker").write_text("a file where a directory should be")
    device(node_id=4, lss_store_file="blocker/lss.json")
    lss = network.lss
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    with pytest.raises(LssError, match="LSS Error: 2"):
        lss.store_configuration()
    assert lss.inquire_node_id() == 4


def _identify_answer(lss, timeout=0.3):
    try:
        return lss.responses.get(timeout=timeout)
    except queue.Empty:
        return None


def test_identify_remote_slave_by_ranges(network, device):
    device(node_id=4)
    lss = network.lss
    lss.send_identify_remote_slave(
        IDENTITY.vendor, IDENTITY.product, 0, 0xFFFFFFFF, IDENTITY.serial, IDENTITY.serial + 10
    )
    assert _identify_answer(lss, 2) == bytes.fromhex("4F 00 00 00 00 00 00 00")
    lss.send_identify_remote_slave(
        IDENTITY.vendor, IDENTITY.product, IDENTITY.revision + 1, 0xFFFFFFFF, 0, 0xFFFFFFFF
    )
    assert _identify_answer(lss) is None


def test_identify_non_configured_remote_slave(network, device):
    device(node_id=4)
    lss = network.lss
    lss.send_identify_non_configured_remote_slave()
    assert _identify_answer(lss) is None  # configured: not for it
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    lss.configure_node_id(0xFF)
    network.send_message(0x000, bytes([0x82, 4]))  # reset communication: now unconfigured
    lss.send_switch_state_global(lss.WAITING_STATE)
    wait_unconfigured_ready(lss, timeout=2)


def test_fastscan_finds_the_unconfigured_node_and_configures_it(network, device, boot_ups):
    device()
    lss = network.lss
    lss.RESPONSE_TIMEOUT = 0.25  # a 1 bit costs one timeout; the identity has few
    found, address = lss.fast_scan()
    assert found
    assert address == [IDENTITY.vendor, IDENTITY.product, IDENTITY.revision, IDENTITY.serial]
    lss.configure_node_id(0x11)  # fastscan left the node in configuration state
    lss.send_switch_state_global(lss.WAITING_STATE)
    assert boot_ups.get(timeout=2) == (0x711, b"\x00")
    assert lss.fast_scan() == (False, None)  # configured nodes stay out of fastscan


def test_i7232d_bit_timing_table_is_selectable(network, device, state_dir):
    device(node_id=4, lss_table="i7232d")
    lss = network.lss
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    lss.configure_bit_timing(3)  # seed-000 TV-21: index 3 of the I-7232D table = 125 kbit/s
    with pytest.raises(LssError, match="LSS Error: 1"):
        lss.configure_bit_timing(8)  # the I-7232D table stops at 7 (1 Mbit/s)
    lss.store_configuration()
    assert lss_store(state_dir)["bitrate"] == 125_000
