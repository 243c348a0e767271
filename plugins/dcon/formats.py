"""DCON analog data formats and their conversion to the process image's 16-bit raw value.

The process image holds every analog value as the module's own "2's complement hex"
scale, as the I-7231D and I-7241D present it on the fieldbus (seed-001 §2.3,
seed-003 §5.2): a bipolar range is 0x8000..0x7FFF (int16), the I-7021/7022 scale is
0x000..0xFFF, the I-87026 scale 0x0000..0xFFFF. Modules set to another data format
(FF byte bits 1:0 of ``$AA2``) are converted with the manuals' formulas::

    Float = (Hex - Hmin) * (Fmax - Fmin) / (Hmax - Hmin) + Fmin      (AI: rounded)
    Hex   = (Float - Fmin) * (Hmax - Hmin) / (Fmax - Fmin) + Hmin    (AO: truncated)

Values beyond the range are clamped to Hmin/Hmax and flagged over/under range.
"""

from __future__ import annotations

import math
import re
from enum import IntEnum

from fieldgate.health import ErrorKind
from fieldgate.image import Quality
from fieldgate.polling import CommError

from .tables import TypeRange


class DataFormat(IntEnum):
    ENGINEERING = 0
    PERCENT = 1
    HEX = 2
    OHMS = 3

    @classmethod
    def from_name(cls, name: str) -> DataFormat:
        return FORMAT_NAMES[name]

    @property
    def label(self) -> str:
        return {0: "engineering", 1: "percent", 2: "hex", 3: "ohms"}[self.value]


FORMAT_NAMES = {
    "engineering": DataFormat.ENGINEERING,
    "percent": DataFormat.PERCENT,
    "hex": DataFormat.HEX,
    "ohms": DataFormat.OHMS,
}


# -- the linear maps --------------------------------------------------------------
def raw_to_engineering(raw: int, tr: TypeRange) -> float:
    return (raw - tr.hmin) * (tr.fmax - tr.fmin) / (tr.hmax - tr.hmin) + tr.fmin


def engineering_to_raw(
    value: float, tr: TypeRange, *, round_down: bool = False
) -> tuple[int, Quality]:
    """AI readings round to nearest; AO set-points round down ("truncated", seed-001 TV-C3)."""
    exact = (value - tr.fmin) * (tr.hmax - tr.hmin) / (tr.fmax - tr.fmin) + tr.hmin
    raw = math.floor(exact + 1e-9) if round_down else math.floor(exact + 0.5)
    return clamp(raw, tr)


def clamp(raw: int, tr: TypeRange) -> tuple[int, Quality]:
    if raw > tr.hmax:
        return tr.hmax, Quality.OVER_RANGE
    if raw < tr.hmin:
        return tr.hmin, Quality.UNDER_RANGE
    return raw, Quality.GOOD


def percent_to_raw(pct: float, tr: TypeRange) -> tuple[int, Quality]:
    pmin, pmax = tr.percent_limits
    exact = (pct - pmin) * (tr.hmax - tr.hmin) / (pmax - pmin) + tr.hmin
    return clamp(math.floor(exact + 0.5), tr)


def raw_to_percent(raw: int, tr: TypeRange) -> float:
    pmin, pmax = tr.percent_limits
    return (raw - tr.hmin) * (pmax - pmin) / (tr.hmax - tr.hmin) + pmin


# -- RTD curves (ohms format) -------------------------------------------------------
# Callendar-Van Dusen: R = R0 (1 + A t + B t^2 + C (t - 100) t^3), C only below 0 degC
_CVD = {
    "pt385": (100.0, 3.9083e-3, -5.775e-7, -4.183e-12),  # IEC 60751
    "pt3916": (100.0, 3.9739e-3, -5.870e-7, -4.4e-12),  # JIS C 1604-1981
    "pt1000": (1000.0, 3.9083e-3, -5.775e-7, -4.183e-12),
}


def rtd_resistance(sensor: str, t: float) -> float:
    r0, a, b, c = _curve(sensor)
    return r0 * (1 + a * t + b * t * t + (c * (t - 100) * t**3 if t < 0 else 0.0))


def rtd_temperature(sensor: str, ohms: float) -> float:
    r0, a, b, c = _curve(sensor)
    t = (-a + math.sqrt(max(a * a - 4 * b * (1 - ohms / r0), 0.0))) / (2 * b)
    if t < 0:  # refine with the C term (Newton)
        for _ in range(20):
            f = rtd_resistance(sensor, t) - ohms
            df = r0 * (a + 2 * b * t + c * (4 * t**3 - 300 * t * t))
            t -= f / df
    return t


def _curve(sensor: str) -> tuple[float, float, float, float]:
    try:
        return _CVD[sensor]
    except KeyError:
        raise CommError(
            ErrorKind.GARBAGE,
            f"ohms format is not supported for sensor {sensor}; set the module to hex format",
        ) from None


def ohms_supported(tr: TypeRange) -> bool:
    return tr.sensor in _CVD


