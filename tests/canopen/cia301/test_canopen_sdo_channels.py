"""Additional SDO server channels 0x1201-0x127F: sans-I/O, fake clock, byte-exact frames.

The second channel in these tests: client -> server 0x681, server -> client 0x6A1
(outside the restricted CAN-IDs; node 1's 0x1200 channel is 0x601 / 0x581).
"""

import random

import pytest
from canopen_rig import Rig, seed_node

from fieldgate.can.frame import Frame
from fieldgate.plugins.canopen.cia301.sdo_channel import SdoChannel, channel_indices

OPEN_1201 = ["23 01 12 01 81 06 00 00", "23 01 12 02 A1 06 00 00"]  # 0x1201:1 = 0x681, :2 = 0x6A1


def configured(**settings) -> Rig:
    r = Rig(seed_node(1, sdo_servers=3, **settings))
    for request in OPEN_1201:
        assert r.sdo(request) == "60" + request[2:11] + " 00 00 00 00"
    return r


def second(r: Rig, text: str) -> list[str]:
    return r.send("681 " + text)


def test_default_is_one_server_and_extra_channels_start_invalid():
    assert (
        Rig(seed_node(1)).sdo("40 01 12 01 00 00 00 00") == "80 01 12 01 00 00 02 06"
    )  # no 0x1201
    r = Rig(seed_node(1, sdo_servers=3))
    assert r.sdo("40 01 12 00 00 00 00 00") == "4F 01 12 00 03 00 00 00"
    assert r.sdo("40 01 12 01 00 00 00 00") == "43 01 12 01 00 00 00 80"
    assert r.sdo("40 02 12 02 00 00 00 00") == "43 02 12 02 00 00 00 80"
    assert r.sdo("40 02 12 03 00 00 00 00") == "4F 02 12 03 00 00 00 00"
    assert r.sdo("40 03 12 01 00 00 00 00") == "80 03 12 01 00 00 02 06"  # 3 servers: 0x1200-0x1202
    assert sorted(s.name for s in r.node.services if isinstance(s, SdoChannel)) == [
        "sdo_1201",
        "sdo_1202",
    ]
    assert r.node.service("sdo").rx_cob == 0x601  # "sdo" stays the 0x1200 server


def test_channel_count_limits():
    assert list(channel_indices(1)) == []
    assert channel_indices(128)[-1] == 0x127F
    for bad in (0, 129):
        with pytest.raises(ValueError):
            channel_indices(bad)


def test_invalid_channel_is_silent_until_both_cob_ids_are_valid():
    r = Rig(seed_node(1, sdo_servers=2))
    assert second(r, "40 00 10 00 00 00 00 00") == []
    assert r.sdo("23 01 12 01 81 06 00 00") == "60 01 12 01 00 00 00 00"
    assert second(r, "40 00 10 00 00 00 00 00") == []  # server -> client still invalid
    assert r.sdo("23 01 12 02 A1 06 00 00") == "60 01 12 02 00 00 00 00"
    assert second(r, "40 00 10 00 00 00 00 00") == ["6A1 43 00 10 00 91 01 0F 00"]
    assert r.node.counters["ignored"] == 2


def test_second_channel_serves_every_request_kind_and_aborts():
    r = configured()
    assert second(r, "2B 02 21 00 2C 01 00 00") == ["6A1 60 02 21 00 00 00 00 00"]  # 0x2102 = 300
    assert r.sdo("40 02 21 00 00 00 00 00") == "4B 02 21 00 2C 01 00 00"  # one dictionary for both
    assert second(r, "2B 02 21 00 E9 03 00 00") == ["6A1 80 02 21 00 31 00 09 06"]  # 1001 > max
    assert second(r, "40 00 20 00 00 00 00 00") == ["6A1 80 00 20 00 00 00 02 06"]
    assert second(r, "E0 00 00 00 00 00 00 00") == [
        "6A1 80 00 00 00 01 00 04 05"
    ]  # unknown specifier
    assert second(r, "40 00 10 00") == []  # DLC 4: counted, dropped
    assert r.node.service("sdo_1201").counters["bad_dlc_dropped"] == 1
    assert r.node.service("sdo").counters["aborts"] == 0


def test_channels_keep_independent_transfers():
    r = configured()
    done = r.node.service("sdo").counters["transfers"]
    # segmented upload of 0x1008 ("CPS_DCON\0", 9 bytes) open on both channels, interleaved
    assert r.sdo("40 08 10 00 00 00 00 00") == "41 08 10 00 09 00 00 00"
    assert second(r, "40 08 10 00 00 00 00 00") == ["6A1 41 08 10 00 09 00 00 00"]
    assert second(r, "60 00 00 00 00 00 00 00") == ["6A1 00 43 50 53 5F 44 43 4F"]
    assert r.sdo("60 00 00 00 00 00 00 00") == "00 43 50 53 5F 44 43 4F"
    assert r.sdo("70 00 00 00 00 00 00 00") == "1B 4E 00 00 00 00 00 00"
    assert second(r, "60 00 00 00 00 00 00 00") == [
        "6A1 80 08 10 00 00 00 03 05"
    ]  # its own toggle: 1 expected
    assert r.node.service("sdo").counters["transfers"] == done + 1
    assert r.node.service("sdo_1201").counters["transfers"] == 0


