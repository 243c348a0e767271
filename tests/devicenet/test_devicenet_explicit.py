"""Explicit messaging: Identity, DeviceNet, Connection and Assembly objects, errors, fragmentation."""

import pytest
from dnet_rig import Rig, show


@pytest.fixture
def rig():
    r = Rig(vendor_id=803, serial=1, product_code=1, major_revision=2, minor_revision=1)
    assert r.allocate(0x03) == "44B 0A CB 00"
    return r


def test_derived_identity_vectors(rig):
    assert rig.explicit("0E 01 01 01") == "0A 8E 23 03"  # DV-1
    assert rig.explicit("0E 01 01 02") == "0A 8E 00 00"
    assert rig.explicit("0E 01 01 03") == "0A 8E 01 00"
    assert rig.explicit("0E 01 01 04") == "0A 8E 02 01"  # DV-2
    assert rig.explicit("0E 01 01 06") == "0A 8E 01 00 00 00"  # DV-3
    assert rig.explicit("0E 03 01 01") == "0A 8E 09"  # DV-4
    assert rig.explicit("0E 05 01 09") == "0A 8E C4 09"  # DV-6
    assert rig.explicit("0E 01 01 08") == "0A 94 14 FF"  # DV-7
    assert rig.explicit("0E 01 00 02") == "0A 8E 01 00"  # class attribute: max instance


def test_product_name_is_sent_in_acknowledged_fragments(rig):
    # DV-5: "ICPDAS-I7241D" (13 characters) makes a 16-byte reply
    assert rig.send("44C 0A 0E 01 01 07") == ["44B 8A 00 8E 0D 49 43 50 44"]
    assert rig.send("44C 8A C0 00") == ["44B 8A 41 41 53 2D 49 37 32"]
    assert rig.send("44C 8A C0 00") == []  # a stale ack: ignored
    assert rig.send("44C 8A C1 00") == ["44B 8A 82 34 31 44"]
    assert rig.send("44C 8A C2 00") == []
    assert rig.slave.outgoing is None


def test_unacknowledged_fragment_is_repeated_then_abandoned(rig):
    first = rig.send("44C 0A 0E 01 01 07")
    assert rig.advance(1.0) == first
    assert rig.advance(1.0) == first
    assert rig.advance(1.0) == []
    assert rig.slave.counters["tx_fragments_abandoned"] == 1


@pytest.mark.parametrize(
    "body, reply",
    [
        ("4B 01 01 01", "0A 94 08 FF"),  # Allocate on Identity: service not supported
        (
            "01 01 00",
            "0A 94 08 FF",
        ),  # Get_Attributes_All on the Identity class: not offered (instance 1 is)
        ("0E 01 01", "0A 94 13 FF"),  # attribute missing
        ("0E 01", "0A 94 13 FF"),
        ("0E 01 01 01 00", "0A 94 15 FF"),  # Get with data
        ("0E 01 02 01", "0A 94 16 FF"),  # Identity instance 2
        ("0E 66 01 01", "0A 94 16 FF"),  # no such class
        ("10 01 01 01 00 00", "0A 94 0E FF"),  # vendor id is not settable
        ("10 03 01 01 40", "0A 94 09 FF"),  # MAC 64
        ("10 03 01 02 03", "0A 94 09 FF"),  # baud code 3
        ("10 03 01 05 00 00", "0A 94 0E FF"),  # allocation info is Get only
        ("10 05 02 09 0A", "0A 94 13 FF"),  # EPR needs 2 bytes
        ("0E 05 03 01", "0A 94 16 FF"),  # strobe connection not allocated
        ("0E 05 01 0A", "0A 94 14 FF"),
        ("10 05 01 0C 07", "0A 94 09 FF"),  # watchdog action 7
    ],
)
def test_error_responses(rig, body, reply):
    assert rig.explicit(body) == reply


def test_strict_length_mode_refuses_trailing_bytes():
    strict = Rig(tolerate_trailing_bytes=False)
    strict.allocate(0x01)
    assert strict.explicit("10 01 01 0A 02 00") == "0A 94 15 FF"
    assert strict.explicit("10 01 01 0A 02") == "0A 90"


def test_seed_epr_is_rounded_up_and_establishes_the_poll_connection(rig):
    assert rig.explicit("10 05 02 09 0A 0E") == "0A 90 10 0E"  # TV-03 / TV-04
    assert rig.explicit("0E 05 02 01") == "0A 8E 03"
    assert rig.explicit("0E 05 02 09") == "0A 8E 10 0E"
    assert rig.explicit("0E 05 02 04") == "0A 8E C9 03"  # produced id 0x3C9
    assert rig.explicit("0E 05 02 05") == "0A 8E 4D 04"  # consumed id 0x44D
    assert rig.explicit("0E 05 02 07") == "0A 8E 02 00"  # 16 DI = 2 bytes
    assert rig.explicit("0E 05 02 08") == "0A 8E 02 00"  # 16 DO = 2 bytes


