"""Group 2 Only unconnected port: Allocate / Release and their CIP error responses."""

import pytest
from dnet_rig import Rig


@pytest.fixture
def rig():
    return Rig()


def test_seed_allocate_explicit_poll_strobe(rig):
    assert rig.allocate(0x07) == "44B 0A CB 00"  # TV-01 / TV-02
    assert rig.explicit("0E 03 01 05") == "0A 8E 07 0A"  # allocation info: choice, master MAC
    assert rig.explicit("0E 05 01 01") == "0A 8E 03"  # explicit established
    assert rig.explicit("0E 05 02 01") == "0A 8E 01"  # poll configuring until EPR is set
    assert rig.explicit("0E 01 01 05") == "0A 8E 01 00"  # identity status: owned


@pytest.mark.parametrize(
    "request_, reply",
    [
        ("0A 4B 03 01 00 0A", "0A 94 09 02"),  # choice 0
        ("0A 4B 03 01 41 0A", "0A 94 09 02"),  # ack suppression without COS/cyclic
        ("0A 4B 03 01 31 0A", "0A 94 09 02"),  # COS and cyclic together
        ("0A 4B 03 01 09 0A", "0A 94 02 02"),  # multicast poll: not supported
        ("0A 4B 03 01 02 0A", "0A 94 09 02"),  # poll without explicit
        ("0A 4B 03 01 01", "0A 94 13 FF"),  # allocator MAC missing
        ("0A 4B 03 01 01 0A 00", "0A 94 15 FF"),  # too much data
        ("0A 4B 03 02 01 0A", "0A 94 16 FF"),  # instance 2 does not exist
        ("0A 4B 04 01 01 0A", "0A 94 16 FF"),  # not the DeviceNet object
        (
            "0A 0E 01 01 01",
            "0A 94 02 03",
        ),  # Get on the unconnected port: invalid unconnected request
        ("0A 4B 03", "0A 94 13 FF"),
    ],
)
def test_allocation_errors(rig, request_, reply):
    assert rig.send("44E " + request_) == ["44B " + reply]
    assert rig.slave.allocation_choice == 0


def test_second_master_is_refused_and_double_allocation_is_already_in_state(rig):
    assert rig.allocate(0x03) == "44B 0A CB 00"
    assert rig.send("44E 0B 4B 03 01 01 0B") == ["44B 0B 94 0C 01"]
    assert rig.allocate(0x03) == "44B 0A 94 0B 02"
    assert rig.allocate(0x04) == "44B 0A CB 00"  # strobe added to the held explicit
    assert rig.slave.allocation_choice == 0x07


def test_release_parts_then_all(rig):
    rig.allocate(0x07)
    assert rig.send("44E 0A 4C 03 01 04") == ["44B 0A CC"]
    assert rig.slave.allocation_choice == 0x03
    assert rig.send("44E 0A 4C 03 01 04") == ["44B 0A 94 0B 02"]  # not allocated any more
    assert rig.send("44E 0A 4C 03 01 00") == ["44B 0A 94 09 02"]
    assert rig.send("44E 0A 4C 03 01 03") == ["44B 0A CC"]  # DV-8 style
    assert rig.slave.master_mac == 0xFF and rig.slave.allocation_choice == 0
    assert rig.send("44C 0A 0E 01 01 01") == []  # no explicit connection: not answered
    assert rig.send("44E 0B 4B 03 01 01 0B") == ["44B 0B CB 00"]  # free for another master


def test_malformed_unconnected_frames_are_dropped(rig):
    for text in ("44E", "44E 0A", "44E 8A 4B 03 01 01 0A", "44E 0A CB 00"):
        assert rig.send(text) == []
    assert rig.slave.counters["rx_malformed"] == 4
