"""NA-9161 special modules (0x3000/0x3200) and the FnBus register 0x4500 (seed-004 §2.2-2.7,
§3.3, TV-06..TV-10, TV-18..TV-21 with the high-speed counter slot), on the node with a fake clock."""

from __future__ import annotations

import pytest
from io_bench import Bench, Kind, make_image, module_health
from na9161_images import NA_DO_VALUES, NA_OUTPUTS, do_value, na_inputs, set_bits

from fieldgate.health import ErrorKind
from fieldgate.plugins.canopen.cia401.iodevice import IoSettings
from fieldgate.plugins.canopen.cia401.layouts import LayoutError, build_layout

HSC_IN = (10, 0, 0, 0, 0, 6, 0)  # slot 10: ST-5101-style counter, 6 bytes in, no digital bits
HSC_OUT = (11, 0, 0, 0, 0, 0, 2)  # slot 11 of the output example: 2 bytes out
SAVE, LOAD = "23 10 10 01 73 61 76 65", "23 11 10 01 6C 6F 61 64"


def hsc_inputs(hsc_digital: int = 0):
    """The §2.3 input example with the counter in slot 10 (bytes 01..06); ``hsc_digital``
    declares digital points on the counter module too ([AMBIG-10], value 0x9)."""
    image = na_inputs([(10, hsc_digital, 0, 0, 0, 6, 0)])
    for i in range(6):
        image.update_input(f"bus/m10/si{i}", i + 1)
    if hsc_digital:
        set_bits(image, 10, Kind.DI, 0x9, hsc_digital)
    return image


def digital(bench, index=0x6000) -> str:
    n = bench.value(index, 0)
    return bytes(bench.value(index, s) for s in range(1, n + 1)).hex(" ").upper()


def special(bench, index=0x3000) -> str:
    n = bench.value(index, 0)
    return bytes(bench.value(index, s) for s in range(1, n + 1)).hex(" ").upper()


# -- special areas ---------------------------------------------------------------------------


def test_tv18_counter_bytes_in_0x3000_and_no_digital_bits_of_the_counter():
    bench = Bench(hsc_inputs(), IoSettings(style="na9161"), node_id=5)
    assert digital(bench) == "CA F5 EE 3B 81 46 23 01"  # 60 bits, the counter adds none
    assert special(bench) == "01 02 03 04 05 06"  # 0x3000:1..6 = byte 0..5
    assert bench.read(0x3000, 0) == "4F 00 30 00 06 00 00 00"
    assert bench.read(0x2020, 1) == "4B 20 20 01 3C 00 00 00"  # TV-04: 60 bits
    assert bench.value(0x1000, 0) == 0x00050191  # TV-17: special data sets no 0x1000 bit
    # not in the default mapping (§A.3): the start TPDOs are TV-18's
    assert bench.start() == ["185 [8] CA F5 EE 3B 81 46 23 01", "285 [8] 34 12 FF 0F 00 00 01 80"]


@pytest.mark.parametrize(
    "compressed, expected",
    [(True, "CA F5 EE 3B 81 46 23 91"), (False, "0A 5C EF BE 03 81 06 34 12 09")],
)
def test_ambig10_a_counter_declared_with_digital_points_has_them_in_both_modes(
    compressed, expected
):
    bench = Bench(hsc_inputs(hsc_digital=4), IoSettings(style="na9161", compressed=compressed))
    assert digital(bench) == expected  # TV-18 note (0x91) and TV-19, byte for byte
    assert special(bench) == "01 02 03 04 05 06"


def test_tv20_tv21_counter_output_bytes_in_0x3200_by_sdo():
    image = make_image(NA_OUTPUTS + [HSC_OUT])
    for address, (value, count) in NA_DO_VALUES.items():
        set_bits(image, address, Kind.DO, value, count)
    bench = Bench(image, IoSettings(style="na9161", compressed=False), node_id=5)
    assert digital(bench, 0x6200) == "05 F0 34 12 0C AA 01 02 FE CA"  # TV-21 without AMBIG-10 bits
    assert bench.value(0x3200, 0) == 2
    assert bench.write(0x3200, 1, 0x10, 1) == "60 00 32 01 00 00 00 00"
    assert bench.write(0x3200, 2, 0x27, 1) == "60 00 32 02 00 00 00 00"
    assert (image.value("bus/m11/so0"), image.value("bus/m11/so1")) == (0x10, 0x27)
    assert bench.read(0x3000, 1).startswith("80 00 30 01 00 00 02 06")  # no special inputs here
    assert bench.write(0x3200, 3, 1, 1).startswith("80 00 32 03 11 00 09 06")