def test_explicit_watchdog_deletes_the_connection():
    rig = Rig()
    rig.allocate(0x01)
    rig.advance(9.9)
    assert rig.explicit("0E 01 01 01") == "0A 8E 23 03"  # kicks the 4 x 2500 ms watchdog
    rig.advance(9.9)
    assert rig.slave.connections[1].established
    rig.advance(0.2)
    assert not rig.slave.connections[1].exists and rig.slave.master_mac == 0xFF
    assert rig.send("44C 0A 0E 01 01 01") == []
    assert rig.master_events == []  # no I/O connection was running


def test_fragmented_set_request_is_acknowledged_then_served():
    from dnet_rig import image_with

    from fieldgate.image import Kind

    rig = Rig(image_with([(1, {Kind.AO: 4})]))  # assembly 0x64: 8 bytes of AO
    rig.allocate(0x01)
    # Set Assembly 0x64 attr 3 = 01 00 02 00 03 00 04 00 in three fragments (TV-55..60 framing)
    assert rig.send("44C 8A 00 10 04 64 03 01 00") == ["44B 8A C0 00"]
    assert rig.send("44C 8A 00 10 04 64 03 01 00") == ["44B 8A C0 00"]  # first again: restart
    assert rig.send("44C 8A 41 02 00 03 00 04 00") == ["44B 8A C1 00"]
    assert rig.send("44C 8A 41 02 00 03 00 04 00") == ["44B 8A C1 00"]  # duplicate: re-acked only
    assert rig.send("44C 8A 82") == ["44B 8A C2 00", "44B 0A 90"]
    assert [rig.image.value(f"io/m1/ao{i}") for i in range(4)] == [1, 2, 3, 4]
    assert rig.explicit("0E 04 64 03") != ""  # 10-byte reply: fragmented, first fragment shown
    assert rig.send("44C 8A C5 00") == []  # out of sequence ack is ignored
    assert rig.slave.counters["rx_unexpected_acks"] == 1
    assert rig.send("44C 8A 45 01 02") == []  # middle fragment without a first: dropped
    assert rig.slave.counters["rx_fragments_dropped"] == 1


def test_wrong_assembly_sizes_and_input_assembly_set(rig):
    assert rig.explicit("0E 04 64 03") == "0A 8E 00 00"  # DO assembly 0x64 (2 bytes)
    assert rig.explicit("0E 04 65 03") == "0A 8E 00 00"  # DI assembly 0x65
    assert rig.explicit("10 04 64 03 01") == "0A 94 13 FF"
    assert rig.explicit("10 04 64 03 01 02 03") == "0A 94 15 FF"
    assert rig.explicit("10 04 65 03 01 02") == "0A 94 0E FF"
    assert rig.explicit("10 04 64 03 05 80") == "0A 90"
    assert [rig.image.value(f"io/m1/do{i}") for i in (0, 1, 2, 15)] == [True, False, True, True]
    assert rig.explicit("0E 04 64 03") == "0A 8E 05 80"
    assert rig.explicit("0E 04 00 02") == "0A 8E 65 00"


def test_seed_mac_change(rig):
    assert rig.send("44C 0A 10 03 01 01 03 0E") == [  # TV-23..27, to MAC 3
        "44B 0A 90",
        "44B 0A CE 03 00 01 00 04 00",
        "41F 00 23 03 01 00 00 00",
    ]
    assert rig.slave.mac_id == 3 and rig.slave.state == "dup-mac-check"
    assert rig.advance(1.0) == ["41F 00 23 03 01 00 00 00"]
    rig.advance(1.0)
    assert rig.send("41E 0A 4B 03 01 01 0A") == ["41B 0A CB 00"]
    assert rig.send("44E 0A 4B 03 01 01 0A") == []


def test_seed_baud_change_waits_for_reset(rig):
    switched = []
    rig.slave.on_bit_timing(lambda rate, delay: switched.append(rate))
    assert rig.explicit("10 03 01 02 01 00") == "0A 90"  # TV-29 / TV-30
    assert rig.explicit("0E 03 01 02") == "0A 8E 01"
    assert switched == [] and rig.slave.bitrate == 125_000
    assert rig.send("44C 0A 05 01 01 00") == [  # TV-32..34: answered at the old rate
        "44B 0A 85",
        "44B 0A CE 01 00 01 00 04 00",
    ]
    assert switched == [250_000] and rig.slave.bitrate == 250_000
    # TV-35, the duplicate MAC ID check, once the adapter says the bus runs at the new rate
    assert rig.advance(0.5) == []
    rig.slave.bit_timing_done(True, rig.now)
    assert show(rig.slave.flush()) == ["44F 00 23 03 01 00 00 00"]
    assert rig.slave.allocation_choice == 0 and rig.slave.master_mac == 0xFF


