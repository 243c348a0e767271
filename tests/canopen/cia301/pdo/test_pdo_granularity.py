"""PDO mapping granularity: CiA 301 dummy entries in RPDOs, 1-bit mapping of the CiA 401 bit
objects 0x6020-/0x6220- (``bit_mapping``), byte-aligned defaults for masters without bit
mapping (Delta AS300, seed-002 REQ-AS-12), and what the EDS says about it."""

from __future__ import annotations

import configparser
import json
import subprocess

import pytest
from io_bench import Bench, make_image
from test_eds_generation import dcfchk, generate, topology

from fieldgate.cli import main as cli_main
from fieldgate.plugins.canopen.cia401.iodevice import IoSettings

NOT_MAPPABLE = "41 00 04 06"
MODULES = [(1, 8, 0, 0, 0), (2, 4, 0, 0, 0), (3, 0, 8, 0, 0), (4, 0, 4, 0, 0), (5, 0, 0, 1, 1)]


def bench(bit_mapping: bool, style: str = "na9161") -> Bench:
    return Bench(make_image(MODULES), IoSettings(style=style, bit_mapping=bit_mapping), node_id=5)


def remap(b: Bench, map_index: int, entries: list[int]) -> list[str]:
    """DS301 sequence: sub 0 = 0, entries, sub 0 = n; the answers of the entry writes."""
    assert b.write(map_index, 0, 0, 1).startswith("60")
    answers = [b.write(map_index, n, e, 4) for n, e in enumerate(entries, 1)]
    if all(a.startswith("60") for a in answers):
        assert b.write(map_index, 0, len(entries), 1).startswith("60")
    return answers


def test_defaults_stay_byte_aligned_with_bit_mapping():
    plain, bits = bench(False), bench(True)
    for index in (0x1600, 0x1601, 0x1A00, 0x1A01):
        for sub in range(9):
            assert plain.value(index, sub) == bits.value(index, sub), (hex(index), sub)
    assert bits.value(0x1A00, 1) == 0x60000108 and bits.value(0x1600, 1) == 0x62000108
    assert plain.start() == bits.start()


def test_bit_objects_mirror_the_8_bit_objects():
    b = bench(True)
    assert b.value(0x6020, 0) == 16 and b.value(0x6220, 0) == 16  # 2 bytes each, padding too
    b.image.update_input("bus/m1/di3", True)
    b.image.update_input("bus/m2/di1", True)
    assert b.value(0x6000, 1) == 0x08 and b.value(0x6000, 2) == 0x02
    assert [b.value(0x6020, n) for n in (4, 10, 13)] == [1, 1, 0]  # 13: padding bit of slot 2
    assert b.write(0x6220, 12, 1, 1) == "60 20 62 0C 00 00 00 00"
    assert b.image.value("bus/m4/do3") is True and b.value(0x6200, 2) == 0x08
    assert b.write(0x6220, 14, 1, 1).startswith("60")  # a padding bit: taken, changes nothing
    assert b.value(0x6200, 2) == 0x08
    assert (0x6020, 0) not in bench(False).node.od


def test_one_bit_entries_pack_lsb_first_in_tpdos_and_rpdos():
    b = bench(True)
    # TPDO3: DI 4, DI 10, then AI 1: 1 + 1 + 16 bits = 3 bytes
    assert remap(b, 0x1A02, [0x60200401, 0x60200A01, 0x64010110]) == [
        "60 02 1A 01 00 00 00 00",
        "60 02 1A 02 00 00 00 00",
        "60 02 1A 03 00 00 00 00",
    ]
    b.write(0x1802, 1, 0x385, 4)
    b.image.update_input("bus/m1/di3", True)
    b.image.update_input("bus/m5/ai0", 0x1234)
    assert "385 [3] D1 48 00" in b.start()  # bit0 = DI4, bit1 = DI10 (0), bits 2-17 = 0x1234
    # RPDO3: DO 12 (bit 0), a BOOLEAN dummy (bit 1), an UNSIGNED8 dummy (bits 2-9), DO 1 (bit 10)
    answers = remap(b, 0x1602, [0x62200C01, 0x00010001, 0x00050008, 0x62200101])
    assert all(a.startswith("60") for a in answers), answers
    b.write(0x1402, 1, 0x405, 4)
    assert b.rx(0x405, "FD 03") == []  # bit0 = 1, bit1 dummy, bits 2-9 dummy, bit 10 = 0
    assert b.image.value("bus/m4/do3") is True and b.image.value("bus/m3/do0") is False
    assert b.rx(0x405, "00 04") == []  # bit 10 = DO 1
    assert b.image.value("bus/m4/do3") is False and b.image.value("bus/m3/do0") is True
    # 11 bits need 2 bytes: one is too short, ignored with EMCY 8210
    assert b.rx(0x405, "00") == ["085 [8] 10 82 11 09 00 00 00 00"]
    assert b.image.value("bus/m3/do0") is True