def test_user_mapped_special_data_travel_in_both_directions():
    image = make_image([(3, 0, 0, 2, 0), HSC_IN, HSC_OUT])
    bench = Bench(image, IoSettings(style="na9161"), node_id=5)
    # TxPDO3: counter bytes 0..5; RxPDO3: the counter's 2 output bytes (DS301 sequence)
    for index, sub, value, size in [
        (0x1A02, 0, 0, 1),
        *[(0x1A02, n, 0x30000008 | n << 8, 4) for n in range(1, 7)],
        (0x1A02, 0, 6, 1),
        (0x1802, 3, 0, 2),  # inhibit time: only while the PDO is invalid
        (0x1802, 2, 255, 1),
        (0x1802, 1, 0x385, 4),
        (0x1602, 0, 0, 1),
        (0x1602, 1, 0x32000108, 4),
        (0x1602, 2, 0x32000208, 4),
        (0x1602, 0, 2, 1),
        (0x1402, 1, 0x405, 4),
    ]:
        assert bench.write(index, sub, value, size).startswith("60"), (hex(index), sub)
    assert "385 [6] 00 00 00 00 00 00" in bench.start()
    image.update_input("bus/m10/si0", 0xE8)
    image.update_input("bus/m10/si1", 0x03)
    assert bench.flush() == ["385 [6] E8 03 00 00 00 00"]  # a counter change is an event
    assert bench.rx(0x405, "10 27") == []
    assert (image.value("bus/m11/so0"), image.value("bus/m11/so1")) == (0x10, 0x27)


def test_an_na9161_head_has_at_most_32_slots():
    image = make_image([(a, 1, 0, 0, 0) for a in range(1, 34)])
    with pytest.raises(LayoutError, match="33 modules exceed the 32 slots"):
        build_layout(list(image), "na9161")
    assert len(build_layout(list(image), "icpdas").modules) == 33


def test_an_na9161_image_holds_64_bytes_per_direction():
    fits = make_image([(1, 0, 0, 24, 0), (2, 64, 0, 0, 0), (3, 0, 0, 0, 0, 8, 0)])  # 48 + 8 + 8
    assert len(build_layout(list(fits), "na9161").si) == 8
    over = make_image([(1, 0, 0, 24, 0), (2, 64, 0, 0, 0), (3, 0, 0, 0, 0, 9, 0)])
    with pytest.raises(LayoutError, match="the inputs need 65 bytes"):
        build_layout(list(over), "na9161")
    non_compressed = make_image([(1, 0, 0, 0, 28)] + [(a, 0, 1, 0, 0) for a in range(2, 11)])
    assert len(build_layout(list(non_compressed), "na9161").do_bytes) == 2  # 56 + 2 bytes
    with pytest.raises(LayoutError, match="the outputs need 65 bytes"):  # 56 + a byte per module
        build_layout(list(non_compressed), "na9161", compressed=False)


# -- 0x4500 -------------------------------------------------------------------------------------


def test_tv06_tv07_status_and_data_mode_read():
    health_bench = Bench(hsc_inputs(), IoSettings(style="na9161"), node_id=5)
    assert health_bench.read(0x4500, 0) == "4F 00 45 00 03 00 00 00"
    assert health_bench.read(0x4500, 1) == "43 00 45 01 00 00 00 00"  # no error, field power on
    assert health_bench.read(0x4500, 2) == "4F 00 45 02 01 00 00 00"  # TV-07: compressed
    assert health_bench.read(0x4500, 3) == "43 00 45 03 00 00 00 00"  # every slot active
    assert health_bench.read(0x4500, 1) != ""  # read-only:
    assert health_bench.write(0x4500, 1, 0, 4).startswith("80 00 45 01 02 00 01 06")


def test_status_names_the_first_active_slot_whose_module_is_offline():
    bench = Bench(hsc_inputs(), IoSettings(style="na9161"), node_id=5)
    health = module_health(bench.health, 4)
    for _ in range(health.fail_threshold + 1):
        health.record_failure(ErrorKind.TIMEOUT, "no answer")
    assert bench.read(0x4500, 1) == "43 00 45 01 01 04 00 00"  # code 01, slot 4 (address 4)
    bench.write(0x4500, 3, 1 << 3, 4)
    bench.nmt(0x81)
    assert bench.read(0x4500, 1) == "43 00 45 01 00 00 00 00"  # slot 4 deactivated: no error


