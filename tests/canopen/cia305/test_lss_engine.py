"""LSS slave engine (CiA 305), sans-I/O, byte for byte (seed-000 TV-21), fake clock."""

from __future__ import annotations

import json
import random
import struct

import pytest

from fieldgate.plugins.canopen.cia305.lss import (
    BIT_TIMING_TABLES,
    LssAddress,
    LssSlave,
    LssState,
    LssStore,
    ResetCommunication,
    StoredLss,
    SwitchBitRate,
)

ADDRESS = LssAddress(vendor=0x00000123, product=0x7232, revision=0x00010002, serial=0x0000BEEF)


def req(hexbytes: str) -> bytes:
    return bytes.fromhex(hexbytes)


def frame(hexbytes: str) -> tuple[int, bytes]:
    return (0x7E4, bytes.fromhex(hexbytes))


def u32(value: int) -> str:
    return struct.pack("<I", value).hex()


def send(slave: LssSlave, hexbytes: str, now: float = 0.0) -> list:
    return slave.on_frame(0x7E5, req(hexbytes), now)


def configuring(**kw) -> LssSlave:
    slave = LssSlave(ADDRESS, **kw)
    assert send(slave, "04 01 00 00 00 00 00 00") == []
    assert slave.state == LssState.CONFIGURATION
    return slave


# -- switch state --------------------------------------------------------------------


def test_tv21_switch_global_has_no_answer_and_changes_state():
    slave = LssSlave(ADDRESS, node_id=1)
    assert send(slave, "04 01 00 00 00 00 00 00") == []
    assert slave.state == LssState.CONFIGURATION
    assert send(slave, "04 00 00 00 00 00 00 00") == []
    assert slave.state == LssState.WAITING


def test_switch_global_with_unknown_mode_is_dropped():
    slave = LssSlave(ADDRESS, node_id=1)
    assert send(slave, "04 02 00 00 00 00 00 00") == []
    assert slave.state == LssState.WAITING
    assert slave.counters.dropped_malformed == 1


def selective(
    slave,
    vendor=ADDRESS.vendor,
    product=ADDRESS.product,
    revision=ADDRESS.revision,
    serial=ADDRESS.serial,
):
    out = []
    for cs, value in ((0x40, vendor), (0x41, product), (0x42, revision), (0x43, serial)):
        out += send(slave, f"{cs:02x} {u32(value)} 00 00 00")
    return out


def test_tv21_switch_selective_answers_44_and_enters_configuration():
    slave = LssSlave(ADDRESS, node_id=3)
    assert selective(slave) == [frame("44 00 00 00 00 00 00 00")]
    assert slave.state == LssState.CONFIGURATION


@pytest.mark.parametrize("field", ["vendor", "product", "revision", "serial"])
def test_switch_selective_with_one_wrong_part_stays_silent(field):
    slave = LssSlave(ADDRESS, node_id=3)
    assert selective(slave, **{field: getattr(ADDRESS, field) + 1}) == []
    assert slave.state == LssState.WAITING


def test_switch_selective_out_of_order_is_not_a_match():
    slave = LssSlave(ADDRESS, node_id=3)
    send(slave, f"40 {u32(ADDRESS.vendor)} 00 00 00")
    send(slave, f"42 {u32(ADDRESS.revision)} 00 00 00")  # product skipped
    send(slave, f"41 {u32(ADDRESS.product)} 00 00 00")
    assert send(slave, f"43 {u32(ADDRESS.serial)} 00 00 00") == []
    assert slave.state == LssState.WAITING
    assert selective(slave) == [frame("44 00 00 00 00 00 00 00")]  # a clean sequence still works


# -- configure node-ID ---------------------------------------------------------------


def test_tv21_configure_node_id_ok():
    slave = configuring(node_id=1)
    assert send(slave, "11 0A 00 00 00 00 00 00") == [frame("11 00 00 00 00 00 00 00")]
    assert slave.pending_node_id == 0x0A
    assert slave.active_node_id == 1  # seed-000: inquire returns the original until reset