def test_dummy_entries_in_rpdos_with_byte_granularity():
    b = bench(False)
    # RPDO3: skip one byte (UNSIGNED8 dummy) and one word (INTEGER16 dummy), then DO byte 1
    answers = remap(b, 0x1602, [0x00050008, 0x00030010, 0x62000108])
    assert all(a.startswith("60") for a in answers), answers
    b.write(0x1402, 1, 0x405, 4)
    b.start()
    assert b.rx(0x405, "AA BB CC 0F") == []
    assert [b.image.value(f"bus/m3/do{i}") for i in range(8)] == [True] * 4 + [False] * 4


@pytest.mark.parametrize(
    "bit_mapping, map_index, entry",
    [
        (False, 0x1602, 0x00010001),  # a 1-bit dummy needs bit granularity
        (True, 0x1A02, 0x00050008),  # no dummy in a TPDO
        (True, 0x1602, 0x00050010),  # a dummy has its type's length
        (True, 0x1602, 0x00050108),  # only sub 0
        (True, 0x1602, 0x62200108),  # a bit object entry is 1 bit
        (True, 0x1A02, 0x62200101),  # DO bits are rw: a TPDO may send them back
    ],
)
def test_entries_that_do_not_fit_the_granularity_are_refused(bit_mapping, map_index, entry):
    b = bench(bit_mapping)
    answer = b.write(map_index, 1, entry, 4)
    if entry == 0x62200101:
        assert answer.startswith("60")  # rw output bits may be sent back in a TPDO
    else:
        assert answer.startswith("80") and answer.endswith(NOT_MAPPABLE), answer


def test_byte_granularity_refuses_one_bit_entries_of_other_objects():
    b = bench(False)
    assert b.write(0x1A02, 1, 0x60000101, 4).endswith(NOT_MAPPABLE)


# -- EDS -----------------------------------------------------------------------------------------


def read_eds(path) -> configparser.ConfigParser:
    parser = configparser.ConfigParser()
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read(path)
    return parser


@pytest.mark.parametrize("bit_mapping", [False, True])
def test_the_eds_states_granularity_and_dummy_usage_and_passes_dcfchk(tmp_path, bit_mapping):
    path = generate(tmp_path, style="na9161", bit_mapping=bit_mapping)
    eds = read_eds(path)
    info, dummies = eds["DeviceInfo"], eds["DummyUsage"]
    assert info["Granularity"] == ("1" if bit_mapping else "8")
    assert info["DynamicChannelsSupported"] == "0"
    assert [dummies[f"Dummy000{i}"] for i in range(1, 8)] == ["1" if bit_mapping else "0"] + [
        "1"
    ] * 6
    assert eds.has_section("6020") == bit_mapping and eds.has_section("6220") == bit_mapping
    if bit_mapping:
        sub1 = eds["6020sub1"]
        assert int(sub1["DataType"], 0) == 0x0001 and int(sub1["PDOMapping"], 0) == 1
    result: subprocess.CompletedProcess = dcfchk(path)
    assert result.returncode == 0 and not result.stderr.strip(), result.stderr


@pytest.mark.parametrize("style", ["icpdas", "na9161"])
def test_special_bytes_bit_objects_and_fnbus_in_the_eds_pass_dcfchk(tmp_path, style):
    topo = topology(tmp_path, style=style, bit_mapping=True)
    topo["backs"][0]["modules"].append({"address": 4, "special": 6})
    source = tmp_path / "topo.json"
    source.write_text(json.dumps(topo))
    path = tmp_path / "plc.eds"
    assert cli_main(["eds", str(source), "-o", str(path)]) == 0
    eds = read_eds(path)
    assert eds["3000"]["SubNumber"] == "0x7" and eds["3200sub6"]["AccessType"] == "rw"
    assert eds.has_section("4500") == (style == "na9161")
    result = dcfchk(path)
    assert result.returncode == 0 and not result.stderr.strip(), result.stderr


def test_eds_of_an_image_too_big_for_an_na9161_is_one_line(tmp_path, capsys):
    topo = topology(tmp_path, style="na9161")
    topo["backs"][0]["modules"].append({"address": 4, "special": 64})
    source = tmp_path / "topo.json"
    source.write_text(json.dumps(topo))
    assert cli_main(["eds", str(source)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.endswith("an NA-9161-style head holds 64 per direction") and "\n" not in err