# -- text <-> raw --------------------------------------------------------------------
def decimals(full_scale: float) -> int:
    """Digits after the point in DCON engineering text: 5 significant digits in all."""
    return max(0, 5 - len(str(int(abs(full_scale)))))


def format_number(
    value: float, full_scale: float, signed: bool = True, round_up: bool = False
) -> str:
    places = decimals(full_scale)
    if round_up:  # so that a module that rounds down lands on the intended raw value
        value = math.ceil(value * 10**places - 1e-6) / 10**places
    width = 6 if places else 5
    text = f"{abs(value):0{width}.{places}f}"
    if signed:
        return ("-" if value < 0 else "+") + text
    return text


_DECIMAL = re.compile(r"[+-]?\d+(?:\.\d*)?")


def split_values(data: str, fmt: DataFormat, count: int, hex_width: int = 4) -> list[str]:
    """Cut the data of an AI reply into ``count`` values (hex: fixed width; else at signs)."""
    if fmt is DataFormat.HEX:
        if len(data) != count * hex_width:
            raise CommError(
                ErrorKind.GARBAGE,
                f"expected {count} hex values of {hex_width} digits, got {data!r}",
            )
        return [data[i * hex_width : (i + 1) * hex_width] for i in range(count)]
    values = re.findall(r"[+-][^+-]*", data)
    if len(values) != count or "".join(values) != data:
        raise CommError(ErrorKind.GARBAGE, f"expected {count} signed values, got {data!r}")
    return values


def parse_number(text: str) -> float:
    if not _DECIMAL.fullmatch(text):
        raise CommError(ErrorKind.GARBAGE, f"not a number: {text!r}")
    return float(text)


def parse_hex_word(text: str, signed: bool) -> int:
    if not text or any(c not in "0123456789ABCDEFabcdef" for c in text):
        raise CommError(ErrorKind.GARBAGE, f"not a hex value: {text!r}")
    value = int(text, 16)
    bits = 4 * len(text)
    if signed and value >= 1 << (bits - 1):
        value -= 1 << bits
    return value


def text_to_raw(text: str, fmt: DataFormat, tr: TypeRange) -> tuple[int, Quality]:
    """One AI value as the module sent it -> (raw, quality); CommError for text that is not one."""
    try:
        return _text_to_raw(text, fmt, tr)
    except (
        ValueError,
        OverflowError,
    ) as exc:  # a number no module sends: 300 digits, an RTD value off every curve
        raise CommError(
            ErrorKind.GARBAGE,
            f"not a value of {tr.describe()}: {text[:20]!r}{'...' if len(text) > 20 else ''}",
        ) from exc


def _text_to_raw(text: str, fmt: DataFormat, tr: TypeRange) -> tuple[int, Quality]:
    if fmt is DataFormat.HEX:
        return clamp(parse_hex_word(text, tr.signed), tr)
    number = parse_number(text)
    if fmt is DataFormat.ENGINEERING:
        return engineering_to_raw(number, tr)
    if fmt is DataFormat.PERCENT:
        return percent_to_raw(number, tr)
    if tr.sensor is None:
        raise CommError(ErrorKind.GARBAGE, f"ohms format on a non-RTD range {tr.describe()}")
    return engineering_to_raw(rtd_temperature(tr.sensor, number), tr)


def raw_to_text(
    raw: int,
    fmt: DataFormat,
    tr: TypeRange,
    *,
    hex_width: int = 4,
    signed_text: bool = True,
    round_up: bool = False,
) -> str:
    """A raw value as a module writes it (AI replies) or expects it (AO commands: ``round_up``)."""
    if fmt is DataFormat.HEX:
        return f"{raw & ((1 << (4 * hex_width)) - 1):0{hex_width}X}"
    if fmt is DataFormat.PERCENT:
        pct = raw_to_percent(raw, tr)
        if round_up:
            pct = math.ceil(pct * 100 - 1e-6) / 100
        return f"{pct:+07.2f}"
    value = raw_to_engineering(raw, tr)
    if fmt is DataFormat.OHMS:
        ohms = rtd_resistance(_sensor(tr), value)
        return format_number(ohms, tr.ohm_max or ohms)
    return format_number(value, tr.full_scale, signed_text, round_up)


def _sensor(tr: TypeRange) -> str:
    if tr.sensor is None:
        raise ValueError(f"ohms format on a non-RTD range {tr.describe()}")
    return tr.sensor


def ao_text_to_raw(text: str, fmt: DataFormat, tr: TypeRange) -> tuple[int, Quality]:
    """An AO command's data -> raw (the simulator side; engineering values truncate as modules do)."""
    if fmt is DataFormat.HEX:
        return clamp(parse_hex_word(text, tr.signed), tr)
    number = parse_number(text)
    if fmt is DataFormat.PERCENT:
        pmin, pmax = tr.percent_limits
        return clamp(
            math.floor((number - pmin) * (tr.hmax - tr.hmin) / (pmax - pmin) + tr.hmin + 1e-9), tr
        )
    return engineering_to_raw(number, tr, round_down=True)
