"""Type-code tables: type code -> range, engineering limits Fmin/Fmax and hex limits Hmin/Hmax.

Data transcribed from the I-7231D and I-7241D manuals' Appendix B (extracts
``seed-001-I7231D.md`` §2.3 and ``seed-003-I7241D.md`` §5.2). Where the OCR lost a
type code, the standard DCON code is used (the extracts list them in brackets). Hex
limits are the manuals' values, not recomputed: they are rounded inconsistently
(J: -9053.9 -> 0xDCA2 = -9054, DIN43710 L: -7281.6 -> 0xE38F = -7281), and the
process image must match the modules bit for bit.

Each row: code, label, unit, Fmin, Fmax, Hmin, Hmax, and for RTD ranges the
resistance at Fmin/Fmax and the sensor curve (used by the ohms data format).
"""

from __future__ import annotations

from dataclasses import dataclass

DIO_TYPE_CODE = 0x40  # what $AA2 reports for digital modules


@dataclass(frozen=True)
class TypeRange:
    code: int
    label: str
    unit: str
    fmin: float
    fmax: float
    hmin: int
    hmax: int
    ohm_min: float | None = None
    ohm_max: float | None = None
    sensor: str | None = None  # RTD curve: pt385, pt3916, pt1000, ni120
    pct_min: float | None = None  # % of FSR at Fmin/Fmax; default F / full scale * 100
    pct_max: float | None = None

    @property
    def full_scale(self) -> float:
        return max(abs(self.fmin), abs(self.fmax))

    @property
    def percent_limits(self) -> tuple[float, float]:
        if self.pct_min is not None and self.pct_max is not None:
            return self.pct_min, self.pct_max
        fs = self.full_scale
        return round(self.fmin / fs * 100, 2), round(self.fmax / fs * 100, 2)

    @property
    def signed(self) -> bool:
        return self.hmin < 0

    def describe(self) -> str:
        return f"0x{self.code:02X} {self.label}"


S16 = (-0x8000, 0x7FFF)


def _bipolar(code: int, label: str, unit: str, fs: float) -> TypeRange:
    return TypeRange(code, label, unit, -fs, fs, *S16)


# I-7012(D)/7012F/7014D/7017(F/C/R/RC), I-87017(R): every range bipolar, 0x8000..0x7FFF
GROUP_A = (
    _bipolar(0x08, "+/-10 V", "V", 10.0),
    _bipolar(0x09, "+/-5 V", "V", 5.0),
    _bipolar(0x0A, "+/-1 V", "V", 1.0),
    _bipolar(0x0B, "+/-500 mV", "mV", 500.0),
    _bipolar(0x0C, "+/-150 mV", "mV", 150.0),
    _bipolar(0x0D, "+/-20 mA (125 ohm)", "mA", 20.0),
)

# I-7011(P)/7018(P/R/BL), I-87018(R), I-87016: mV/V/mA ranges
GROUP_C_VOLTAGE = (
    _bipolar(0x00, "+/-15 mV", "mV", 15.0),
    _bipolar(0x01, "+/-50 mV", "mV", 50.0),
    _bipolar(0x02, "+/-100 mV", "mV", 100.0),
    _bipolar(0x03, "+/-500 mV", "mV", 500.0),
    _bipolar(0x04, "+/-1 V", "V", 1.0),
    _bipolar(0x05, "+/-2.5 V", "V", 2.5),
    _bipolar(0x06, "+/-20 mA", "mA", 20.0),
)

# thermocouples of the same modules (L and M only on I-7011P, I-7018P, I-87018)
THERMOCOUPLES = (
    TypeRange(0x0E, "J thermocouple", "degC", -210.0, 760.0, -9054, 0x7FFF),
    TypeRange(0x0F, "K thermocouple", "degC", -270.0, 1372.0, -6448, 0x7FFF),
    TypeRange(0x10, "T thermocouple", "degC", -270.0, 400.0, -22118, 0x7FFF),
    TypeRange(0x11, "E thermocouple", "degC", -270.0, 1000.0, -8847, 0x7FFF),
    TypeRange(0x12, "R thermocouple", "degC", 0.0, 1768.0, 0, 0x7FFF),
    TypeRange(0x13, "S thermocouple", "degC", 0.0, 1768.0, 0, 0x7FFF),
    TypeRange(0x14, "B thermocouple", "degC", 0.0, 1820.0, 0, 0x7FFF),
    TypeRange(0x15, "N thermocouple", "degC", -270.0, 1300.0, -6805, 0x7FFF),
    TypeRange(0x16, "C thermocouple", "degC", 0.0, 2320.0, 0, 0x7FFF),
    TypeRange(0x17, "L thermocouple", "degC", -200.0, 800.0, -8192, 0x7FFF),
    TypeRange(0x18, "M thermocouple", "degC", -200.0, 100.0, -0x8000, 0x4000),
    TypeRange(0x19, "L (DIN43710) thermocouple", "degC", -200.0, 900.0, -7281, 0x7FFF),
)

