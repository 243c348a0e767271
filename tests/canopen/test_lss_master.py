"""LSS slave against canopen's LssMaster on an in-process virtual CAN bus.

The device is a black box on the bus: the tests only use LssMaster and watch frames.
"""

from __future__ import annotations

import queue
import threading
import time
import types

import can
import canopen
import canopen.lss
import pytest
from canopen.lss import LssError

from fieldgate.plugins.canopen.lss import (
    REQUEST_ID, LssAddress, LssSlave, LssStore, ResetCommunication, SwitchBitRate)

# Few 1 bits: fastscan pays one response timeout per 1 bit.
IDENTITY = LssAddress(vendor=0x00000001, product=0x00000232, revision=0x00010000, serial=0x00000010)


class LssDevice:
    """The LSS engine on a virtual bus, with a node's boot-up (until the front runs here)."""

    def __init__(self, channel, node_id=0xFF, bitrate=None, store_path=None):
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        store = LssStore(store_path) if store_path is not None else None
        self.slave = LssSlave.starting(IDENTITY, node_id=node_id, bitrate=bitrate, store=store)
        self.bitrate_changes: queue.Queue[int] = queue.Queue()
        self._running = True
        self._thread = threading.Thread(target=self._loop, daemon=True)
        if self.slave.configured:
            self._boot_up(self.slave.active_node_id)
        self._thread.start()

    def _boot_up(self, node_id):
        self.bus.send(can.Message(arbitration_id=0x700 + node_id, data=b"\x00", is_extended_id=False))

    def _loop(self):
        while self._running:
            msg = self.bus.recv(0.005)
            now = time.monotonic()
            frames = self.slave.on_timer(now)
            if msg is not None and msg.arbitration_id == REQUEST_ID:
                frames += self.slave.on_frame(msg.arbitration_id, bytes(msg.data), now,
                                              rtr=msg.is_remote_frame)
            for can_id, data in frames:
                self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
            for action in self.slave.take_actions():
                if isinstance(action, ResetCommunication):
                    self._boot_up(action.node_id)
                elif isinstance(action, SwitchBitRate):
                    self.bitrate_changes.put(action.bitrate)

    def stop(self):
        if self._running:
            self._running = False
            self._thread.join()
            self.bus.shutdown()


@pytest.fixture
def fast_master(monkeypatch):
    """LssMaster pauses 0.2 s after every address frame for slow devices; ours needs none."""
    monkeypatch.setattr(canopen.lss, "time", types.SimpleNamespace(sleep=lambda s: None))


@pytest.fixture
def bus_channel(request):
    return f"lss-{request.node.name}"


@pytest.fixture
def network(bus_channel, fast_master):
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05  # quick shutdown
    net.connect(interface="virtual", channel=bus_channel, receive_own_messages=False)
    yield net
    net.disconnect()


@pytest.fixture
def boot_ups(network):
    seen: queue.Queue[tuple[int, bytes]] = queue.Queue()
    for node_id in range(1, 128):
        network.subscribe(0x700 + node_id, lambda can_id, data, ts: seen.put((can_id, bytes(data))))
    return seen


@pytest.fixture
def device(bus_channel, tmp_path):
    devices = []

    def start(node_id: int = 0xFF, **kw) -> LssDevice:
        kw.setdefault("store_path", tmp_path / "lss.json")
        dev = LssDevice(bus_channel, node_id=node_id, **kw)
        devices.append(dev)
        return dev

    yield start
    for dev in devices:
        dev.stop()


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
        lss.send_switch_state_selective(IDENTITY.vendor, IDENTITY.product, IDENTITY.revision, IDENTITY.serial + 1)
    assert lss.send_switch_state_selective(IDENTITY.vendor, IDENTITY.product, IDENTITY.revision, IDENTITY.serial)
    assert lss.inquire_node_id() == 4  # now in configuration state


def test_configure_node_id_with_error_for_invalid_ids(network, device, boot_ups):
    device(node_id=4)
    assert boot_ups.get(timeout=2) == (0x704, b"\x00")
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


def test_unconfigured_node_is_silent_until_given_an_id_then_boots_up(network, device, boot_ups):
    device()  # no node-ID
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


def test_bit_timing_store_and_power_cycle(network, device, boot_ups):
    dev = device(node_id=4, bitrate=500_000)
    assert boot_ups.get(timeout=2) == (0x704, b"\x00")
    lss = network.lss
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    with pytest.raises(LssError, match="LSS Error: 1"):
        lss.configure_bit_timing(9)  # auto bit rate is not offered
    lss.configure_bit_timing(4)  # CiA table: 125 kbit/s
    lss.configure_node_id(0x30)
    lss.store_configuration()
    lss.activate_bit_timing(20)
    assert dev.bitrate_changes.get(timeout=2) == 125_000
    dev.stop()
    device(node_id=4, bitrate=500_000)  # power cycle: the stored settings win
    assert boot_ups.get(timeout=2) == (0x730, b"\x00")
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    assert lss.inquire_node_id() == 0x30


def test_store_is_refused_without_a_store_file(network, device):
    device(node_id=4, store_path=None)
    lss = network.lss
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    with pytest.raises(LssError, match="LSS Error: 1"):
        lss.store_configuration()


def _identify_answer(lss, timeout=0.3):
    try:
        return lss.responses.get(timeout=timeout)
    except queue.Empty:
        return None


def test_identify_remote_slave_by_ranges(network, device):
    device(node_id=4)
    lss = network.lss
    lss.send_identify_remote_slave(IDENTITY.vendor, IDENTITY.product, 0, 0xFFFFFFFF,
                                   IDENTITY.serial, IDENTITY.serial + 10)
    assert _identify_answer(lss, 2) == bytes.fromhex("4F 00 00 00 00 00 00 00")
    lss.send_identify_remote_slave(IDENTITY.vendor, IDENTITY.product, IDENTITY.revision + 1,
                                   0xFFFFFFFF, 0, 0xFFFFFFFF)
    assert _identify_answer(lss) is None


def test_identify_non_configured_remote_slave(network, device):
    device()
    lss = network.lss
    lss.send_identify_non_configured_remote_slave()
    assert _identify_answer(lss, 2) == bytes.fromhex("50 00 00 00 00 00 00 00")


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
