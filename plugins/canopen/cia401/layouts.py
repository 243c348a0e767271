"""How a front's channels become CiA 401 objects and default PDO mappings.

Two styles, chosen per front with ``style:``:

``icpdas`` (I-7232D / I-7231D, seed-000 §2.7 and §3.7, seed-001 §2.2 and §4.6)
    Modules by ascending address, digital channels packed per module into whole bytes
    (a module never shares a byte). PDO1 carries the digital bytes 1-8, PDO2/3/4 carry
    analog channels 1-4 / 5-8 / 9-12. Digital bytes beyond 8 go to PDO5 and up (8 per
    PDO), analog channels beyond 12 go to the PDOs after those (4 per PDO). PDO1-4 keep
    their predefined COB-IDs even when empty; overflow PDOs start invalid
    (0x80000000, as the seeds' tables print). Type 255, no inhibit time.
    ``mapping_closed`` (the I-7232D utility's "Tx/RxPDO Mapping Closed"): when a
    direction has no digital channels its analog channels fill PDO1, 2, 3, ... without
    the gap at PDO1.

``na9161`` (CREVIS NA-9161, seed-004 §2)
    Digital bits packed across modules into one stream (``compressed``, the default) or
    one fresh byte per module. PDO1 = digital bytes 1-8, PDO2 = analog channels 1-4, the
    rest in later PDOs, digital before analog, a new PDO for each data type. PDO1/PDO2
    are valid only when they carry data; PDO3 and up start invalid. Type 254, TPDO
    inhibit time 5000 x 100 us (500 ms).

Special channels (``si``/``so``: the raw byte blocks of modules such as a high-speed
counter) go to 0x3000 (inputs) / 0x3200 (outputs) in both styles, byte after byte in
slot order (sub n = byte n-1), never into the default PDO mapping (seed-004 §2.2).
A module's digital channels are in the digital area in both packing modes, whatever
else it has ([AMBIG-10]: a counter block declared without digital channels has none).

Limits of ``na9161`` (seed-004 §2.6): 32 slots, 64 bytes of image per direction
(analog words, digital bytes and special bytes together); more is a :class:`LayoutError`.

Slots (``na9161``, at most 32): the front's modules in order, numbered from 1. A slot
named in ``inactive`` (0x4500:3) keeps its number and its 0x2010-/0x4503 entries, but
its channels are left out of every I/O object: the next slots move up.

The result is a :class:`IoLayout` (what 0x6000/0x6200/0x6401/0x6411 and 0x2000 hold)
and a :class:`PdoDefaults` per direction (what 0x1400-/0x1600-/0x1800-/0x1A00- hold
after a reset).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

from fieldgate.image import Channel, Kind
from fieldgate.layout import of_kind, pack_bits

from ..cia301.pdo.defaults import PdoDefault, PdoDefaults, PdoSetting, mapping_entry

Style = Literal["icpdas", "na9161"]

DI_OBJECT, DO_OBJECT, AI_OBJECT, AO_OBJECT = 0x6000, 0x6200, 0x6401, 0x6411
SI_OBJECT, SO_OBJECT = 0x3000, 0x3200  # NA-9161 special areas: one byte per sub-index
MAX_SLOTS = 32  # NA-9161 expansion slots (0x4500:3 has a bit for each)
MAX_IMAGE_BYTES = 64  # NA-9161 process image per direction (seed-004 §1.2, §2.6)
DIGITAL_PER_PDO = 8  # bytes
ANALOG_PER_PDO = 4  # 16-bit channels
TPDO_BASES = (0x180, 0x280, 0x380, 0x480)
RPDO_BASES = (0x200, 0x300, 0x400, 0x500)
STYLE_PDO_COUNT = {"icpdas": 32, "na9161": 8}
DEVICE_PROFILE_401 = 0x0191
IO_KINDS = (Kind.DI, Kind.DO, Kind.AI, Kind.AO)  # the order of the 0x1000 bits 16-19


class LayoutError(ValueError):
    """The channels do not fit the PDOs or objects of the style."""


@dataclass(frozen=True)
class ModuleRef:
    """One module a front exposes, in 0x2000 sub-index order."""

    back: str
    address: int
    model: str = ""
    di: int = 0
    do: int = 0
    ai: int = 0
    ao: int = 0
    si: int = 0
    so: int = 0


@dataclass
class IoLayout:
    di_bytes: list[list[Channel | None]]
    do_bytes: list[list[Channel | None]]
    ai: list[Channel]
    ao: list[Channel]
    modules: list[ModuleRef]
    si: list[Channel] = field(default_factory=list)  # 0x3000 sub n = si[n - 1]
    so: list[Channel] = field(default_factory=list)  # 0x3200 sub n = so[n - 1]
    compressed: bool = True  # the packing the digital bytes were built with
    inactive: frozenset[int] = frozenset()  # deactivated slots (1-based), left out

    @property
    def device_type(self) -> int:
        return device_type(
            {
                kind
                for kind, present in zip(
                    IO_KINDS, (self.di_bytes, self.do_bytes, self.ai, self.ao), strict=True
                )
                if present
            }
        )


def device_type(kinds: set[Kind]) -> int:
    """0x1000: profile 401 (0x0191) plus bit 16/17/18/19 when DI/DO/AI/AO are served (I-7232D rule)."""
    return DEVICE_PROFILE_401 | sum(
        1 << (16 + i) for i, kind in enumerate(IO_KINDS) if kind in kinds
    )


def build_layout(
    channels: Sequence[Channel],
    style: Style = "icpdas",
    *,
    compressed: bool = True,
    models: dict[tuple[str, int], str] | None = None,
    inactive: frozenset[int] = frozenset(),
) -> IoLayout:
    """Place a front's channels (in the seeds' default order) into the CiA 401 objects.

    ``inactive``: slots (1-based module positions) whose channels are left out.
    """
    ordered = list(channels)  # the front's order: its expose list, or backs then ascending address
    modules = _modules(ordered, models or {})
    if style == "na9161" and len(modules) > MAX_SLOTS:
        raise LayoutError(
            f"{len(modules)} modules exceed the {MAX_SLOTS} slots of an NA-9161-style head"
        )
    if inactive:
        dropped = {(m.back, m.address) for n, m in enumerate(modules, 1) if n in inactive}
        ordered = [c for c in ordered if (c.source.back, c.source.module) not in dropped]
    per_module = style == "icpdas" or not compressed
    layout = IoLayout(
        di_bytes=pack_bits(of_kind(ordered, Kind.DI), per_module=per_module),
        do_bytes=pack_bits(of_kind(ordered, Kind.DO), per_module=per_module),
        ai=of_kind(ordered, Kind.AI),
        ao=of_kind(ordered, Kind.AO),
        modules=modules,
        si=of_kind(ordered, Kind.SI),
        so=of_kind(ordered, Kind.SO),
        compressed=not per_module,
        inactive=frozenset(inactive),
    )
    if style == "na9161":
        for direction, analog, digital, special in (
            ("inputs", layout.ai, layout.di_bytes, layout.si),
            ("outputs", layout.ao, layout.do_bytes, layout.so),
        ):
            size = 2 * len(analog) + len(digital) + len(special)
            if size > MAX_IMAGE_BYTES:
                raise LayoutError(
                    f"the {direction} need {size} bytes ({len(analog)} analog channels, "
                    f"{len(digital)} digital bytes, {len(special)} special bytes); an NA-9161-style "
                    f"head holds {MAX_IMAGE_BYTES} per direction"
                )
    for name, count, limit in (
        ("DI bytes", len(layout.di_bytes), 254),
        ("DO bytes", len(layout.do_bytes), 254),
        ("AI channels", len(layout.ai), 254),
        ("AO channels", len(layout.ao), 254),
        ("special input bytes", len(layout.si), 254),
        ("special output bytes", len(layout.so), 254),
        ("modules", len(layout.modules), 254),
    ):
        if count > limit:
            raise LayoutError(f"{count} {name} exceed the {limit} sub-indices of one object")
    return layout


def _modules(channels: Sequence[Channel], models: dict[tuple[str, int], str]) -> list[ModuleRef]:
    counts: dict[tuple[str, int], dict[Kind, int]] = {}
    for c in channels:
        counts.setdefault((c.source.back, c.source.module), {k: 0 for k in Kind})[c.kind] += 1
    return [
        ModuleRef(
            back,
            address,
            models.get((back, address), ""),
            n[Kind.DI],
            n[Kind.DO],
            n[Kind.AI],
            n[Kind.AO],
            n[Kind.SI],
            n[Kind.SO],
        )
        for (back, address), n in counts.items()
    ]


# -- default PDOs ---------------------------------------------------------------------


def _chunks(items: list[int], size: int) -> list[list[int]]:
    return [items[i : i + size] for i in range(0, len(items), size)]


def _plan(
    n_digital: int, n_analog: int, count: int, style: Style, closed: bool
) -> list[list[tuple[str, int]]]:
    """Which objects each PDO of one direction carries: lists of ("d", byte) / ("a", channel)."""
    digital = [
        [("d", i) for i in chunk]
        for chunk in _chunks(list(range(1, n_digital + 1)), DIGITAL_PER_PDO)
    ]
    analog = [
        [("a", i) for i in chunk] for chunk in _chunks(list(range(1, n_analog + 1)), ANALOG_PER_PDO)
    ]
    slots: list[list[tuple[str, int]]] = []
    if style == "icpdas":
        if closed and not digital:
            slots = analog
        else:
            slots = [digital[0] if digital else []] + analog[:3]
            if len(analog) > 3 or len(digital) > 1:
                slots += [[]] * (4 - len(slots)) + digital[1:] + analog[3:]
    else:
        slots = (
            [digital[0] if digital else [], analog[0] if analog else []] + digital[1:] + analog[1:]
        )
    while slots and not slots[-1]:
        slots.pop()
    if len(slots) > count:
        raise LayoutError(
            f"the default mapping needs {len(slots)} PDOs per direction, only {count} exist"
        )
    return slots


def default_pdos(
    layout: IoLayout,
    style: Style = "icpdas",
    *,
    count: int | None = None,
    mapping_closed: bool = False,
    empty_invalid: bool = False,
    tpdo_settings: dict[int, PdoSetting] | None = None,
    rpdo_settings: dict[int, PdoSetting] | None = None,
    analog_event_timer_ms: int = 0,
) -> PdoDefaults:
    """``analog_event_timer_ms`` (a master that needs analog data to keep flowing, the Delta
    AS300's REQ-AS-15): the event timer of every event-driven TPDO that maps analog inputs,
    where the style gives none. ``empty_invalid`` (a master that waits for every valid PDO, the Delta AS300): a PDO
    with nothing mapped starts invalid whatever the style says. ``tpdo_settings`` /
    ``rpdo_settings`` (PDO number -> :class:`PdoSetting`, the topology's ``tpdos:`` /
    ``rpdos:``) replace the style's values last; a number beyond ``count`` is a
    :class:`LayoutError`."""
    count = count or STYLE_PDO_COUNT[style]
    result = PdoDefaults([], [])
    for direction, bases, digital, analog, d_obj, a_obj in (
        ("t", TPDO_BASES, len(layout.di_bytes), len(layout.ai), DI_OBJECT, AI_OBJECT),
        ("r", RPDO_BASES, len(layout.do_bytes), len(layout.ao), DO_OBJECT, AO_OBJECT),
    ):
        plan = _plan(digital, analog, count, style, mapping_closed)
        pdos = result.tpdo if direction == "t" else result.rpdo
        for n in range(count):
            objects = plan[n] if n < len(plan) else []
            entries = [
                mapping_entry(d_obj, i, 8) if kind == "d" else mapping_entry(a_obj, i, 16)
                for kind, i in objects
            ]
            base = bases[n] if n < len(bases) else None
            if style == "icpdas":
                valid = base is not None and (bool(entries) or not empty_invalid)
                pdo = PdoDefault(base, valid, 255, entries=entries)
            else:
                pdo = PdoDefault(
                    base if n < 2 else None,
                    n < 2 and bool(entries),
                    254,
                    inhibit=5000 if direction == "t" else 0,
                    entries=entries,
                )
            if (
                direction == "t"
                and analog_event_timer_ms
                and any(kind == "a" for kind, _ in objects)
                and pdo.trans_type >= 254
                and not pdo.event_timer
            ):
                pdo.event_timer = analog_event_timer_ms
            pdos.append(pdo)
        given = (tpdo_settings if direction == "t" else rpdo_settings) or {}
        for number, setting in sorted(given.items()):
            if not 1 <= number <= count:
                raise LayoutError(
                    f"{'T' if direction == 't' else 'R'}PDO{number}: this front has PDOs 1..{count} (pdo_count)"
                )
            pdos[number - 1] = setting.apply(pdos[number - 1])
    return result
