"""The CiA 401 objects of a front as data: one row per object, one builder.

Each row (:class:`~..cia301.entries.ObjectSpec`) names the object, its entries, their type
and access, the channels it serves (``di``/``do`` bytes, ``ai``/``ao`` channels) and the
:class:`~.profile.Profile401` functions that read and write an entry;
:func:`~..cia301.entries.build_objects` makes the dictionary's objects of them. The
interrupt objects 0x6421-0x6426 are :mod:`.analog`'s table (``interrupt`` mode only), the
bit objects 0x6020-/0x6220- are made per 128 channels (``bit_mapping``), the special bytes
0x3000/0x3200 are the NA-9161's (:mod:`..na9161.special`).
"""

from __future__ import annotations

from functools import partial

from ..cia301.abort import VALUE_RANGE
from ..cia301.entries import (
    BOOLEAN,
    INTEGER16,
    INTEGER32,
    UNSIGNED8,
    Abort,
    ObjectDef,
    ObjectSpec,
    build_objects,
    item,
)
from .analog import INTERRUPT_OBJECTS
from .layouts import AI_OBJECT, AO_OBJECT, DI_OBJECT, DO_OBJECT
from .profile import BITS_PER_OBJECT, DI_BIT_OBJECT, DO_BIT_OBJECT, Profile401

DI_POLARITY, DO_ERROR_MODE, DO_ERROR_VALUE, DO_FILTER = 0x6002, 0x6206, 0x6207, 0x6208
AO_ERROR_MODE, AO_ERROR_VALUE = 0x6443, 0x6444

P = Profile401

# A documented table, not code to read line by line: (index, object name, entry name ({n}:
# the sub-index), data type, access, the channels it serves, read, write); ``default``
# None is the value when built, ``mappable`` entries may be mapped into PDOs.
# fmt: off
PROFILE_OBJECTS: tuple[ObjectSpec[Profile401], ...] = (
    ObjectSpec(DI_OBJECT, "Read input 8-bit", "Read input 8-bit {n}", UNSIGNED8, "ro", "di",
               P.read_di, default=0, mappable=True),
    ObjectSpec(DI_POLARITY, "Polarity input 8-bit", "Polarity input 8-bit {n}", UNSIGNED8, "rw",
               "di", *item("polarity"), default=0),
    ObjectSpec(DO_OBJECT, "Write output 8-bit", "Write output 8-bit {n}", UNSIGNED8, "rw", "do",
               P.read_do, P.write_do, mappable=True),
    ObjectSpec(DO_ERROR_MODE, "Error mode output 8-bit", "Error mode output 8-bit {n}", UNSIGNED8,
               "rw", "do", P.do_error_modes, lambda p, n, v: p.write_do_error(n, v, mode=True)),
    ObjectSpec(DO_ERROR_VALUE, "Error value output 8-bit", "Error value output 8-bit {n}",
               UNSIGNED8, "rw", "do", P.do_error_values,
               lambda p, n, v: p.write_do_error(n, v, mode=False)),
    ObjectSpec(DO_FILTER, "Filter mask output 8-bit", "Filter mask output 8-bit {n}", UNSIGNED8,
               "rw", "do", *item("filter")),
    ObjectSpec(AI_OBJECT, "Read analog input 16-bit", "Read analog input {n}", INTEGER16, "ro",
               "ai", P.read_ai, default=0, mappable=True),
    ObjectSpec(AO_OBJECT, "Write analog output 16-bit", "Write analog output {n}", INTEGER16,
               "rw", "ao", P.read_ao, P.write_ao, mappable=True),
    ObjectSpec(AO_ERROR_MODE, "Analog output error mode", "Error mode {n}", UNSIGNED8, "rw", "ao",
               P.ao_error_mode, P.write_ao_error_mode),
    ObjectSpec(AO_ERROR_VALUE, "Analog output error value", "Error value {n}", INTEGER32, "rw",
               "ao", P.ao_error_value, P.write_ao_error_value),
)
# fmt: on


def _u16_to_u8(data: bytes) -> bytes:
    """A 2-byte write to 0x6443 (the ICP DAS manuals print it UNSIGNED16; CiA 401: UNSIGNED8)."""
    if data[1]:
        raise Abort(VALUE_RANGE, "0x6443: 0 = keep the value, 1 = go to the error value")
    return data[:1]


def _i16_to_i32(data: bytes) -> bytes:
    """A 2-byte write to 0x6444 (printed U16 by the ICP DAS and NA-9161 manuals; CiA 401:
    INTEGER32): the 16-bit raw value, sign-extended as 0x6411's INTEGER16 is."""
    return int.from_bytes(data, "little", signed=True).to_bytes(4, "little", signed=True)


SHORT_WRITES = {AO_ERROR_MODE: _u16_to_u8, AO_ERROR_VALUE: _i16_to_i32}  # a style may take them


def _bit_name(verb: str, sub: int, n: int) -> str:
    return f"{verb} bit {n + 1}"


def _these(bits: range, over: str) -> range:
    return bits


def _bit_objects(profile: Profile401) -> list[ObjectDef]:
    """0x6020-0x6027 / 0x6220-0x6227: one BOOLEAN entry per digital channel, 128 per object."""
    objects: list[ObjectDef] = []
    lay = profile.layout
    for base, n_bits, verb, spec in (
        (DI_BIT_OBJECT, 8 * len(lay.di_bytes), "Read input", (P.read_di_bit, None, 0)),
        (
            DO_BIT_OBJECT,
            8 * len(lay.do_bytes),
            "Write output",
            (P.read_do_bit, P.write_do_bit, None),
        ),
    ):
        get, put, default = spec
        for offset in range((n_bits + BITS_PER_OBJECT - 1) // BITS_PER_OBJECT):
            first = offset * BITS_PER_OBJECT
            row = ObjectSpec(
                base + offset,
                f"{verb} bit {first + 1} to {first + BITS_PER_OBJECT}",
                partial(_bit_name, verb),
                BOOLEAN,
                "ro" if put is None else "rw",
                "bits",
                get,
                put,
                default=default,
                mappable=True,
            )
            bits = range(first, min(n_bits, first + BITS_PER_OBJECT))
            objects += build_objects(profile, (row,), partial(_these, bits))
    return objects


def cia401_objects(profile: Profile401) -> list[ObjectDef]:
    """Every CiA 401 object of the profile's layout."""
    objects = build_objects(profile, PROFILE_OBJECTS, profile.items)
    analog = profile.analog
    if analog.mode == "interrupt" and profile.layout.ai:
        objects += build_objects(
            analog,
            INTERRUPT_OBJECTS,
            lambda over: analog.banks if over == "banks" else profile.items(over),
        )
    if profile.bit_objects:
        objects += _bit_objects(profile)
    return objects
