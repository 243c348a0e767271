"""Object fill and default PDO mapping: seed-000 TV-25, seed-001 TV-C6/C7/C8 and demo, seed-004 TV-17..21."""

from __future__ import annotations

import pytest
from io_bench import Bench, Kind, make_image
from na9161_images import NA_DO_VALUES, NA_OUTPUTS, do_value, na_inputs, set_bits

from fieldgate.layout import default_order
from fieldgate.plugins.canopen.cia401.iodevice import IoSettings
from fieldgate.plugins.canopen.cia401.layouts import LayoutError, build_layout, default_pdos


def entries(pdo):
    return [f"{e >> 16:04X}:{e >> 8 & 0xFF:02X}/{e & 0xFF}" for e in pdo.entries]


def test_tv25_object_fill_of_the_i7232d_example():
    bench = Bench(make_image([(1, 8, 0, 0, 0), (3, 0, 8, 0, 0), (4, 0, 0, 0, 1), (5, 0, 0, 1, 0)]))
    assert [bench.value(i, 0) for i in (0x6000, 0x6200, 0x6401, 0x6411)] == [1, 1, 1, 1]
    assert bench.read(0x1000, 0) == "43 00 10 00 91 01 0F 00"
    assert bench.value(0x2000, 0) == 4
    assert [bench.value(0x2010, s) for s in range(1, 5)] == [1, 3, 4, 5]
    lay = bench.io.layout
    assert [c.id for c in lay.di_bytes[0]] == [f"bus/m1/di{i}" for i in range(8)]
    assert lay.ao[0].id == "bus/m4/ao0" and lay.ai[0].id == "bus/m5/ai0"


def test_tv_c6_seven_dcon_modules_fill_the_objects():
    image = make_image(
        [
            (1, 1, 2, 1, 0),
            (2, 16, 0, 0, 0),
            (3, 16, 0, 0, 0),
            (6, 0, 0, 0, 4),
            (8, 0, 0, 8, 0),
            (10, 16, 0, 0, 0),
            (11, 14, 0, 0, 0),
        ]
    )
    lay = build_layout(default_order(image))
    assert (len(lay.di_bytes), len(lay.do_bytes), len(lay.ai), len(lay.ao)) == (9, 1, 9, 4)
    first = [next(c for c in b if c is not None).id for b in lay.di_bytes]
    assert first == [
        "bus/m1/di0",
        "bus/m2/di0",
        "bus/m2/di8",
        "bus/m3/di0",
        "bus/m3/di8",
        "bus/m10/di0",
        "bus/m10/di8",
        "bus/m11/di0",
        "bus/m11/di8",
    ]
    assert [c is None for c in lay.di_bytes[0]] == [False] + [
        True
    ] * 7  # one padded byte per module
    assert [c is None for c in lay.di_bytes[8]] == [False] * 6 + [True] * 2  # DI8-13 of 0x0B
    assert [c.id for c in lay.ai] == ["bus/m1/ai0"] + [f"bus/m8/ai{i}" for i in range(8)]
    assert [m.address for m in lay.modules] == [1, 2, 3, 6, 8, 10, 11]


def test_tv_c7_overflow_goes_to_pdo5_and_up():
    image = make_image([(1, 0, 88, 0, 0), (2, 0, 0, 0, 13)])
    pdos = default_pdos(build_layout(default_order(image)))
    assert entries(pdos.rpdo[0]) == [f"6200:{i:02X}/8" for i in range(1, 9)]
    assert entries(pdos.rpdo[1]) == [f"6411:{i:02X}/16" for i in range(1, 5)]
    assert entries(pdos.rpdo[3]) == [f"6411:{i:02X}/16" for i in range(9, 13)]
    assert entries(pdos.rpdo[4]) == ["6200:09/8", "6200:0A/8", "6200:0B/8"]
    assert entries(pdos.rpdo[5]) == ["6411:0D/16"]
    assert [p.cob_id(1) for p in pdos.rpdo[:6]] == [
        0x201,
        0x301,
        0x401,
        0x501,
        0x8000_0000,
        0x8000_0000,
    ]
    assert all(not p.entries for p in pdos.rpdo[6:]) and len(pdos.rpdo) == 32


def test_tv_c8_utility_example():
    image = make_image(
        [
            (1, 0, 0, 8, 0),
            (2, 0, 0, 1, 0),
            (3, 8, 0, 0, 0),
            (4, 1, 2, 1, 0),
            (5, 0, 0, 1, 0),
            (6, 0, 0, 3, 0),
        ]
    )
    bench = Bench(image, node_id=5)
    assert bench.value(0x1000, 0) == 0x00070191
    assert bench.value(0x2000, 0) == 6 and [bench.value(0x2000, s) for s in range(1, 7)] == [0] * 6
    assert [bench.value(0x1400 + n, 1) for n in range(4)] == [0x205, 0x305, 0x405, 0x505]
    assert [bench.value(0x1400 + n, 2) for n in range(4)] == [255] * 4
    tp = bench.io.defaults.tpdo
    assert entries(tp[0]) == ["6000:01/8", "6000:02/8"]
    assert entries(tp[3]) == [f"6401:{i:02X}/16" for i in range(9, 13)]
    assert entries(tp[4]) == ["6401:0D/16", "6401:0E/16"]
    assert entries(bench.io.defaults.rpdo[0]) == ["6200:01/8"]