def test_tv08_data_mode_takes_effect_at_reset_node():
    bench = Bench(hsc_inputs(hsc_digital=4), IoSettings(style="na9161"), node_id=5)
    assert bench.write(0x4500, 2, 0, 1) == "60 00 45 02 00 00 00 00"
    assert bench.read(0x4500, 2) == "4F 00 45 02 00 00 00 00"  # written ...
    assert digital(bench) == "CA F5 EE 3B 81 46 23 91"  # ... the image keeps its layout
    bench.nmt(0x82)  # reset communication is not enough
    assert digital(bench) == "CA F5 EE 3B 81 46 23 91"
    bench.nmt(0x81)
    assert digital(bench) == "0A 5C EF BE 03 81 06 34 12 09"  # TV-19
    assert bench.value(0x1A00, 0) == 8 and bench.value(0x1A02, 1) == 0x60000908
    assert bench.start()[0] == "185 [8] 0A 5C EF BE 03 81 06 34"
    assert special(bench) == "01 02 03 04 05 06"
    assert bench.write(0x4500, 2, 1, 1) == "60 00 45 02 00 00 00 00"  # TV-08
    bench.nmt(0x81)
    assert digital(bench) == "CA F5 EE 3B 81 46 23 91"
    assert bench.write(0x4500, 2, 2, 1).startswith("80 00 45 02")


def test_tv10_a_deactivated_slot_leaves_the_image_at_reset_node():
    bench = Bench(hsc_inputs(), IoSettings(style="na9161"), node_id=5)
    assert bench.write(0x4500, 3, 0x01, 4) == "60 00 45 03 00 00 00 00"  # TV-10, DS301-strict
    assert bench.read(0x4500, 3) == "43 00 45 03 01 00 00 00"
    bench.nmt(0x81)
    # slot 1 (4 DI = 0xA) gone: the stream starts with slot 2 (0x5C), 56 bits
    assert digital(bench) == "5C EF BE 13 68 34 12"
    assert bench.value(0x2020, 1) == 56
    assert bench.value(0x2010, 1) == 1 and bench.value(0x2010, 0) == 10  # the slot keeps its number
    bench.write(0x4500, 3, 1 << 9, 4)  # slot 10: the counter
    bench.nmt(0x81)
    assert (0x3000, 0) not in bench.node.od and digital(bench).startswith("CA F5")
    # analog slots 3 and 8 off: no 0x6401, and 0x1000 says no AI any more
    bench.write(0x4500, 3, 1 << 2 | 1 << 7, 4)
    bench.nmt(0x81)
    assert (0x6401, 0) not in bench.node.od and bench.value(0x1000, 0) == 0x00010191
    assert bench.start() == ["185 [8] CA F5 EE 3B 81 46 23 01"]


def test_slot_flags_beyond_the_modules_are_refused():
    bench = Bench(hsc_inputs(), IoSettings(style="na9161"), node_id=5)
    assert bench.write(0x4500, 3, 1 << 10, 4) == "80 00 45 03 30 00 09 06"
    assert bench.write(0x4500, 3, 1 << 9, 4).startswith("60")


def test_fnbus_settings_are_stored_by_0x1010_and_forgotten_by_0x1011(tmp_path):
    path = tmp_path / "store.json"
    options = {"node_id": 5, "store_path": path}
    bench = Bench(hsc_inputs(hsc_digital=4), IoSettings(style="na9161"), **options)
    bench.write(0x4500, 2, 0, 1)
    bench.write(0x4500, 3, 0x01, 4)
    assert bench.sdo(SAVE) == "60 10 10 01 00 00 00 00"
    # power cycle: the stored settings are in effect from the boot
    bench = Bench(hsc_inputs(hsc_digital=4), IoSettings(style="na9161"), **options)
    assert bench.read(0x4500, 2) == "4F 00 45 02 00 00 00 00"
    assert bench.read(0x4500, 3) == "43 00 45 03 01 00 00 00"
    assert digital(bench) == "5C EF BE 03 81 06 34 12 09"  # non-compressed, slot 1 left out
    # a PDO mapping saved together with the layout comes back with it
    bench.write(0x1A00, 0, 0, 1)
    bench.write(0x1A00, 1, 0x60000908, 4)
    bench.write(0x1A00, 0, 1, 1)
    assert bench.sdo(SAVE) == "60 10 10 01 00 00 00 00"
    bench = Bench(hsc_inputs(hsc_digital=4), IoSettings(style="na9161"), **options)
    assert bench.start()[0] == "185 [1] 09"
    assert bench.sdo(LOAD) == "60 11 10 01 00 00 00 00"
    bench = Bench(hsc_inputs(hsc_digital=4), IoSettings(style="na9161"), **options)
    assert bench.read(0x4500, 2) == "4F 00 45 02 01 00 00 00"
    assert digital(bench) == "CA F5 EE 3B 81 46 23 91"


