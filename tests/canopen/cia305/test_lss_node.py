"""LssService inside the sans-I/O Node: unconfigured start, new node-ID, boot-up, bit rate."""

from __future__ import annotations

import struct

from canopen.objectdictionary import datatypes as dt

from fieldgate.can.frame import Frame
from fieldgate.plugins.canopen.cia301.nmt import NmtState
from fieldgate.plugins.canopen.cia301.node import Node
from fieldgate.plugins.canopen.cia301.od import Dictionary
from fieldgate.plugins.canopen.cia305.lss import LssService, LssStore, StoredLss

VENDOR, PRODUCT, REVISION, SERIAL = 0x0000_0301, 0x0000_7232, 0x0002_0001, 0x0012_3456


def identity_od() -> Dictionary:
    od = Dictionary()
    od.add_record(
        0x1018,
        "Identity object",
        [
            (1, "Vendor-ID", dt.UNSIGNED32, "ro", VENDOR),
            (2, "Product code", dt.UNSIGNED32, "ro", PRODUCT),
            (3, "Revision number", dt.UNSIGNED32, "ro", REVISION),
            (4, "Serial number", dt.UNSIGNED32, "ro", SERIAL),
        ],
    )
    return od


def make_node(node_id=None, **lss_options) -> tuple[Node, LssService]:
    node = Node(node_id, identity_od())
    lss = node.add_service(LssService(**lss_options))
    return node, lss


def lss(hexbytes: str) -> Frame:
    return Frame(0x7E5, bytes.fromhex(hexbytes))


def answer(hexbytes: str) -> Frame:
    return Frame(0x7E4, bytes.fromhex(hexbytes))


def test_unconfigured_node_is_silent_then_boots_with_the_lss_node_id():
    node, _ = make_node()
    assert node.boot(0.0) == []  # no boot-up without a node-ID
    assert node.state == NmtState.INITIALISING
    assert node.receive(Frame(0x000, bytes([0x01, 0x00])), 0.1) == []  # NMT ignored
    assert node.receive(lss("04 01 00 00 00 00 00 00"), 0.2) == []
    assert node.receive(lss("5E 00 00 00 00 00 00 00"), 0.3) == [answer("5E FF 00 00 00 00 00 00")]
    assert node.receive(lss("11 0A 00 00 00 00 00 00"), 0.4) == [answer("11 00 00 00 00 00 00 00")]
    assert node.receive(lss("04 00 00 00 00 00 00 00"), 0.5) == [Frame(0x70A, b"\x00")]
    assert node.state == NmtState.PRE_OPERATIONAL and node.node_id == 0x0A
    node.receive(Frame(0x000, bytes([0x01, 0x0A])), 0.6)
    assert node.state == NmtState.OPERATIONAL


def test_lss_address_comes_from_the_identity_object():
    node, _ = make_node(5)
    node.boot(0.0)
    out = []
    for cs, value in ((0x40, VENDOR), (0x41, PRODUCT), (0x42, REVISION), (0x43, SERIAL)):
        out += node.receive(Frame(0x7E5, struct.pack("<BI3x", cs, value)), 0.1)
    assert out == [answer("44 00 00 00 00 00 00 00")]
    assert node.receive(lss("5D 00 00 00 00 00 00 00"), 0.2) == [answer("5D 56 34 12 00 00 00 00")]


def test_lss_works_in_every_nmt_state():
    node, _ = make_node(5)
    node.boot(0.0)
    node.receive(Frame(0x000, bytes([0x02, 0x05])), 0.1)  # stopped
    assert node.state == NmtState.STOPPED
    node.receive(lss("04 01 00 00 00 00 00 00"), 0.2)
    assert node.receive(lss("5E 00 00 00 00 00 00 00"), 0.3) == [answer("5E 05 00 00 00 00 00 00")]


def test_new_node_id_of_a_configured_node_waits_for_nmt_reset_communication():
    node, _ = make_node(5)
    node.boot(0.0)
    node.receive(lss("04 01 00 00 00 00 00 00"), 0.1)
    node.receive(lss("11 06 00 00 00 00 00 00"), 0.2)
    assert node.receive(lss("04 00 00 00 00 00 00 00"), 0.3) == []
    assert node.node_id == 5
    assert node.receive(Frame(0x000, bytes([0x82, 0x05])), 0.4) == [Frame(0x706, b"\x00")]
    node.receive(lss("04 01 00 00 00 00 00 00"), 0.5)
    assert node.receive(lss("5E 00 00 00 00 00 00 00"), 0.6) == [answer("5E 06 00 00 00 00 00 00")]


def test_activate_bit_timing_reaches_the_node_after_the_switch_delay():
    node, service = make_node(5, bitrate=250_000)
    changes = []
    node.on_bit_timing(lambda bitrate, delay: changes.append((bitrate, delay)))
    node.boot(0.0)
    node.receive(lss("04 01 00 00 00 00 00 00"), 1.0)
    node.receive(lss("13 00 02 00 00 00 00 00"), 1.0)  # 500k
    assert node.receive(lss("15 32 00 00 00 00 00 00"), 1.0) == []  # 50 ms
    assert node.next_deadline() == 1.05
    assert not service.transmit_allowed(1.01)
    node.tick(1.04)
    assert changes == []
    node.tick(1.05)
    assert changes == [(500_000, 0.0)]
    assert service.bitrate == 500_000
    assert node.next_deadline() == 1.1
    node.tick(1.1)
    assert service.transmit_allowed(1.1) and node.next_deadline() is None


def test_stored_lss_settings_win_at_power_on(tmp_path):
    store = LssStore(tmp_path / "lss.json")
    store.save(StoredLss(node_id=0x33, bitrate=125_000))
    node, service = make_node(5, bitrate=500_000, store=store)
    assert service.bitrate == 125_000
    assert node.boot(0.0) == [Frame(0x733, b"\x00")]


def test_malformed_lss_frames_are_counted_not_answered():
    node, service = make_node(5)
    node.boot(0.0)
    assert node.receive(Frame(0x7E5, bytes(3)), 0.1) == []
    assert node.receive(Frame(0x7E5, rtr=True, dlc=8), 0.1) == []
    assert service.status()["dropped_malformed"] == 2
    assert node.status()["services"]["lss"]["received"] == 2