def test_seed_heartbeat(rig):
    assert rig.explicit("10 01 01 0A 02 00") == "0A 90"  # TV-37
    assert rig.explicit("0E 01 01 0A") == "0A 8E 02"
    assert rig.advance(2.0) == ["44B 0A CD 01 00 03 00 00 00"]  # TV-38
    assert rig.advance(2.0) == ["44B 0A CD 01 00 03 00 00 00"]
    rig.explicit("10 01 01 0A 00")
    assert rig.advance(6.0) == []


def test_garbage_never_raises(rig):
    import random

    rnd = random.Random(7)
    for _ in range(3000):
        can_id = rnd.choice([0x44C, 0x44D, 0x44E, 0x44F, 0x44A, 0x450, rnd.randrange(0x800)])
        data = bytes(rnd.randrange(256) for _ in range(rnd.randrange(9)))
        rig.slave.receive(
            __import__("fieldgate.can.frame", fromlist=["Frame"]).Frame(can_id, data), rig.now
        )
    assert rig.slave.counters["rx_internal_errors"] == 0


def test_identity_status_shows_ownership_and_module_faults():
    rig = Rig()
    rig.allocate(0x01)
    assert rig.explicit("0E 01 01 05") == "0A 8E 01 00"
    rig.slave.module_fault = True  # the front sets it while a served module is offline
    assert rig.explicit("0E 01 01 05") == "0A 8E 01 01"  # bit 8: minor recoverable fault


def test_application_object_serves_each_module():
    from dnet_rig import image_with

    from fieldgate.image import Kind

    image = image_with(
        [(1, {Kind.DI: 8, Kind.DO: 8}), (2, {Kind.AI: 2}), (4, {Kind.DO: 2, Kind.AO: 1})]
    )
    rig = Rig(image)
    rig.slave.module_errors = lambda back, address: 7 if (back, address) == ("io", 2) else 0
    rig.allocate(0x01)
    assert rig.explicit("0E 64 00 02") == "0A 8E 03 00"  # three modules
    assert rig.explicit("0E 64 03 02") == "0A 8E 04"  # instance 3 = module 4
    assert rig.explicit("0E 64 02 07") == "0A 8E 07 00 00 00"
    assert [rig.explicit(f"0E 64 02 {a:02X}") for a in (0x0C, 0x0D, 0x0E, 0x0F)] == [
        "0A 8E 00",
        "0A 8E 00",
        "0A 8E 00",
        "0A 8E 04",
    ]
    assert [rig.explicit(f"0E 64 03 {a:02X}") for a in (0x10, 0x11)] == ["0A 8E 02", "0A 8E 01"]
    image.update_input("io/m2/ai1", -2)
    assert rig.explicit("0E 64 02 17") == "0A 8E 00 00 FE FF"
    assert rig.explicit("10 64 03 14 03") == "0A 90"
    assert rig.explicit("10 64 03 15 E8 03") == "0A 90"
    assert image.value("io/m4/do1") is True and image.value("io/m4/ao0") == 1000
    assert rig.explicit("10 64 01 16 FF") == "0A 94 0E FF"  # DI data is Get only
    assert rig.explicit("10 64 03 14 03 00") == "0A 94 15 FF"
    assert rig.explicit("0E 64 01 15") == "0A 8E"  # module 1 has no AO: empty data
    assert rig.explicit("10 64 01 15") == "0A 90" and rig.explicit("10 64 01 15 00") == (
        "0A 94 15 FF"
    )
    assert rig.explicit("0E 64 01 08") == "0A 8E 00"  # no DCON watchdog here: off
    assert rig.explicit("0E 64 01 01") == "0A 8E 00 00 00 00"  # no module identity here: 0
    assert rig.explicit("0E 64 04 02") == "0A 94 16 FF"


def test_a_fragmented_answer_is_not_resent_after_its_connection_is_released():
    rig = Rig()
    assert rig.send("44E 0A 4B 03 01 01 0A") == ["44B 0A CB 00"]  # allocate explicit
    assert rig.send("44C 0A 0E 01 01 07") == [
        "44B 8A 00 8E 0D 49 43 50 44"
    ]  # product name: first fragment
    assert rig.send("44E 0A 4C 03 01 01") == [
        "44B 0A CC"
    ]  # released before the fragment was acknowledged
    assert rig.advance(1.0) == [] and rig.advance(2.0) == []  # nothing on a connection that is gone
    assert rig.slave.counters["tx_fragments_dropped"] == 1


def test_a_baud_switch_the_adapter_never_confirms_still_checks_the_mac(rig):
    """The duplicate MAC ID check waits for the adapter's switch, at most 5 s."""
    rig.slave.on_bit_timing(lambda rate, delay: None)
    assert rig.explicit("10 03 01 02 02 00") == "0A 90"
    rig.send("44C 0A 05 01 01 00")
    assert rig.advance(4.9) == []
    assert rig.advance(0.2) == ["44F 00 23 03 01 00 00 00"]
