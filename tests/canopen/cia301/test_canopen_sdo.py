"""SDO server against the I-7232D / I-7231D vectors, byte for byte, and every abort."""

import struct

import pytest
from canopen_rig import Rig, seed_node

from fieldgate.plugins.canopen.cia301.sdo import crc16


@pytest.fixture
def rig():
    r = Rig(seed_node(1))
    assert r.boot == ["701 00"]
    return r


def abort_of(answer: str) -> int:
    data = bytes.fromhex(answer.replace(" ", ""))
    assert data[0] == 0x80, answer
    return struct.unpack_from("<I", data, 4)[0]


def test_tv01_expedited_upload(rig):
    assert rig.sdo("40 00 14 00 00 00 00 00") == "4F 00 14 00 02 00 00 00"


def test_tv02_segmented_upload_of_device_name(rig):
    assert rig.sdo("40 08 10 00 00 00 00 00") == "41 08 10 00 09 00 00 00"
    assert rig.sdo("60 00 00 00 00 00 00 00") == "00 43 50 53 5F 44 43 4F"
    assert rig.sdo("70 00 00 00 00 00 00 00") == "1B 4E 00 00 00 00 00 00"
    # the transfer is over: another segment request is an unknown command now
    assert abort_of(rig.sdo("60 00 00 00 00 00 00 00")) == 0x05040001


def test_tv03_block_upload_without_crc(rig):
    assert rig.sdo("A0 08 10 00 7F 00 00 00") == "C2 08 10 00 09 00 00 00"
    assert rig.send("601 A3 00 00 00 00 00 00 00") == [
        "581 01 43 50 53 5F 44 43 4F",
        "581 82 4E 00 00 00 00 00 00",
    ]
    assert rig.sdo("A2 02 7F 00 00 00 00 00") == "D5 00 00 00 00 00 00 00"
    assert rig.send("601 A1 00 00 00 00 00 00 00") == []
    assert rig.node.service("sdo").phase.name == "IDLE"


def test_tv04_expedited_download_and_read_back(rig):
    assert rig.sdo("2F 00 14 02 05 00 00 00") == "60 00 14 02 00 00 00 00"
    assert rig.sdo("40 00 14 02 00 00 00 00") == "4F 00 14 02 05 00 00 00"


def test_tv05_block_download_i7231d_form(rig):
    assert rig.sdo("C0 00 14 02 00 00 00 00") == "A0 00 14 02 7F 00 00 00"
    assert rig.sdo("81 05 00 00 00 00 00 00") == "A2 01 7F 00 00 00 00 00"
    assert rig.sdo("D9 00 00 00 00 00 00 00") == "A1 00 00 00 00 00 00 00"
    assert rig.node.od.get(0x1400, 2) == 5


def test_tv05_printed_n5_is_a_length_error(rig):
    """The I-7232D prints D5 (2 bytes) for a 1-byte object; a strict server refuses it."""
    rig.sdo("C0 00 14 02 00 00 00 00")
    rig.sdo("81 05 00 00 00 00 00 00")
    assert abort_of(rig.sdo("D5 00 00 00 00 00 00 00")) == 0x06070012
    assert rig.node.od.get(0x1400, 2) == 0xFF


def test_tv06_abort_missing_subindex(rig):
    assert rig.sdo("40 08 10 01 00 00 00 00") == "80 08 10 01 11 00 09 06"


@pytest.mark.parametrize(
    "request_, code",
    [
        ("40 00 30 00 00 00 00 00", 0x06020000),  # no object
        ("40 18 10 07 00 00 00 00", 0x06090011),  # no sub-index
        ("23 00 10 00 00 00 00 00", 0x06010002),  # 0x1000 read-only
        ("23 08 10 00 41 42 43 44", 0x06010002),  # const string
        ("40 03 21 00 00 00 00 00", 0x06010001),  # write-only
        ("2B 00 14 02 05 00 00 00", 0x06070012),  # 2 bytes into U8
        ("2F 0C 10 00 05 00 00 00", 0x06070013),  # 1 byte into U16
        ("2B 02 21 00 E9 03 00 00", 0x06090031),  # 1001 > max 1000
        ("2B 02 21 00 9B FF 00 00", 0x06090032),  # -101 < min -100
        ("2B 0C 10 00 00 80 00 00", 0x06090031),  # guard time > 32767
        ("2F 03 10 00 01 00 00 00", 0x06090030),  # 0x1003:0 only accepts 0
        ("23 10 10 01 73 61 76 66", 0x08000020),  # wrong "save" signature
        ("E0 00 10 00 00 00 00 00", 0x05040001),  # ccs 7
        ("A0 08 10 00 00 00 00 00", 0x05040002),  # block size 0
        ("A0 08 10 00 80 00 00 00", 0x05040002),  # block size 128
    ],
)
def test_aborts(rig, request_, code):
    assert abort_of(rig.sdo(request_)) == code


