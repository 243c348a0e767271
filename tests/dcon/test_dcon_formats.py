"""Data formats and type-code tables against the seeds' Appendix B and worked examples."""

import pytest

from fieldgate import ErrorKind, Quality
from fieldgate.plugins.dcon.formats import (
    DataFormat,
    ao_text_to_raw,
    engineering_to_raw,
    raw_to_engineering,
    raw_to_text,
    rtd_resistance,
    rtd_temperature,
    split_values,
    text_to_raw,
)
from fieldgate.plugins.dcon.tables import TABLES
from fieldgate.polling import CommError

A = TABLES["group-a"]
C = TABLES["group-c"]
RTD = TABLES["rtd"]
AO12 = TABLES["ao-12bit"]
AO24 = TABLES["ao-7024"]


def test_tv_c1_i7017_at_10v_0x1234_is_1_422_v():
    assert round(raw_to_engineering(0x1234, A.get(0x08)), 3) == 1.422


@pytest.mark.parametrize("raw, volts", [(0x3FF5, 4.997), (0x3FF8, 4.998), (0x0006, 0.002)])
def test_tv_c2_i7012_readings(raw, volts):
    rng = A.get(0x08)
    assert round(raw_to_engineering(raw, rng), 3) == volts
    # the same reading sent in engineering units (1 mV = 3.3 LSB) comes back within the text's resolution
    back, quality = text_to_raw(
        raw_to_text(raw, DataFormat.ENGINEERING, rng), DataFormat.ENGINEERING, rng
    )
    assert quality is Quality.GOOD and abs(back - raw) <= 2


def test_tv_c3_i7021_5v_truncates_to_0x07ff():
    rng = AO12.get(0x32)
    assert engineering_to_raw(5.0, rng, round_down=True) == (0x07FF, Quality.GOOD)
    assert ao_text_to_raw("05.000", DataFormat.ENGINEERING, rng) == (0x07FF, Quality.GOOD)


@pytest.mark.parametrize(
    "code, tmin, hmin, tmax, hmax",
    [
        (0x0E, -210, -9054, 760, 0x7FFF),  # J: 0xDCA2
        (0x0F, -270, -6448, 1372, 0x7FFF),  # K: 0xE6D0
        (0x10, -270, -22118, 400, 0x7FFF),  # T: 0xA99A
        (0x11, -270, -8847, 1000, 0x7FFF),  # E: 0xDD71
        (0x15, -270, -6805, 1300, 0x7FFF),  # N: 0xE56B
        (0x17, -200, -8192, 800, 0x7FFF),  # L: 0xE000
        (0x18, -200, -32768, 100, 0x4000),  # M: 0x8000 .. 0x4000
        (0x19, -200, -7281, 900, 0x7FFF),  # L (DIN43710): 0xE38F
    ],
)
def test_tv_c9_thermocouple_limits(code, tmin, hmin, tmax, hmax):
    rng = C.get(code)
    assert (rng.fmin, rng.hmin, rng.fmax, rng.hmax) == (tmin, hmin, tmax, hmax)
    assert engineering_to_raw(tmin, rng) == (hmin, Quality.GOOD)
    assert engineering_to_raw(tmax, rng) == (hmax, Quality.GOOD)


def test_hex_limits_match_the_appendix_b_bit_patterns():
    as_u16 = lambda v: v & 0xFFFF  # noqa: E731
    assert as_u16(C.get(0x0E).hmin) == 0xDCA2 and as_u16(C.get(0x0F).hmin) == 0xE6D0
    assert as_u16(RTD.get(0x28).hmin) == 0x999A and as_u16(RTD.get(0x2A).hmin) == 0xD556
    assert as_u16(C.get(0x19).hmin) == 0xE38F