def test_timeouts_are_per_channel():
    r = configured(sdo_timeout_s=1.0)
    assert second(r, "40 08 10 00 00 00 00 00") == ["6A1 41 08 10 00 09 00 00 00"]
    r.advance(0.5)
    assert r.sdo("40 08 10 00 00 00 00 00") == "41 08 10 00 09 00 00 00"
    assert r.advance(0.5) == ["6A1 80 08 10 00 00 00 04 05"]
    assert r.advance(0.499) == []
    assert r.advance(0.001) == ["581 80 08 10 00 00 00 04 05"]


@pytest.mark.parametrize(
    "request_, code",
    [
        ("23 01 12 01 82 06 00 00", "30 00 09 06"),  # valid 0x681 -> 0x682: set bit 31 first
        ("23 01 12 01 81 06 00 20", "30 00 09 06"),  # 29-bit frame bit
        ("23 01 12 01 81 86 00 00", "30 00 09 06"),  # bits 11-28
    ],
)
def test_cob_id_change_rules_on_a_valid_channel(request_, code):
    r = configured()
    assert r.sdo(request_) == "80 01 12 01 " + code
    assert second(r, "40 00 10 00 00 00 00 00") == ["6A1 43 00 10 00 91 01 0F 00"]  # unchanged


def test_cob_id_moves_through_invalid():
    r = configured()
    assert r.sdo("23 01 12 01 81 06 00 80") == "60 01 12 01 00 00 00 00"
    assert second(r, "40 00 10 00 00 00 00 00") == []
    assert r.sdo("23 01 12 01 82 06 00 00") == "60 01 12 01 00 00 00 00"
    assert r.send("682 40 00 10 00 00 00 00 00") == ["6A1 43 00 10 00 91 01 0F 00"]
    assert (
        r.sdo("23 01 12 01 82 06 00 40") == "60 01 12 01 00 00 00 00"
    )  # bit 30 (dynamic) is kept, same CAN-ID
    assert r.sdo("40 01 12 01 00 00 00 00") == "43 01 12 01 82 06 00 40"


@pytest.mark.parametrize(
    "value, ok",
    [
        ("05 06 00 00", False),  # 0x605 restricted (another node's SDO)
        ("05 06 00 80", True),  # restricted but not valid: not in use
        ("E0 06 00 00", False),  # 0x6E0 restricted
        ("DF 06 00 00", True),
        ("00 00 00 00", False),  # 0x000 (NMT)
    ],
)
def test_restricted_can_ids(value, ok):
    r = Rig(seed_node(1, sdo_servers=2))
    assert r.sdo("23 01 12 01 " + value) == (
        "60 01 12 01 00 00 00 00" if ok else "80 01 12 01 30 00 09 06"
    )


def test_can_ids_cannot_be_shared_between_sdo_channels():
    r = configured()
    assert r.sdo("23 02 12 01 81 06 00 00") == "80 02 12 01 30 00 09 06"  # 0x681 is 0x1201's
    assert r.sdo("23 02 12 02 A1 06 00 00") == "80 02 12 02 30 00 09 06"
    assert (
        r.sdo("23 02 12 01 A1 06 00 00") == "80 02 12 01 30 00 09 06"
    )  # another's server -> client
    assert r.sdo("23 02 12 01 82 06 00 00") == "60 02 12 01 00 00 00 00"
    assert r.sdo("23 02 12 02 82 06 00 00") == "80 02 12 02 30 00 09 06"  # its own client -> server
    assert r.sdo("23 02 12 02 A2 06 00 00") == "60 02 12 02 00 00 00 00"
    assert r.send("682 40 00 10 00 00 00 00 00") == ["6A2 43 00 10 00 91 01 0F 00"]


def test_client_node_id_sub_3():
    r = configured()
    assert second(r, "2F 01 12 03 7F 00 00 00") == ["6A1 60 01 12 03 00 00 00 00"]
    assert second(r, "2F 01 12 03 80 00 00 00") == ["6A1 80 01 12 03 31 00 09 06"]
    assert r.sdo("40 01 12 03 00 00 00 00") == "4F 01 12 03 7F 00 00 00"