@pytest.mark.parametrize("node_id", [0x00, 0x80, 0xFE])
def test_tv21_configure_node_id_out_of_range_answers_error_1(node_id):
    slave = configuring(node_id=1)
    assert send(slave, f"11 {node_id:02x} 00 00 00 00 00 00") == [frame("11 01 00 00 00 00 00 00")]
    assert slave.pending_node_id == 1


def test_configure_node_id_ff_unconfigures_at_next_reset():
    slave = configuring(node_id=7)
    assert send(slave, "11 FF 00 00 00 00 00 00") == [frame("11 00 00 00 00 00 00 00")]
    assert slave.configured
    assert slave.node_id_for_reset() == 0xFF
    assert not slave.configured


def test_configuration_services_are_ignored_in_waiting_state():
    slave = LssSlave(ADDRESS, node_id=1)
    for cs in ("11 05", "13 00 03", "17 00", "5A 00", "5E 00", "15 64"):
        assert send(slave, cs + " 00" * (8 - len(cs.split()))) == []
    assert slave.pending_node_id == 1 and slave.pending_bitrate is None
    assert slave.counters.ignored_in_state == 6


def test_unconfigured_node_resets_communication_with_new_id_on_switch_to_waiting():
    slave = LssSlave(ADDRESS)  # no node-ID: 0xFF
    assert not slave.configured
    send(slave, "04 01 00 00 00 00 00 00")
    assert send(slave, "5E 00 00 00 00 00 00 00") == [frame("5E FF 00 00 00 00 00 00")]
    send(slave, "11 05 00 00 00 00 00 00")
    assert slave.take_actions() == []  # nothing until the master leaves configuration
    send(slave, "04 00 00 00 00 00 00 00")
    assert slave.take_actions() == [ResetCommunication(5)]
    assert slave.configured and slave.active_node_id == 5
    assert slave.take_actions() == []


def test_configured_node_keeps_its_id_until_reset_communication():
    slave = configuring(node_id=9)
    send(slave, "11 05 00 00 00 00 00 00")
    send(slave, "04 00 00 00 00 00 00 00")
    assert slave.take_actions() == []
    assert slave.active_node_id == 9
    assert slave.node_id_for_reset() == 5
    assert slave.active_node_id == 5


# -- bit timing ----------------------------------------------------------------------


def test_tv21_configure_bit_timing_with_the_i7232d_table():
    slave = configuring(node_id=1, table="i7232d")
    assert send(slave, "13 00 03 00 00 00 00 00") == [frame("13 00 00 00 00 00 00 00")]
    assert slave.pending_bitrate == 125_000


def test_configure_bit_timing_defaults_to_the_cia_table():
    slave = configuring(node_id=1)
    assert send(slave, "13 00 03 00 00 00 00 00") == [frame("13 00 00 00 00 00 00 00")]
    assert slave.pending_bitrate == 250_000
    # The CiA 305 table is also the NA-9161's baud switch code table (seed-004 TV-27).
    assert [BIT_TIMING_TABLES["cia"][i] for i in range(9)] == [
        1_000_000,
        800_000,
        500_000,
        250_000,
        125_000,
        100_000,
        50_000,
        20_000,
        10_000,
    ]


@pytest.mark.parametrize(
    ("table", "request_hex"),
    [
        ("cia", "13 00 09"),  # auto bit rate: not offered
        ("cia", "13 01 00"),  # no user-defined tables
        ("i7232d", "13 00 08"),
    ],
)
def test_configure_bit_timing_unsupported_answers_error_1(table, request_hex):
    slave = configuring(node_id=1, table=table)
    assert send(slave, request_hex + " 00 00 00 00 00") == [frame("13 01 00 00 00 00 00 00")]
    assert slave.pending_bitrate is None


def test_unknown_table_name_is_refused():
    with pytest.raises(ValueError, match="i7232d"):
        LssSlave(ADDRESS, table="nope")


