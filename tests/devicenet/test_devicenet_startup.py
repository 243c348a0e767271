"""Duplicate MAC ID check at start, answering other nodes' checks, and the silent comm-fault state."""

from dnet_rig import Rig

REQUEST = "44F 00 23 03 01 00 00 00"  # TV-26: port 0, vendor 803, serial 1


def test_two_requests_one_second_apart_then_online():
    rig = Rig(online=False, vendor_id=803, serial=1)
    assert rig.boot == [REQUEST]
    assert rig.slave.state == "dup-mac-check"
    assert rig.send("44E 0A 4B 03 01 01 0A") == []  # not online yet: silent
    assert rig.advance(0.99) == []
    assert rig.advance(0.01) == [REQUEST]
    assert rig.advance(0.99) == [] and rig.slave.state == "dup-mac-check"
    rig.advance(0.01)
    assert rig.slave.state == "online"
    assert rig.allocate(0x01) == "44B 0A CB 00"


def test_a_response_during_the_check_is_a_duplicate():
    rig = Rig(online=False)
    assert rig.send("44F 80 34 12 07 00 00 00") == []
    assert rig.slave.state == "comm-fault"
    assert rig.faults and "duplicate MAC ID 9" in rig.faults[0] and "vendor 4660" in rig.faults[0]
    assert rig.advance(5.0) == []  # never goes online, never sends again
    assert rig.send("44E 0A 4B 03 01 01 0A") == []
    assert rig.slave.counters["rx_while_comm-fault"] == 1


def test_another_node_checking_the_same_mac_is_a_duplicate():
    rig = Rig(online=False)
    rig.advance(1.0)
    rig.send("44F 00 34 12 07 00 00 00")
    assert rig.slave.state == "comm-fault"


def test_online_slave_answers_a_check_of_its_mac_and_ignores_others():
    rig = Rig(vendor_id=803, serial=0x01020304)
    assert rig.send("44F 00 34 12 07 00 00 00") == ["44F 80 23 03 04 03 02 01"]
    assert rig.send("44F 80 34 12 07 00 00 00") == []  # a response while online: ignored
    assert rig.send("457 00 34 12 07 00 00 00") == []  # another MAC's check
    assert rig.send("44F 00 01") == []  # malformed: counted
    assert rig.slave.state == "online" and rig.slave.counters["rx_malformed"] == 1


def test_seed_offline_connection_set_identifies_and_moves_a_faulted_node():
    rig = Rig(online=False, vendor_id=803, serial=1)
    rig.send("44F 80 23 03 02 00 00 00")
    assert rig.slave.state == "comm-fault"
    assert rig.send("7ED 3F 4B 02") == ["7EC 00 23 03 01 00 00 00"]  # TV-39 / TV-40
    assert rig.send("7ED 07 4D 23 03 02 00 00 00") == []  # another device's serial: not us
    assert rig.send("7ED 07 4D 23 03 01 00 00 00") == ["43F 00 23 03 01 00 00 00"]  # TV-41 / TV-42
    assert rig.slave.mac_id == 7 and rig.slave.state == "dup-mac-check"
    assert rig.advance(1.0) == ["43F 00 23 03 01 00 00 00"]
    rig.advance(1.0)
    assert rig.slave.state == "online"
    assert rig.send("7ED 3F 4B 02") == []  # only faulted nodes answer


def test_the_identify_request_matches_a_mac_and_staggers_the_answers_by_serial():
    """Byte 0 of the identify request: bit 6 set asks only the faulted node at MAC ``value``;
    byte 2 names the serial number byte whose value is the answer's delay in ms."""
    rig = Rig(online=False, vendor_id=803, serial=0x0A1E3205)
    rig.send("44F 80 23 03 02 00 00 00")
    assert rig.slave.state == "comm-fault"
    assert rig.send("7ED 48 4B") == []  # match MAC 8: not us (9)
    assert rig.send("7ED 49 4B") == ["7EC 00 23 03 05 32 1E 0A"]  # match MAC 9, no delay
    assert rig.send("7ED 3F 4B 01") == []  # serial byte 1 = 0x32: 50 ms
    assert rig.advance(0.049) == []
    assert rig.advance(0.002) == ["7EC 00 23 03 05 32 1E 0A"]
    assert rig.send("7ED 3F 4B 06") == [] and rig.advance(0.031) == [
        "7EC 00 23 03 05 32 1E 0A"
    ]  # offset 6 = byte 2 (modulo 4): 0x1E = 30 ms
    assert rig.send("7ED BF 4B 02") == [] and rig.advance(1.0) == []  # bit 7 set: not a request
    assert rig.slave.counters["rx_offline_ignored"] == 2
    assert rig.send("7EE 0A 00") == [] and rig.send("7EF 0A 00") == []  # ownership: among tools


def test_online_node_ignores_the_offline_connection_set():
    rig = Rig(serial=1, vendor_id=803)
    assert rig.send("7ED 07 4D 23 03 01 00 00 00") == [] and rig.slave.mac_id == 9
    assert rig.send("7ED 3F 4B 02") == []


def test_offline_connection_set_frames_not_for_us_are_counted():
    """0x7ED while we are not faulted, or naming another device: counted, never silently dropped."""
    rig = Rig(serial=1, vendor_id=803)
    rig.send("7ED 07 4D 23 03 01 00 00 00")
    rig.send("7ED 3F 4B 02")
    assert rig.slave.counters["rx_offline_not_faulted"] == 2
    assert rig.slave.status()["rx_offline_not_faulted"] == 2  # in the front's status
    rig = Rig(online=False, vendor_id=803, serial=1)
    rig.send("44F 80 23 03 02 00 00 00")
    assert rig.slave.state == "comm-fault"
    rig.send("7ED 07 4D 23 03 02 00 00 00")  # another device's serial
    assert rig.slave.counters["rx_offline_ignored"] == 1
    assert rig.slave.counters["rx_offline_not_faulted"] == 0
