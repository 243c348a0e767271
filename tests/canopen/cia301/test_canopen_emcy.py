"""EMCY producer: TV-19 history and register, inhibit time, COB-ID valid bit, clearing."""

import pytest
from canopen_rig import Rig, seed_node


@pytest.fixture
def rig():
    return Rig(seed_node(1))


def emit(rig, fn, *args):
    fn(*args)
    return [str(f) for f in rig.node.flush()]


def test_tv19_pdo_length_error_history_and_register(rig):
    emcy = rig.node.emcy
    assert emit(rig, emcy.raise_error, 0x8210, 0x11, b"\x09") == ["081 [8] 10 82 11 09 00 00 00 00"]
    assert rig.sdo("40 03 10 01 00 00 00 00") == "43 03 10 01 10 82 09 00"
    assert rig.sdo("40 01 10 00 00 00 00 00") == "4F 01 10 00 11 00 00 00"
    assert emit(rig, emcy.raise_error, 0x8210, 0x11, b"\x09") == []  # not per repetition
    assert emit(rig, emcy.clear_error, 0x8210) == ["081 [8] 00 00 00 00 00 00 00 00"]
    assert rig.sdo("40 03 10 01 00 00 00 00") == "43 03 10 01 00 00 00 00"
    assert rig.sdo("40 03 10 02 00 00 00 00") == "43 03 10 02 10 82 09 00"
    assert rig.sdo("40 01 10 00 00 00 00 00") == "4F 01 10 00 00 00 00 00"
    assert rig.sdo("40 03 10 00 00 00 00 00") == "4F 03 10 00 02 00 00 00"
    assert rig.sdo("40 03 10 03 00 00 00 00") == "80 03 10 03 24 00 00 08"  # no data yet


def test_module_failure_code_and_partial_clear(rig):
    emcy = rig.node.emcy
    assert emit(rig, emcy.raise_error, 0xFF00, 0x81, bytes([0x0B, 5])) == [
        "081 [8] 00 FF 81 0B 05 00 00 00"
    ]
    assert emit(rig, emcy.raise_error, 0xFF00, 0x81, bytes([0x0B, 6])) == [
        "081 [8] 00 FF 81 0B 06 00 00 00"
    ]
    assert rig.sdo("40 03 10 01 00 00 00 00") == "43 03 10 01 00 FF 0B 06"
    # one clears, the other remains: reset code with the remaining register
    assert emit(rig, emcy.clear_error, 0xFF00, bytes([0x0B, 5])) == [
        "081 [8] 00 00 81 00 00 00 00 00"
    ]
    assert emit(rig, emcy.clear_error, 0xFF00, bytes([0x0B, 6])) == [
        "081 [8] 00 00 00 00 00 00 00 00"
    ]


def test_history_depth_newest_first_and_clear(rig):
    emcy = rig.node.emcy
    for i in range(7):
        emcy.raise_error(0x1000 + i, 0x01)
    rig.node.flush()
    assert rig.sdo("40 03 10 00 00 00 00 00") == "4F 03 10 00 05 00 00 00"
    assert rig.sdo("40 03 10 01 00 00 00 00") == "43 03 10 01 06 10 00 00"
    assert rig.sdo("40 03 10 05 00 00 00 00") == "43 03 10 05 02 10 00 00"
    assert rig.sdo("40 03 10 06 00 00 00 00") == "80 03 10 06 11 00 09 06"
    assert rig.sdo("2F 03 10 00 00 00 00 00") == "60 03 10 00 00 00 00 00"
    assert rig.sdo("40 03 10 00 00 00 00 00") == "4F 03 10 00 00 00 00 00"
    assert rig.sdo("23 03 10 01 00 00 00 00") == "80 03 10 01 02 00 01 06"


def test_configurable_depth():
    rig = Rig(seed_node(1, emcy_history=8))
    for i in range(10):
        rig.node.emcy.raise_error(0x1000 + i)
    assert len(rig.node.flush()) == 10
    assert rig.sdo("40 03 10 00 00 00 00 00") == "4F 03 10 00 08 00 00 00"
    assert rig.sdo("40 03 10 08 00 00 00 00") == "43 03 10 08 02 10 00 00"


def test_inhibit_time_in_100us_units(rig):
    assert rig.sdo("2B 15 10 00 E8 03 00 00") == "60 15 10 00 00 00 00 00"  # 1000 x 100 us = 100 ms
    emcy = rig.node.emcy
    assert len(emit(rig, emcy.raise_error, 0x1000)) == 1
    assert emit(rig, emcy.raise_error, 0x5000) == []  # inhibited, queued
    assert rig.advance(0.099) == []
    assert rig.advance(0.002) == ["081 00 50 01 00 00 00 00 00"]


def test_cob_id_valid_bit_and_change_rules(rig):
    assert rig.sdo("23 14 10 00 81 00 00 80") == "60 14 10 00 00 00 00 00"
    assert emit(rig, rig.node.emcy.raise_error, 0x1000) == []
    assert rig.sdo("23 14 10 00 90 00 00 00") == "60 14 10 00 00 00 00 00"
    assert emit(rig, rig.node.emcy.raise_error, 0x5000) == ["090 [8] 00 50 01 00 00 00 00 00"]
    # changing the ID while valid is refused; 29-bit is refused
    assert rig.sdo("23 14 10 00 91 00 00 00") == "80 14 10 00 30 00 09 06"
    assert rig.sdo("23 14 10 00 90 00 00 20") == "80 14 10 00 30 00 09 06"


def test_no_emcy_in_stopped_but_history_kept(rig):
    rig.send("000 02 01")
    assert emit(rig, rig.node.emcy.raise_error, 0x1000) == []
    rig.send("000 80 01")
    assert rig.sdo("40 03 10 01 00 00 00 00") == "43 03 10 01 00 10 00 00"


def test_emcy_on_nmt_reset_option():
    plain = Rig(seed_node(1))
    assert plain.send("000 82 01") == ["701 00"]
    icpdas = Rig(seed_node(1, emcy_on_nmt_reset=True))
    assert icpdas.send("000 81 00") == ["081 00 FF 80 0A 00 00 00 00", "701 00"]
    assert icpdas.sdo("40 01 10 00 00 00 00 00") == "4F 01 10 00 00 00 00 00"  # not an active error
    assert icpdas.sdo("40 03 10 01 00 00 00 00") == "43 03 10 01 00 FF 0A 00"


@pytest.mark.parametrize(
    "can_id", [0x000, 0x07F, 0x101, 0x180, 0x581, 0x601, 0x6E0, 0x701, 0x77F, 0x780, 0x7FF]
)
def test_cob_id_restricted_can_ids_are_refused(rig, can_id):
    assert (
        rig.sdo("23 14 10 00 81 00 00 80") == "60 14 10 00 00 00 00 00"
    )  # EMCY off: the ID may change
    assert (
        rig.sdo("23 14 10 00 " + can_id.to_bytes(4, "little").hex(" ")) == "80 14 10 00 30 00 09 06"
    )
    assert rig.node.od.get(0x1014) == 0x80000081
    assert (
        rig.sdo("23 14 10 00 " + (can_id | 1 << 31).to_bytes(4, "little").hex(" "))
        == "60 14 10 00 00 00 00 00"
    )  # not in use
    assert rig.sdo("23 14 10 00 00 01 00 00") == "60 14 10 00 00 00 00 00"  # 0x100: allowed