def test_an_unsaved_write_is_lost_at_power_off_but_kept_over_reset_node(tmp_path):
    options = {"node_id": 5, "store_path": tmp_path / "store.json"}
    bench = Bench(hsc_inputs(), IoSettings(style="na9161"), **options)
    bench.write(0x4500, 2, 0, 1)
    bench.nmt(0x81)
    assert bench.read(0x4500, 2) == "4F 00 45 02 00 00 00 00"
    bench = Bench(hsc_inputs(), IoSettings(style="na9161"), **options)
    assert bench.read(0x4500, 2) == "4F 00 45 02 01 00 00 00"


def test_icpdas_style_has_no_fnbus_register_but_serves_special_bytes():
    bench = Bench(make_image([HSC_IN]), IoSettings(style="icpdas"))
    assert (0x4500, 0) not in bench.node.od
    assert bench.value(0x3000, 0) == 6


def test_outputs_of_a_deactivated_slot_are_not_written_by_rpdos():
    image = make_image(NA_OUTPUTS)
    bench = Bench(image, IoSettings(style="na9161"), node_id=5)
    bench.write(0x4500, 3, 1, 4)  # slot 1 (4 DO) off
    bench.nmt(0x81)
    bench.start()
    bench.rx(0x205, "FF 00 00 00 00 00 00 00")  # 0x6200:1 = slot 2's 8 points now
    assert do_value(image, 1, 4) == 0 and do_value(image, 2, 8) == 0xFF


# -- 0x4503 product codes (TV-11) -----------------------------------------------------------

TV11_SLOTS = [  # (address, di, do, ai, ao): ST-2424, ST-2318, ST-4112, ST-222F, ST-2314, ST-2328, ST-2742
    (1, 4, 4, 0, 0),
    (2, 0, 8, 0, 0),
    (3, 0, 0, 0, 2),
    (4, 0, 16, 0, 0),
    (5, 0, 4, 0, 0),
    (6, 0, 8, 0, 0),
    (7, 0, 2, 0, 0),
]
TV11_ANSWERS = [
    "4F 03 45 00 07 00 00 00",
    "43 03 45 01 83 83 C0 01",
    "43 03 45 02 C0 00 80 01",
    "43 03 45 03 C0 41 A0 03",
    "43 03 45 04 C0 01 80 01",
    "43 03 45 05 C0 83 80 01",
    "43 03 45 06 C0 00 80 01",
    "43 03 45 07 C0 81 80 01",
]


def test_tv11_product_codes_of_the_slots_byte_for_byte():
    bench = Bench(make_image(TV11_SLOTS), IoSettings(style="na9161"), node_id=5)
    assert [bench.read(0x4503, sub) for sub in range(8)] == TV11_ANSWERS
    counter = Bench(make_image([HSC_IN[:5] + (6, 2)]), IoSettings(style="na9161"))
    assert counter.read(0x4503, 1) == "43 03 45 01 05 01 D0 03"  # ST-5101: 6 bytes in, 2 out
    assert counter.write(0x4503, 1, 0, 4).startswith("80 03 45 01")  # read-only


def test_tv10_as_printed_needs_the_lenient_sdo_option():
    bench = Bench(hsc_inputs(), IoSettings(style="na9161"), node_id=5)
    tv10 = "2B 00 45 03 01 00 00 00"  # a 2-byte write to a U32, as the seed prints it
    assert bench.sdo(tv10) == "80 00 45 03 13 00 07 06"  # 0607 0013 by default (CiA 301)
    bench.node.service("sdo").zero_extend = True  # sdo_zero_extend: true on the front
    assert bench.sdo(tv10) == "60 00 45 03 00 00 00 00"
    assert bench.read(0x4500, 3) == "43 00 45 03 01 00 00 00"


def test_a_data_mode_the_image_cannot_hold_is_refused_at_the_write():
    image = make_image([(1, 0, 0, 0, 28)] + [(a, 0, 1, 0, 0) for a in range(2, 11)])
    bench = Bench(image, IoSettings(style="na9161"), node_id=5)
    assert bench.write(0x4500, 2, 0, 1) == "80 00 45 02 47 00 04 06"  # 0604 0047: 65 bytes
    assert bench.read(0x4500, 2) == "4F 00 45 02 01 00 00 00"
    assert bench.write(0x4500, 3, 1, 4).startswith("60")  # slot 1 (the AO) off: now it fits
    assert bench.write(0x4500, 2, 0, 1) == "60 00 45 02 00 00 00 00"
    bench.nmt(0x81)
    assert bench.value(0x6200, 0) == 9 and (0x6411, 0) not in bench.node.od