def test_switching_off_its_own_channel_confirms_on_the_old_cob_id():
    r = configured()
    assert second(r, "23 01 12 02 A1 06 00 80") == ["6A1 60 01 12 02 00 00 00 00"]
    assert second(r, "40 00 10 00 00 00 00 00") == []
    assert r.node.status()["services"]["sdo_1201"]["valid"] is False


def test_changing_the_cob_ids_ends_an_open_transfer_without_a_frame():
    r = configured()
    assert second(r, "40 08 10 00 00 00 00 00") == ["6A1 41 08 10 00 09 00 00 00"]
    assert r.sdo("23 01 12 01 81 06 00 80") == "60 01 12 01 00 00 00 00"
    assert r.node.service("sdo_1201").counters["ended_by_cob_id_change"] == 1
    assert r.advance(2.0) == []  # no timeout abort for the ended transfer
    assert r.sdo("23 01 12 01 81 06 00 00") == "60 01 12 01 00 00 00 00"
    assert second(r, "60 00 00 00 00 00 00 00") == ["6A1 80 00 00 00 01 00 04 05"]  # nothing open


def test_no_sdo_on_any_channel_in_stopped():
    r = configured()
    r.send("000 02 01")
    assert second(r, "40 00 10 00 00 00 00 00") == []
    r.send("000 80 01")
    assert second(r, "40 00 10 00 00 00 00 00") == ["6A1 43 00 10 00 91 01 0F 00"]


def test_reset_communication_reloads_stored_channel_parameters(tmp_path):
    path = tmp_path / "node.json"
    r = configured(store_path=path)
    assert r.send("000 82 01") == ["701 00"]
    assert second(r, "40 00 10 00 00 00 00 00") == []  # not stored: invalid again
    for request in OPEN_1201:
        r.sdo(request)
    assert r.sdo("23 10 10 02 73 61 76 65") == "60 10 10 02 00 00 00 00"  # save communication
    assert r.send("000 82 01") == ["701 00"]
    assert second(r, "40 00 10 00 00 00 00 00") == ["6A1 43 00 10 00 91 01 0F 00"]
    # a fresh node (power-on) loads the store
    node = seed_node(1, sdo_servers=3, store_path=path)
    node.service("store").load()
    fresh = Rig(node)
    assert fresh.send("681 40 00 10 00 00 00 00 00") == ["6A1 43 00 10 00 91 01 0F 00"]
    assert fresh.sdo("23 11 10 02 6C 6F 61 64") == "60 11 10 02 00 00 00 00"  # restore defaults
    assert fresh.send("000 82 01") == ["701 00"]
    assert fresh.send("681 40 00 10 00 00 00 00 00") == []


def test_random_requests_on_every_channel_never_raise_and_keep_the_rules():
    rng = random.Random(1201)
    r = configured()
    mux = [b"\x01\x12", b"\x02\x12", b"\x00\x12", b"\x12\x10", b"\x08\x10", b"\x02\x21"]
    ids = [0x601, 0x681, 0x682, 0x6A1, 0x100, 0x7FF]
    for i in range(5_000):
        can_id = rng.choice(ids)
        if rng.random() < 0.8:
            command = rng.choice(
                [0x23, 0x2B, 0x2F, 0x40, 0x60, 0x70, 0x00, 0x10, 0x80, 0xA0, 0xA1, 0xC0, 0xC4]
            )
            value = rng.choice(
                [
                    0x681,
                    0x682,
                    0x6A1,
                    0x6A2,
                    0x605,
                    0x80000682,
                    0x20000681,
                    0x40000682,
                    rng.randrange(1 << 32),
                ]
            )
            data = (
                bytes([command])
                + rng.choice(mux)
                + bytes([rng.randrange(4)])
                + value.to_bytes(4, "little")
            )
        else:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        out = r.node.receive(Frame(can_id, data), r.now)
        if i % 25 == 0:
            r.now += 0.3
            out += r.node.tick(r.now)
        for f in out:
            assert 0 <= f.can_id <= 0x7FF and len(f.data) <= 8
    assert r.node.counters["internal_errors"] == 0
    assert (
        r.node.service("sdo_1201").counters["requests"] > 100
        and r.node.service("time").counters["bad_length"] > 0
    )
    in_use = []
    for index in (0x1201, 0x1202):
        for sub in (1, 2):
            cob = r.node.od.get(index, sub)
            assert not cob & 0x3FFFF800  # bit 29 and bits 11-28 never taken
            if not cob & 0x80000000:
                in_use.append(cob & 0x7FF)
    assert len(in_use) == len(set(in_use)) and not any(
        0x601 <= c <= 0x67F or 0x581 <= c <= 0x5FF for c in in_use
    )
    r.advance(2.0)  # open transfers time out
    assert r.sdo("40 00 10 00 00 00 00 00") == "43 00 10 00 91 01 0F 00"  # 0x1200 still serves