def test_i7231d_demo_defaults_are_served():
    from io_bench import demo_7231d

    bench = demo_7231d()
    assert [bench.value(0x1600, s) for s in range(4)] == [3, 0x62000108, 0x62000208, 0x62000308]
    assert [bench.value(0x1601, s) for s in range(2)] == [1, 0x64110110]
    assert [bench.value(0x1A00, s) for s in range(4)] == [3, 0x60000108, 0x60000208, 0x60000308]
    assert [bench.value(0x1A01, s) for s in range(2)] == [1, 0x64010110]
    assert (
        bench.value(0x1602, 0) == 0
        and bench.value(0x1402, 1) == 0x401
        and bench.value(0x1803, 1) == 0x481
    )
    assert bench.value(0x1404, 1) == 0x8000_0000 and bench.value(0x1A04, 0) == 0
    assert bench.read(0x1400, 0) == "4F 00 14 00 02 00 00 00"  # TV-01: RPDO comm sub 0 = 2


def test_mapping_closed_moves_analog_to_pdo1_without_digital():
    image = make_image([(1, 0, 0, 6, 0), (2, 0, 8, 0, 0)])
    lay = build_layout(default_order(image))
    closed = default_pdos(lay, mapping_closed=True)
    assert entries(closed.tpdo[0]) == [f"6401:{i:02X}/16" for i in range(1, 5)]
    assert entries(closed.tpdo[1]) == ["6401:05/16", "6401:06/16"]
    assert entries(closed.rpdo[0]) == ["6200:01/8"]  # DO present: RPDO1 stays digital
    open_ = default_pdos(lay)
    assert open_.tpdo[0].entries == [] and entries(open_.tpdo[1])[0] == "6401:01/16"


def test_too_many_channels_for_the_pdos_is_a_layout_error():
    image = make_image([(1, 0, 0, 40, 0)])
    with pytest.raises(LayoutError, match="needs 11 PDOs"):
        default_pdos(build_layout(default_order(image)), count=8)


# -- NA-9161 (seed-004 §2, TV-17..TV-21) ----------------------------------------------------


def test_na9161_tv18_compressed_inputs_and_the_start_tpdos():
    bench = Bench(na_inputs(), IoSettings(style="na9161"), node_id=5)
    assert (
        bytes(bench.value(0x6000, s) for s in range(1, 9)).hex(" ").upper()
        == "CA F5 EE 3B 81 46 23 01"
    )
    assert bench.value(0x1000, 0) == 0x00050191  # TV-17: DI + AI
    assert bench.start() == ["185 [8] CA F5 EE 3B 81 46 23 01", "285 [8] 34 12 FF 0F 00 00 01 80"]
    assert bench.value(0x2020, 1) == 60


def test_na9161_tv19_non_compressed_inputs():
    image = na_inputs([(10, 4, 0, 0, 0)])
    set_bits(image, 10, Kind.DI, 0x9, 4)
    bench = Bench(image, IoSettings(style="na9161", compressed=False), node_id=5)
    assert bench.value(0x6000, 0) == 10
    assert (
        bytes(bench.value(0x6000, s) for s in range(1, 11)).hex(" ").upper()
        == "0A 5C EF BE 03 81 06 34 12 09"
    )
    assert bench.start()[0] == "185 [8] 0A 5C EF BE 03 81 06 34"


def test_na9161_tv20_compressed_outputs_from_rpdos():
    bench = Bench(make_image(NA_OUTPUTS), IoSettings(style="na9161"), node_id=5)
    assert bench.value(0x1000, 0) == 0x000A0191
    bench.start()
    assert bench.rx(0x205, "05 4F 23 C1 AA E9 AF 0C") == []
    assert bench.rx(0x305, "00 08 FF 0F 01 00 FF 07") == []
    assert {a: do_value(bench.image, a, n) for a, (_, n) in NA_DO_VALUES.items()} == {
        a: v for a, (v, _) in NA_DO_VALUES.items()
    }
    assert [bench.image.value(f"bus/m{a}/ao{i}") for a in (3, 9) for i in (0, 1)] == [
        0x0800,
        0x0FFF,
        0x0001,
        0x07FF,
    ]


def test_na9161_tv21_non_compressed_outputs():
    image = make_image(NA_OUTPUTS + [(11, 0, 4, 0, 0)])
    for address, (value, count) in NA_DO_VALUES.items():
        set_bits(image, address, Kind.DO, value, count)
    bench = Bench(image, IoSettings(style="na9161", compressed=False), node_id=5)
    assert (
        bytes(bench.value(0x6200, s) for s in range(1, 12)).hex(" ").upper()
        == "05 F0 34 12 0C AA 01 02 FE CA 00"
    )


def test_na9161_defaults_type_254_inhibit_500ms_pdo3_up_invalid():
    bench = Bench(na_inputs(), IoSettings(style="na9161"), node_id=5)
    assert [bench.value(0x1800 + n, 1) for n in range(3)] == [0x185, 0x285, 0x8000_0000]
    assert bench.value(0x1400, 1) == 0x8000_0205  # no outputs: RPDO1 deactivated
    assert {bench.value(0x1800 + n, 2) for n in range(8)} == {254} and bench.value(
        0x1800, 3
    ) == 5000
    assert bench.value(0x1401, 2) == 254 and len(bench.io.engine.tpdos) == 8