def test_tv21_activate_bit_timing_switches_after_delay_and_is_silent_twice_as_long():
    slave = configuring(node_id=1, bitrate=500_000)
    send(slave, "13 00 04 00 00 00 00 00")  # 125k
    assert send(slave, "15 64 00 00 00 00 00 00", now=10.0) == []  # 100 ms, no answer
    assert not slave.transmit_allowed(10.0)
    assert slave.next_deadline() == pytest.approx(10.1)
    assert slave.on_timer(10.05) == [] and slave.take_actions() == []
    assert send(slave, "5E 00 00 00 00 00 00 00", now=10.05) == []  # silent
    slave.on_timer(10.1)
    assert slave.take_actions() == [SwitchBitRate(125_000)]
    assert slave.bitrate == 125_000
    assert not slave.transmit_allowed(10.15)
    assert slave.next_deadline() == pytest.approx(10.2)
    slave.on_timer(10.2)
    assert slave.transmit_allowed(10.2) and slave.next_deadline() is None
    assert send(slave, "5E 00 00 00 00 00 00 00", now=10.2) == [frame("5E 01 00 00 00 00 00 00")]


# -- store ---------------------------------------------------------------------------


def test_tv21_store_configuration_persists_node_id_and_bit_rate(tmp_path):
    store = LssStore(tmp_path / "lss.json")
    slave = configuring(node_id=1, bitrate=250_000, store=store)
    send(slave, "11 0A 00 00 00 00 00 00")
    assert send(slave, "17 00 00 00 00 00 00 00") == [frame("17 00 00 00 00 00 00 00")]
    assert store.load() == StoredLss(node_id=0x0A, bitrate=250_000)
    send(slave, "13 00 02 00 00 00 00 00")
    send(slave, "17 00 00 00 00 00 00 00")
    assert store.load() == StoredLss(node_id=0x0A, bitrate=500_000)
    assert [p.name for p in tmp_path.iterdir()] == ["lss.json"]  # no temporary file left


def test_store_without_a_store_file_answers_not_supported():
    slave = configuring(node_id=1)
    assert send(slave, "17 00 00 00 00 00 00 00") == [frame("17 01 00 00 00 00 00 00")]


def test_store_that_cannot_write_answers_access_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    slave = configuring(node_id=1, store=LssStore(blocker / "lss.json"))  # parent is a file
    assert send(slave, "17 00 00 00 00 00 00 00") == [frame("17 02 00 00 00 00 00 00")]


@pytest.mark.parametrize(
    "content",
    [
        b"{not json",
        json.dumps({"format": "other", "node_id": 5, "bitrate": None}).encode(),
        json.dumps({"format": "fieldgate-lss/1", "node_id": 200, "bitrate": None}).encode(),
        json.dumps({"format": "fieldgate-lss/1", "node_id": 5, "bitrate": "fast"}).encode(),
        json.dumps([1, 2]).encode(),
    ],
)
def test_unusable_store_is_ignored_with_one_log_line(tmp_path, caplog, content):
    path = tmp_path / "lss.json"
    path.write_bytes(content)
    assert LssStore(path).load() is None
    assert len([r for r in caplog.records if "LSS store" in r.getMessage()]) == 1


def test_unreadable_store_path_is_ignored_with_one_log_line(tmp_path, caplog):
    (tmp_path / "file").write_text("x")
    assert LssStore(tmp_path / "file" / "lss.json").load() is None  # parent is a file
    assert LssStore(tmp_path).load() is None  # a directory
    assert len([r for r in caplog.records if "LSS store" in r.getMessage()]) == 2


def test_missing_store_is_simply_empty(tmp_path):
    assert LssStore(tmp_path / "none.json").load() is None


# -- inquire -------------------------------------------------------------------------