def test_percent_of_fsr_limits_follow_the_seed():
    assert C.get(0x0E).percent_limits == (-27.63, 100.0)  # J
    assert C.get(0x18).percent_limits == (-100.0, 50.0)  # M
    assert A.get(0x08).percent_limits == (-100.0, 100.0)
    assert RTD.get(0x28).percent_limits == (-80.0, 100.0)  # Ni120
    assert RTD.get(0x2A).percent_limits == (-33.33, 100.0)  # Pt1000
    assert AO12.get(0x31).percent_limits == (0.0, 100.0)  # 4-20 mA: % of span


def test_percent_format_converts_to_the_hex_scale():
    rng = A.get(0x09)
    # the manuals' linear map over the whole scale: (50 + 100) * 65535 / 200 - 32768 = 16383.25
    assert text_to_raw("+050.00", DataFormat.PERCENT, rng) == (16383, Quality.GOOD)
    assert text_to_raw("-100.00", DataFormat.PERCENT, rng) == (-32768, Quality.GOOD)
    j = C.get(0x0E)
    assert text_to_raw("-027.63", DataFormat.PERCENT, j)[0] == pytest.approx(-9054, abs=1)


def test_engineering_over_and_under_range_clamp_and_flag():
    rng = A.get(0x08)
    assert text_to_raw("+10.500", DataFormat.ENGINEERING, rng) == (0x7FFF, Quality.OVER_RANGE)
    assert text_to_raw("-10.500", DataFormat.ENGINEERING, rng) == (-0x8000, Quality.UNDER_RANGE)
    rng = RTD.get(0x21)  # 0..100 degC
    assert text_to_raw("-005.00", DataFormat.ENGINEERING, rng) == (0, Quality.UNDER_RANGE)


def test_hex_format_is_twos_complement_on_bipolar_ranges_and_unsigned_otherwise():
    assert text_to_raw("8000", DataFormat.HEX, A.get(0x08)) == (-32768, Quality.GOOD)
    assert text_to_raw("1999", DataFormat.HEX, A.get(0x09)) == (
        0x1999,
        Quality.GOOD,
    )  # +1 V on +/-5 V, the ND-6017 example
    assert round(raw_to_engineering(0x1999, A.get(0x09)), 2) == 1.0
    assert ao_text_to_raw("FFF", DataFormat.HEX, AO12.get(0x32)) == (4095, Quality.GOOD)
    assert ao_text_to_raw("8000", DataFormat.HEX, AO24.get(0x33)) == (-32768, Quality.GOOD)
    assert raw_to_text(-1, DataFormat.HEX, AO24.get(0x33)) == "FFFF"
    assert raw_to_text(0x7FF, DataFormat.HEX, AO12.get(0x32), hex_width=3) == "7FF"


def test_engineering_text_has_the_dcon_shape():
    assert raw_to_text(0x7FFF, DataFormat.ENGINEERING, A.get(0x08)) == "+10.000"
    assert raw_to_text(-0x8000, DataFormat.ENGINEERING, C.get(0x05)) == "-2.5000"
    assert raw_to_text(0x7FFF, DataFormat.ENGINEERING, C.get(0x0F)) == "+1372.0"
    assert raw_to_text(0x7FFF, DataFormat.ENGINEERING, A.get(0x0C)) == "+150.00"
    assert raw_to_text(0x7FF, DataFormat.ENGINEERING, AO12.get(0x32), signed_text=False) == "04.999"
    assert raw_to_text(0x4000, DataFormat.PERCENT, A.get(0x08)) == "+050.00"