# RTD modules I-7013(D), I-7015, I-7033(D), I-87013
RTD = (
    TypeRange(
        0x20, "Pt100 a=0.00385 -100..100 degC", "degC", -100.0, 100.0, *S16, 60.25, 138.50, "pt385"
    ),
    TypeRange(
        0x21, "Pt100 a=0.00385 0..100 degC", "degC", 0.0, 100.0, 0, 0x7FFF, 100.00, 138.50, "pt385"
    ),
    TypeRange(
        0x22, "Pt100 a=0.00385 0..200 degC", "degC", 0.0, 200.0, 0, 0x7FFF, 100.00, 175.84, "pt385"
    ),
    TypeRange(
        0x23, "Pt100 a=0.00385 0..600 degC", "degC", 0.0, 600.0, 0, 0x7FFF, 100.00, 313.59, "pt385"
    ),
    TypeRange(
        0x24,
        "Pt100 a=0.003916 -100..100 degC",
        "degC",
        -100.0,
        100.0,
        *S16,
        59.58,
        139.16,
        "pt3916",
    ),
    TypeRange(
        0x25,
        "Pt100 a=0.003916 0..100 degC",
        "degC",
        0.0,
        100.0,
        0,
        0x7FFF,
        100.00,
        139.16,
        "pt3916",
    ),
    TypeRange(
        0x26,
        "Pt100 a=0.003916 0..200 degC",
        "degC",
        0.0,
        200.0,
        0,
        0x7FFF,
        100.00,
        177.13,
        "pt3916",
    ),
    TypeRange(
        0x27,
        "Pt100 a=0.003916 0..600 degC",
        "degC",
        0.0,
        600.0,
        0,
        0x7FFF,
        100.00,
        317.28,
        "pt3916",
    ),
    TypeRange(
        0x28, "Ni120 -80..100 degC", "degC", -80.0, 100.0, -26214, 0x7FFF, None, 200.64, "ni120"
    ),
    TypeRange(0x29, "Ni120 0..100 degC", "degC", 0.0, 100.0, 0, 0x7FFF, 120.60, 200.64, "ni120"),
    TypeRange(
        0x2A,
        "Pt1000 a=0.00385 -200..600 degC",
        "degC",
        -200.0,
        600.0,
        -10922,
        0x7FFF,
        185.2,
        3137.1,
        "pt1000",
    ),
)


def _ao(
    code: int,
    label: str,
    unit: str,
    fmin: float,
    fmax: float,
    hmin: int,
    hmax: int,
    pct: tuple[float, float] | None = None,
) -> TypeRange:
    return TypeRange(
        code,
        label,
        unit,
        fmin,
        fmax,
        hmin,
        hmax,
        pct_min=pct[0] if pct else None,
        pct_max=pct[1] if pct else None,
    )


# I-7021, I-7022, I-87022: 12-bit, 0x000..0xFFF on every range
AO_12BIT = (
    _ao(0x30, "0-20 mA", "mA", 0.0, 20.0, 0, 0xFFF),
    _ao(0x31, "4-20 mA", "mA", 4.0, 20.0, 0, 0xFFF, (0.0, 100.0)),
    _ao(0x32, "0-10 V", "V", 0.0, 10.0, 0, 0xFFF),
)

# I-7024, I-87024
AO_7024 = (
    _ao(0x30, "0-20 mA", "mA", 0.0, 20.0, 0, 0x7FFF),
    _ao(0x31, "4-20 mA", "mA", 4.0, 20.0, 0, 0x7FFF, (0.0, 100.0)),
    _ao(0x32, "0-10 V", "V", 0.0, 10.0, 0, 0x7FFF),
    _ao(0x33, "+/-10 V", "V", -10.0, 10.0, *S16),
    _ao(0x34, "0-5 V", "V", 0.0, 5.0, 0, 0x7FFF),
    _ao(0x35, "+/-5 V", "V", -5.0, 5.0, *S16),
)

# I-87026: 16-bit unsigned scale
AO_87026 = (
    _ao(0x30, "0-20 mA", "mA", 0.0, 20.0, 0, 0xFFFF),
    _ao(0x31, "4-20 mA", "mA", 4.0, 20.0, 0, 0xFFFF, (0.0, 100.0)),
    _ao(0x32, "0-10 V", "V", 0.0, 10.0, 0, 0xFFFF),
)


@dataclass(frozen=True)
class TypeTable:
    """The type codes one module accepts, and its factory default."""

    name: str
    ranges: tuple[TypeRange, ...]
    default: int

    def get(self, code: int) -> TypeRange | None:
        return next((r for r in self.ranges if r.code == code), None)

    def codes(self) -> list[int]:
        return [r.code for r in self.ranges]


TABLES = {
    "group-a": TypeTable("group-a", GROUP_A, 0x08),
    "group-c": TypeTable("group-c", GROUP_C_VOLTAGE + THERMOCOUPLES, 0x05),
    "strain": TypeTable("strain", GROUP_C_VOLTAGE[:6], 0x05),
    "universal": TypeTable("universal", GROUP_C_VOLTAGE + GROUP_A + THERMOCOUPLES, 0x08),
    "rtd": TypeTable("rtd", RTD, 0x20),
    "ao-12bit": TypeTable("ao-12bit", AO_12BIT, 0x32),
    "ao-7024": TypeTable("ao-7024", AO_7024, 0x33),
    "ao-87026": TypeTable("ao-87026", AO_87026, 0x32),
}