def test_tv21_inquire_identity_and_node_id():
    slave = configuring(node_id=0x21)
    assert send(slave, "5A 00 00 00 00 00 00 00") == [frame(f"5A {u32(ADDRESS.vendor)} 00 00 00")]
    assert send(slave, "5B 00 00 00 00 00 00 00") == [frame("5B 32 72 00 00 00 00 00")]
    assert send(slave, "5C 00 00 00 00 00 00 00") == [frame("5C 02 00 01 00 00 00 00")]
    assert send(slave, "5D 00 00 00 00 00 00 00") == [frame("5D EF BE 00 00 00 00 00")]
    assert send(slave, "5E 00 00 00 00 00 00 00") == [frame("5E 21 00 00 00 00 00 00")]


# -- identify ------------------------------------------------------------------------


def identify(
    slave,
    vendor=ADDRESS.vendor,
    product=ADDRESS.product,
    rev=(0, 0xFFFFFFFF),
    serial=(0, 0xFFFFFFFF),
):
    out = []
    for cs, value in (
        (0x46, vendor),
        (0x47, product),
        (0x48, rev[0]),
        (0x49, rev[1]),
        (0x4A, serial[0]),
        (0x4B, serial[1]),
    ):
        out += send(slave, f"{cs:02x} {u32(value)} 00 00 00")
    return out


@pytest.mark.parametrize(
    ("rev", "serial", "answers"),
    [
        ((0, 0xFFFFFFFF), (0, 0xFFFFFFFF), True),
        ((ADDRESS.revision, ADDRESS.revision), (ADDRESS.serial, ADDRESS.serial), True),  # inclusive
        ((ADDRESS.revision + 1, 0xFFFFFFFF), (0, 0xFFFFFFFF), False),
        ((0, ADDRESS.revision - 1), (0, 0xFFFFFFFF), False),
        ((0, 0xFFFFFFFF), (ADDRESS.serial + 1, 0xFFFFFFFF), False),
        ((0, 0xFFFFFFFF), (0, ADDRESS.serial - 1), False),
    ],
)
def test_identify_remote_slave_with_ranges(rev, serial, answers):
    for state in ("04 00", "04 01"):  # in either state
        slave = LssSlave(ADDRESS, node_id=4)
        send(slave, state + " 00 00 00 00 00 00")
        expected = [frame("4F 00 00 00 00 00 00 00")] if answers else []
        assert identify(slave, rev=rev, serial=serial) == expected


def test_identify_remote_slave_needs_exact_vendor_and_product():
    slave = LssSlave(ADDRESS, node_id=4)
    assert identify(slave, vendor=ADDRESS.vendor + 1) == []
    assert identify(slave, product=0) == []
    assert identify(slave) == [frame("4F 00 00 00 00 00 00 00")]


def test_identify_non_configured_remote_slave():
    assert send(LssSlave(ADDRESS), "4C 00 00 00 00 00 00 00") == [frame("50 00 00 00 00 00 00 00")]
    assert send(LssSlave(ADDRESS, node_id=5), "4C 00 00 00 00 00 00 00") == []


# -- fastscan ------------------------------------------------------------------------


def fastscan_master(slave: LssSlave) -> list[int] | None:
    """The CiA 305 fastscan algorithm, as canopen's LssMaster runs it."""

    def ask(id_number, bit_check, sub, next_sub) -> bool:
        data = struct.pack("<BIBBB", 0x51, id_number, bit_check, sub, next_sub)
        return slave.on_frame(0x7E5, data, 0.0) == [frame("4F 00 00 00 00 00 00 00")]

    if not ask(0, 0x80, 0, 0):
        return None
    found = [0, 0, 0, 0]
    for sub in range(4):
        for bit in range(31, -1, -1):
            if not ask(found[sub], bit, sub, sub):
                found[sub] |= 1 << bit
        if not ask(found[sub], 0, sub, (sub + 1) & 3):
            return None
    return found