@pytest.mark.parametrize(
    "table, code, signed",
    [
        ("ao-12bit", 0x32, False),
        ("ao-12bit", 0x31, False),
        ("ao-7024", 0x33, True),
        ("ao-7024", 0x34, True),
    ],
)
@pytest.mark.parametrize("fmt", [DataFormat.ENGINEERING, DataFormat.PERCENT, DataFormat.HEX])
def test_ao_set_points_survive_the_round_trip_through_the_module(table, code, signed, fmt):
    """The back rounds text up; a module truncating it lands on the raw value (or within the text's resolution)."""
    rng = TABLES[table].get(code)
    width = 3 if rng.hmax == 0xFFF else 4
    step = 1 if rng.hmax == 0xFFF else 97
    resolution = (
        {DataFormat.HEX: 0, DataFormat.ENGINEERING: 0, DataFormat.PERCENT: 1}[fmt]
        if rng.hmax == 0xFFF
        else 4
    )
    for raw in range(rng.hmin, rng.hmax + 1, step):
        text = raw_to_text(raw, fmt, rng, hex_width=width, signed_text=signed, round_up=True)
        back, quality = ao_text_to_raw(text, fmt, rng)
        assert quality is Quality.GOOD
        assert 0 <= back - raw <= resolution, (raw, text, back)


def test_ohms_format_uses_the_rtd_curves():
    # Pt100 (IEC 60751) at the table's end points
    assert rtd_resistance("pt385", 100) == pytest.approx(138.50, abs=0.01)
    assert rtd_resistance("pt385", -100) == pytest.approx(60.25, abs=0.02)
    assert rtd_resistance("pt3916", 100) == pytest.approx(139.16, abs=0.02)
    assert rtd_temperature("pt385", 100.0) == pytest.approx(0.0, abs=1e-6)
    assert rtd_temperature("pt385", rtd_resistance("pt385", -57.3)) == pytest.approx(
        -57.3, abs=1e-4
    )
    rng = RTD.get(0x20)
    raw, quality = text_to_raw("+138.50", DataFormat.OHMS, rng)
    assert quality is Quality.GOOD and raw == pytest.approx(0x7FFF, abs=15)
    raw, _ = text_to_raw("+100.00", DataFormat.OHMS, rng)
    assert raw == 0
    with pytest.raises(CommError) as exc:
        text_to_raw("+150.00", DataFormat.OHMS, RTD.get(0x29))  # Ni120: no curve, hex format needed
    assert exc.value.kind is ErrorKind.GARBAGE


def test_split_values():
    assert split_values("+05.123+04.153-00.001", DataFormat.ENGINEERING, 3) == [
        "+05.123",
        "+04.153",
        "-00.001",
    ]
    assert split_values("4C53FFFF", DataFormat.HEX, 2) == ["4C53", "FFFF"]
    for bad in ("+05.123+04.153", "05.123+04.153+1.000", "+05.1+04.1+0.1+1.0"):
        with pytest.raises(CommError):
            split_values(bad, DataFormat.ENGINEERING, 3)
    with pytest.raises(CommError):
        split_values("4C53FFF", DataFormat.HEX, 2)
    with pytest.raises(CommError):
        text_to_raw("+0x.000", DataFormat.ENGINEERING, A.get(0x08))
    with pytest.raises(CommError):
        text_to_raw("ZZZZ", DataFormat.HEX, A.get(0x08))


def test_every_table_row_is_consistent():
    for table in TABLES.values():
        assert table.get(table.default) is not None, table.name
        for rng in table.ranges:
            assert rng.fmin < rng.fmax and rng.hmin < rng.hmax
            assert engineering_to_raw(rng.fmax, rng)[0] == rng.hmax
            assert engineering_to_raw(rng.fmin, rng)[0] == rng.hmin


@pytest.mark.parametrize(
    "text, fmt, rng",
    [
        (
            "-" + "9" * 155,
            DataFormat.OHMS,
            RTD.get(0x20),
        ),  # an RTD resistance off every curve (was NaN -> ValueError)
        ("-1" + "0" * 202, DataFormat.OHMS, RTD.get(0x20)),  # was OverflowError
        ("+1" + "0" * 310, DataFormat.ENGINEERING, A.get(0x08)),  # inf
        ("+1" + "0" * 310, DataFormat.PERCENT, A.get(0x08)),
    ],
)
def test_a_number_no_module_sends_is_garbage_not_a_crash(text, fmt, rng):
    with pytest.raises(CommError) as err:
        text_to_raw(text, fmt, rng)
    assert err.value.kind is ErrorKind.GARBAGE
