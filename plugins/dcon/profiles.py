"""Per-family command profiles of the DCON modules the I-7231D and I-7241D support.

The same mnemonic means different things on different families (``~AA5V`` on I-7000
digital modules, ``~AA5PPSS`` on the I-7011/7012 family, ``~AA5N`` on analog
outputs), so every module is polled through its profile. M-7000 modules in DCON mode
answer as the I-7000 module of the same number; ``D`` (display) and ``P``/``F``/``R``
variants share the profile of their base model.

Digital data layout of ``@AA`` (``>(data)``) and ``$AA6`` (``!(data)00``), one
reading of the I-7000 DIO manual's configuration table, ADAM-4000 compatible:
outputs first then inputs, two hex digits each, for mixed modules; a 16- or 32-bit
hex value (bit n = channel n) for modules with 9 or more channels of one kind; one
byte followed by ``00`` for modules with 8 or fewer channels of one kind.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from fieldgate.health import ErrorKind
from fieldgate.polling import CommError

from .codec import hex_field

# digital families
DIO = "dio"  # @AA / @AA(data) / ~AA5V
AIDIO = "aidio"  # I-7011/7012/7014/7016: @AADI / @AADO(data) / ~AA5PPSS
# analog output command styles
AO_SINGLE = "single"  # #AA(data): I-7021
AO_CHANNEL = "channel"  # #AAN(data): I-7022, I-7024, I-87022/24/26


@dataclass(frozen=True)
class Profile:
    model: str
    series: str  # "I-7000" or "I-87K"
    di: int = 0
    do: int = 0
    ai: int = 0
    ao: int = 0
    digital: str | None = None  # DIO or AIDIO
    do_chars: int = 2  # width of @AA(data)
    ai_table: str | None = None
    ao_table: str | None = None
    ao_style: str = AO_CHANNEL
    ao_hex_width: int = 4
    ao_signed_text: bool = True
    aliases: tuple[str, ...] = ()

    @property
    def description(self) -> str:
        parts = [
            f"{n} {k}"
            for n, k in ((self.di, "DI"), (self.do, "DO"), (self.ai, "AI"), (self.ao, "AO"))
            if n
        ]
        return ", ".join(parts)

    @property
    def has_digital(self) -> bool:
        return bool(self.di or self.do)

    # -- digital data ------------------------------------------------------------
    def dio_fields(self) -> list[tuple[str, int]]:
        """(kind, hex digits) of the ``@AA`` data: kind 'do', 'di' or 'pad'."""
        if self.di and self.do:
            return [("do", 2), ("di", 2)]
        kind, count = ("di", self.di) if self.di else ("do", self.do)
        if count <= 8:
            return [(kind, 2), ("pad", 2)]
        return [(kind, 4 if count <= 16 else 8)]

    def decode_dio(self, data: str) -> tuple[int, int]:
        """``@AA`` data -> (DO bits, DI bits)."""
        fields = self.dio_fields()
        if len(data) != sum(w for _, w in fields):
            raise CommError(
                ErrorKind.GARBAGE,
                f"{self.model}: digital data {data!r} should have {sum(w for _, w in fields)} hex digits",
            )
        values, pos = {"di": 0, "do": 0, "pad": 0}, 0
        for kind, width in fields:
            values[kind] = hex_field(data[pos : pos + width], f"{self.model} {kind}")
            pos += width
        return values["do"] & _mask(self.do), values["di"] & _mask(self.di)

    def encode_dio(self, do_bits: int, di_bits: int) -> str:
        values = {"do": do_bits & _mask(self.do), "di": di_bits & _mask(self.di), "pad": 0}
        return "".join(f"{values[kind]:0{width}X}" for kind, width in self.dio_fields())

    def encode_do(self, do_bits: int) -> str:
        return f"{do_bits & _mask(self.do):0{self.do_chars}X}"


def _mask(count: int) -> int:
    return (1 << count) - 1


def _dio(
    model: str, series: str, di: int, do: int, do_chars: int = 2, aliases: tuple[str, ...] = ()
) -> Profile:
    return Profile(model, series, di=di, do=do, digital=DIO, do_chars=do_chars, aliases=aliases)


def _ai(
    model: str,
    series: str,
    ai: int,
    table: str,
    aliases: tuple[str, ...] = (),
    di: int = 0,
    do: int = 0,
) -> Profile:
    return Profile(
        model,
        series,
        di=di,
        do=do,
        ai=ai,
        ai_table=table,
        digital=AIDIO if (di or do) else None,
        aliases=aliases,
    )


def _ao(
    model: str,
    series: str,
    ao: int,
    table: str,
    style: str = AO_CHANNEL,
    hex_width: int = 4,
    signed_text: bool = True,
) -> Profile:
    return Profile(
        model,
        series,
        ao=ao,
        ao_table=table,
        ao_style=style,
        ao_hex_width=hex_width,
        ao_signed_text=signed_text,
    )


S7, S87 = "I-7000", "I-87K"

PROFILES: tuple[Profile, ...] = (
    # I-7000 digital (do_chars: the I-7000 DIO manual's @AA(data) widths)
    _dio("I-7041", S7, 14, 0, aliases=("7041P",)),
    _dio("I-7042", S7, 0, 13, 4),
    _dio("I-7043", S7, 0, 16, 4),
    _dio("I-7044", S7, 4, 8, 2),
    _dio("I-7045", S7, 0, 16, 4),
    _dio("I-7050", S7, 7, 8, 2),
    _dio("I-7051", S7, 16, 0),
    _dio("I-7052", S7, 8, 0),
    _dio("I-7053", S7, 16, 0, aliases=("7053P",)),
    _dio("I-7055", S7, 8, 8, 2),
    _dio("I-7058", S7, 8, 0),
    _dio("I-7060", S7, 4, 4, 1),
    _dio("I-7063", S7, 8, 3, 1, aliases=("7063A", "7063B")),
    _dio("I-7065", S7, 4, 5, 2, aliases=("7065A", "7065B")),
    _dio("I-7066", S7, 0, 7, 2),
    _dio("I-7067", S7, 0, 7, 2),
    # I-7000 analog input (with the DI/DO of the I-7011/7012/7014/7016 family)
    _ai("I-7011", S7, 1, "group-c", ("7011P",), di=1, do=2),
    _ai("I-7012", S7, 1, "group-a", ("7012F",), di=1, do=2),
    _ai("I-7014", S7, 1, "group-a", di=1, do=2),
    _ai("I-7016", S7, 2, "strain", di=1, do=4),
    _ai("I-7016P", S7, 1, "strain", di=1, do=4),
    _ai("I-7013", S7, 1, "rtd"),
    _ai("I-7015", S7, 6, "rtd"),
    _ai("I-7017", S7, 8, "group-a", ("7017F", "7017C", "7017R", "7017RC")),
    _ai("I-7018", S7, 8, "group-c", ("7018P", "7018R", "7018BL")),
    _ai("I-7019", S7, 8, "universal", ("7019R",)),
    _ai("I-7033", S7, 3, "rtd"),
    # I-7000 analog output
    _ao("I-7021", S7, 1, "ao-12bit", AO_SINGLE, 3, False),
    _ao("I-7022", S7, 2, "ao-12bit", AO_CHANNEL, 3, False),
    _ao("I-7024", S7, 4, "ao-7024"),
    # I-87K
    _ai("I-87013", S87, 4, "rtd"),
    _ai("I-87016", S87, 2, "strain"),
    _ai("I-87017", S87, 8, "group-a", ("87017R",)),
    _ai("I-87018", S87, 8, "group-c", ("87018R",)),
    _ai("I-87019", S87, 8, "universal", ("87019R",)),
    _ao("I-87022", S87, 2, "ao-12bit", AO_CHANNEL, 3, False),
    _ao("I-87024", S87, 4, "ao-7024"),
    _ao("I-87026", S87, 2, "ao-87026"),
    _dio("I-87040", S87, 32, 0),
    _dio("I-87041", S87, 0, 32, 8),
    _dio("I-87051", S87, 16, 0),
    _dio("I-87052", S87, 8, 0),
    _dio("I-87053", S87, 16, 0),
    _dio("I-87054", S87, 8, 8),
    _dio("I-87055", S87, 8, 8),
    _dio("I-87057", S87, 0, 16, 4),
    _dio("I-87058", S87, 8, 0),
    _dio("I-87063", S87, 4, 4),
    _dio("I-87064", S87, 0, 8),
    _dio("I-87065", S87, 0, 8),
    _dio("I-87066", S87, 0, 8),
    _dio("I-87068", S87, 0, 8),
    _dio("I-87069", S87, 0, 8),
)

_INDEX: dict[str, Profile] = {}
for _p in PROFILES:
    _INDEX[_p.model[2:]] = _p
    for _alias in _p.aliases:
        _INDEX[_alias] = _p


def normalize(name: str) -> str:
    """'I-7017RC', 'M-7055D', '7053D', '87017' -> the bare model text ('7017RC', '7055D', ...)."""
    text = name.strip().upper().replace(" ", "")
    text = re.sub(r"^(?:[IM]-?|TM-?)", "", text)
    return text.split("-", 1)[0]  # '7017R-A5' -> '7017R'


def find_profile(name: str) -> Profile | None:
    """The profile for a model name from the topology or from ``$AAM`` (suffix letters tolerated)."""
    text = normalize(name)
    while text:
        if text in _INDEX:
            return _INDEX[text]
        if not text[-1].isalpha():
            break
        text = text[:-1]
    return None


def model_names() -> list[str]:
    return [p.model for p in PROFILES]