def test_value_unchanged_after_refused_write(rig):
    rig.sdo("2B 02 21 00 0A 00 00 00")
    rig.sdo("2B 02 21 00 E9 03 00 00")
    assert rig.node.od.get(0x2102) == 10


def test_expedited_upload_states_its_size(rig):
    assert rig.sdo("40 00 10 00 00 00 00 00") == "43 00 10 00 91 01 0F 00"
    assert rig.sdo("40 0C 10 00 00 00 00 00") == "4B 0C 10 00 00 00 00 00"
    assert rig.sdo("40 18 10 00 00 00 00 00") == "4F 18 10 00 04 00 00 00"


def test_segmented_download_and_toggle_error(rig):
    text = b"hello, fieldgate!"
    assert rig.sdo("21 00 21 00" + struct.pack("<I", len(text)).hex()) == "60 00 21 00 00 00 00 00"
    assert rig.sdo("00" + text[0:7].hex()) == "20 00 00 00 00 00 00 00"
    assert rig.sdo("10" + text[7:14].hex()) == "30 00 00 00 00 00 00 00"
    last = text[14:]
    n = 7 - len(last)
    assert rig.sdo(f"{(n << 1) | 1:02X}" + last.ljust(7, b"\0").hex()) == "20 00 00 00 00 00 00 00"
    assert rig.node.od.get(0x2100) == "hello, fieldgate!"
    rig.sdo("21 00 21 00 10 00 00 00")
    assert abort_of(rig.sdo("10" + "00" * 7)) == 0x05030000
    assert rig.node.od.get(0x2100) == "hello, fieldgate!"


def test_segmented_download_size_mismatch(rig):
    rig.sdo("21 00 21 00 03 00 00 00")
    assert abort_of(rig.sdo("01" + b"abcdefg".hex())) == 0x06070010


def test_upload_toggle_error(rig):
    rig.sdo("40 08 10 00 00 00 00 00")
    assert abort_of(rig.sdo("70 00 00 00 00 00 00 00")) == 0x05030000


def test_server_timeout_aborts(rig):
    rig.sdo("40 08 10 00 00 00 00 00")
    assert rig.advance(0.5) == []
    assert rig.advance(0.6) == ["581 80 08 10 00 00 00 04 05"]
    assert rig.node.service("sdo").phase.name == "IDLE"


def test_new_initiate_supersedes_open_transfer(rig):
    rig.sdo("40 08 10 00 00 00 00 00")
    assert rig.sdo("40 00 14 00 00 00 00 00") == "4F 00 14 00 02 00 00 00"
    assert abort_of(rig.sdo("60 00 00 00 00 00 00 00")) == 0x05040001


def test_client_abort_ends_transfer_silently(rig):
    rig.sdo("40 08 10 00 00 00 00 00")
    assert rig.send("601 80 08 10 00 00 00 04 05") == []
    assert rig.advance(2.0) == []


def _segments(data: bytes, blksize: int = 127):
    frames, seq = [], 0
    for i in range(0, len(data), 7):
        seq += 1
        last = i + 7 >= len(data)
        frames.append(bytes([seq | (0x80 if last else 0)]) + data[i : i + 7].ljust(7, b"\0"))
    return frames


def test_block_download_with_crc_and_lost_segment(rig):
    payload = bytes(range(40))
    assert (
        rig.sdo("C6 01 21 00" + struct.pack("<I", len(payload)).hex()) == "A4 01 21 00 7F 00 00 00"
    )
    segs = _segments(payload)
    assert rig.send(segs[0].hex()[:0] + "601 " + segs[0].hex()) == []
    # segment 2 is lost; 3..6 arrive, the last one is acknowledged short (ackseq 1)
    for s in segs[2:-1]:
        assert rig.send("601 " + s.hex()) == []
    assert rig.sdo(segs[-1].hex()) == "A2 01 7F 00 00 00 00 00"
    # the client repeats from segment 2, renumbered from 1
    again = _segments(payload[7:])
    for s in again[:-1]:
        assert rig.send("601 " + s.hex()) == []
    assert rig.sdo(again[-1].hex()) == f"A2 {len(again):02X} 7F 00 00 00 00 00"
    n = 7 - (len(payload) % 7 or 7)
    crc = crc16(payload)
    assert (
        rig.sdo(f"{0xC1 | (n << 2):02X}" + struct.pack("<H", crc).hex() + "00" * 5)
        == "A1 00 00 00 00 00 00 00"
    )
    assert rig.node.od.get(0x2101) == payload


