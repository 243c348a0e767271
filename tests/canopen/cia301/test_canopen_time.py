"""TIME consumer 0x1012: sans-I/O, fake clock, byte-exact frames."""

from datetime import UTC, datetime, timedelta, timezone

import pytest
from canopen_rig import Rig, seed_node

from fieldgate.plugins.canopen.cia301.timestamp import decode_time_of_day, encode_time_of_day

UTC = UTC
NOON_2000 = (
    "00 2E 93 02 D4 16"  # 43 200 000 ms, day 5844 (16 years, 4 of them leap): 2000-01-01 12:00 UTC
)


@pytest.fixture
def rig():
    return Rig(seed_node(1))


def time_of(r: Rig):
    return r.node.service("time").last


def test_default_cob_id_consumes_on_0x100(rig):
    assert rig.sdo("40 12 10 00 00 00 00 00") == "43 12 10 00 00 01 00 80"
    assert time_of(rig) is None
    assert rig.send("100 " + NOON_2000) == []
    assert time_of(rig) == datetime(2000, 1, 1, 12, 0, tzinfo=UTC)
    assert rig.send("100 E8 03 00 F0 01 00") == []  # reserved top 4 bits ignored: 1000 ms, day 1
    assert time_of(rig) == datetime(1984, 1, 2, 0, 0, 1, tzinfo=UTC)
    assert rig.node.status()["services"]["time"] == {
        "received": 2,
        "consuming": True,
        "last": datetime(1984, 1, 2, 0, 0, 1, tzinfo=UTC),
    }


@pytest.mark.parametrize(
    "text, counter",
    [
        ("100 00 2E 93 02 D4", "bad_length"),
        ("100 00 2E 93 02 D4 16 00", "bad_length"),
        ("100", "bad_length"),
        ("100 RTR", "rtr_dropped"),
        ("100 00 5C 26 05 00 00", "bad_value"),  # 86 400 000 ms: not within a day
    ],
)
def test_malformed_time_is_counted_and_dropped(rig, text, counter):
    rig.send("100 " + NOON_2000)
    assert rig.send(text) == []
    time = rig.node.service("time")
    assert time.counters[counter] == 1 and time.counters["received"] == 1
    assert time.last == datetime(2000, 1, 1, 12, 0, tzinfo=UTC)
    assert rig.node.emcy.status()["active"] == []  # no EMCY for a bad TIME


def test_not_consumed_in_stopped(rig):
    rig.send("000 02 01")
    rig.send("100 " + NOON_2000)
    assert time_of(rig) is None
    rig.send("000 01 01")
    rig.send("100 " + NOON_2000)
    assert time_of(rig) == datetime(2000, 1, 1, 12, 0, tzinfo=UTC)


@pytest.mark.parametrize(
    "value, answer",
    [
        ("00 01 00 C0", "80 12 10 00 30 00 09 06"),  # produce bit: not supported
        ("00 01 00 40", "80 12 10 00 30 00 09 06"),
        ("00 01 00 A0", "80 12 10 00 30 00 09 06"),  # 29-bit frame
        (
            "90 01 00 80",
            "80 12 10 00 30 00 09 06",
        ),  # new CAN-ID while consuming: clear bit 31 first
        ("01 07 00 80", "80 12 10 00 30 00 09 06"),  # restricted (0x701, heartbeat) while consumed
        ("01 07 00 00", "60 12 10 00 00 00 00 00"),  # restricted but not consumed
        ("00 01 00 00", "60 12 10 00 00 00 00 00"),  # consumption off
    ],
)
def test_cob_id_rules(rig, value, answer):
    assert rig.sdo("23 12 10 00 " + value) == answer


def test_moving_the_cob_id_through_not_consumed(rig):
    assert rig.sdo("23 12 10 00 00 01 00 00") == "60 12 10 00 00 00 00 00"
    rig.send("100 " + NOON_2000)
    assert time_of(rig) is None and rig.node.counters["ignored"] == 1
    assert (
        rig.sdo("23 12 10 00 20 01 00 80") == "80 12 10 00 30 00 09 06"
    )  # 0x120 restricted while consumed
    assert rig.sdo("23 12 10 00 90 01 00 80") == "60 12 10 00 00 00 00 00"
    rig.send("100 " + NOON_2000)
    assert time_of(rig) is None
    rig.send("190 " + NOON_2000)
    assert time_of(rig) == datetime(2000, 1, 1, 12, 0, tzinfo=UTC)


def test_stored_cob_id_survives_reset_communication(tmp_path):
    r = Rig(seed_node(1, store_path=tmp_path / "node.json"))
    r.sdo("23 12 10 00 00 01 00 00")
    assert r.sdo("23 12 10 00 90 01 00 80") == "60 12 10 00 00 00 00 00"
    r.sdo("23 10 10 02 73 61 76 65")
    r.sdo("23 12 10 00 00 01 00 00")  # not saved
    assert r.send("000 82 01") == ["701 00"]
    assert r.sdo("40 12 10 00 00 00 00 00") == "43 12 10 00 90 01 00 80"


def test_listener_and_current_time(rig):
    seen = []
    time = rig.node.service("time")
    time.on_time(seen.append)
    time.on_time(lambda when: 1 / 0)  # a broken listener is counted, not raised
    rig.now = 10.0
    rig.send("100 " + NOON_2000)
    assert seen == [datetime(2000, 1, 1, 12, 0, tzinfo=UTC)]
    assert time.counters["listener_errors"] == 1
    assert time.current(12.5) == datetime(2000, 1, 1, 12, 0, 2, 500000, tzinfo=UTC)
    rig.advance(1.0)
    assert time.current() == datetime(2000, 1, 1, 12, 0, 1, tzinfo=UTC)  # the node's clock


def test_time_of_day_codec():
    when = datetime(2026, 11, 22, 7, 38, 54, 123000, tzinfo=UTC)
    data = encode_time_of_day(when)
    assert len(data) == 6 and decode_time_of_day(data) == when
    assert encode_time_of_day(
        datetime(2000, 1, 1, 13, 0, tzinfo=timezone(timedelta(hours=1)))
    ) == bytes.fromhex(NOON_2000)
    with pytest.raises(ValueError):
        encode_time_of_day(datetime(1983, 12, 31, tzinfo=UTC))
    with pytest.raises(ValueError):
        decode_time_of_day(b"\x00" * 7)