def test_fastscan_finds_an_unconfigured_node_and_selects_it():
    slave = LssSlave(ADDRESS)
    assert fastscan_master(slave) == [
        ADDRESS.vendor,
        ADDRESS.product,
        ADDRESS.revision,
        ADDRESS.serial,
    ]
    assert slave.state == LssState.CONFIGURATION
    assert fastscan_master(slave) is None  # a selected node no longer takes part


def test_fastscan_is_ignored_by_a_configured_node():
    slave = LssSlave(ADDRESS, node_id=3)
    assert fastscan_master(slave) is None
    assert slave.state == LssState.WAITING


def test_fastscan_mismatch_stays_silent_and_bad_fields_are_dropped():
    slave = LssSlave(ADDRESS)
    assert send(slave, "51 00 00 00 00 80 00 00") == [frame("4F 00 00 00 00 00 00 00")]
    wrong_vendor = ADDRESS.vendor ^ 0x100
    assert slave.on_frame(0x7E5, struct.pack("<BIBBB", 0x51, wrong_vendor, 0, 0, 1), 0) == []
    assert (
        slave.on_frame(0x7E5, struct.pack("<BIBBB", 0x51, ADDRESS.product, 0, 1, 2), 0) == []
    )  # wrong sub
    before = slave.counters.dropped_malformed
    assert send(slave, "51 00 00 00 00 20 00 00") == []  # bit 32
    assert send(slave, "51 00 00 00 00 00 04 00") == []  # sub 4
    assert slave.counters.dropped_malformed == before + 2


# -- malformed input -----------------------------------------------------------------


def test_malformed_frames_are_counted_and_dropped():
    slave = configuring(node_id=1)
    assert slave.on_frame(0x7E5, req("5E 00 00 00 00 00 00"), 0) == []  # DLC 7
    assert slave.on_frame(0x7E5, req("5E 00 00 00 00 00 00 00 00"), 0) == []  # DLC 9 (FD)
    assert slave.on_frame(0x7E5, bytes(8), 0, rtr=True) == []
    assert slave.on_frame(0x7E5, req("99 00 00 00 00 00 00 00"), 0) == []  # unknown cs
    assert slave.counters.dropped_malformed == 4
    assert slave.on_frame(0x7E4, req("5E 00 00 00 00 00 00 00"), 0) == []  # not an LSS request
    assert slave.counters.received == 4 + 1  # the configuring() switch


def test_random_frames_never_raise():
    rng = random.Random(305)
    slave = LssSlave(ADDRESS)
    for n in range(20000):
        length = rng.choice((0, 1, 7, 8, 8, 8, 8))
        data = bytes(
            [
                rng.choice(
                    (
                        0x04,
                        0x11,
                        0x13,
                        0x15,
                        0x17,
                        0x40,
                        0x43,
                        0x46,
                        0x4B,
                        0x4C,
                        0x51,
                        0x5A,
                        0x5E,
                        rng.randrange(256),
                    )
                )
            ]
        )[:length]
        data += bytes(rng.randrange(256) for _ in range(length - len(data)))
        if data[:1] == b"\x15":
            data = data[:1] + b"\x00\x00" + data[3:]  # keep switch delays at zero
        for can_id, payload in slave.on_frame(0x7E5, data, n * 0.001):
            assert can_id == 0x7E4 and len(payload) == 8
        slave.take_actions()


def test_power_on_takes_node_id_and_bit_rate_from_the_store(tmp_path):
    store = LssStore(tmp_path / "lss.json")
    assert LssSlave.starting(ADDRESS, node_id=3, bitrate=125_000, store=store).active_node_id == 3
    store.save(StoredLss(node_id=0x2A, bitrate=None))
    slave = LssSlave.starting(ADDRESS, node_id=3, bitrate=125_000, store=store)
    assert (slave.active_node_id, slave.bitrate) == (0x2A, 125_000)
    store.save(StoredLss(node_id=0xFF, bitrate=1_000_000))
    slave = LssSlave.starting(ADDRESS, node_id=3, bitrate=125_000, store=store)
    assert (slave.configured, slave.bitrate) == (False, 1_000_000)