def test_block_download_crc_error(rig):
    payload = b"0123456789"
    rig.sdo("C6 01 21 00 0A 00 00 00")
    segs = _segments(payload)
    rig.send("601 " + segs[0].hex())
    rig.sdo(segs[1].hex())
    n = 7 - len(payload) % 7
    bad = crc16(payload) ^ 1
    assert (
        abort_of(rig.sdo(f"{0xC1 | (n << 2):02X}" + struct.pack("<H", bad).hex() + "00" * 5))
        == 0x05040004
    )
    assert rig.node.od.get(0x2101) == b""


def test_block_download_bad_sequence_number(rig):
    rig.sdo("C0 01 21 00 00 00 00 00")
    assert abort_of(rig.sdo("00 01 02 03 04 05 06 07")) == 0x05040003


def test_block_upload_with_crc_small_blocks_and_resend(rig):
    payload = bytes(range(100, 130))
    rig.node.od.set(0x2101, 0, payload)
    assert rig.sdo("A4 01 21 00 02 00 00 00") == "C6 01 21 00 1E 00 00 00"
    out = rig.send("601 A3 00 00 00 00 00 00 00")
    assert out == [
        "581 01 " + payload[0:7].hex(" ").upper(),
        "581 02 " + payload[7:14].hex(" ").upper(),
    ]
    # the client lost segment 2: ackseq 1 -> the server resends from byte 7
    out = rig.send("601 A2 01 03 00 00 00 00 00")
    assert [o[4:6] for o in out] == ["01", "02", "03"]
    assert out[0][7:] == payload[7:14].hex(" ").upper()
    out = rig.send("601 A2 03 7F 00 00 00 00 00")
    assert out == ["581 " + "81 " + payload[28:30].hex(" ").upper() + " 00 00 00 00 00"]
    n = 7 - 2
    crc = struct.pack("<H", crc16(payload)).hex(" ").upper()
    assert rig.sdo("A2 01 7F 00 00 00 00 00") == f"{0xC1 | (n << 2):02X} {crc} 00 00 00 00 00"
    assert rig.send("601 A1 00 00 00 00 00 00 00") == []


def test_block_upload_protocol_switch(rig):
    assert rig.sdo("A0 00 14 00 7F 04 00 00") == "4F 00 14 00 02 00 00 00"
    assert rig.sdo("A0 08 10 00 7F 10 00 00") == "41 08 10 00 09 00 00 00"
    assert rig.sdo("60 00 00 00 00 00 00 00") == "00 43 50 53 5F 44 43 4F"


def test_malformed_frames_are_counted_drops(rig):
    assert rig.send("601 40 00 14 00") == []
    assert rig.send("601 RTR") == []
    assert rig.send("602 40 00 14 00 00 00 00 00") == []  # another node's SDO
    st = rig.node.status()
    assert st["services"]["sdo"]["bad_dlc_dropped"] == 1
    assert st["services"]["sdo"]["rtr_dropped"] == 1
    assert st["counters"]["ignored"] == 1


def test_no_sdo_in_stopped(rig):
    rig.send("000 02 01")
    assert rig.send("601 40 00 14 00 00 00 00 00") == []
    rig.send("000 80 00")
    assert rig.sdo("40 00 14 00 00 00 00 00") == "4F 00 14 00 02 00 00 00"


def test_a_failing_listener_gets_a_general_error_abort(rig):
    def broken(index, sub, value):
        raise NameError("bug")

    rig.node.od.on_write(0x2102, broken)
    assert abort_of(rig.sdo("2B 02 21 00 01 00 00 00")) == 0x08000000
    assert rig.node.service("sdo").counters["internal_errors"] == 1
    assert rig.sdo("40 00 14 00 00 00 00 00") == "4F 00 14 00 02 00 00 00"


def test_short_expedited_write_zero_extended_only_when_enabled():
    strict = Rig(seed_node(1))
    assert abort_of(strict.sdo("2B 16 10 01 C8 00 00 00")) == 0x06070013
    lenient = Rig(seed_node(1, sdo_zero_extend=True))
    assert lenient.sdo("2B 16 10 01 C8 00 00 00") == "60 16 10 01 00 00 00 00"
    assert lenient.node.od.get(0x1016, 1) == 200
    assert abort_of(lenient.sdo("2F 02 21 00 05 00 00 00")) == 0x06070013  # signed: not extended


def test_transfer_survives_start_but_not_stop(rig):
    rig.sdo("40 08 10 00 00 00 00 00")
    rig.send("000 01 01")  # pre-operational -> operational: the transfer goes on
    assert rig.sdo("60 00 00 00 00 00 00 00") == "00 43 50 53 5F 44 43 4F"
    rig.send("000 02 01")  # stopped: the transfer is dropped
    rig.send("000 01 01")
    assert abort_of(rig.sdo("70 00 00 00 00 00 00 00")) == 0x05040001
