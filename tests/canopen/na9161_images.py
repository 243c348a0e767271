"""The NA-9161 manual's example images (seed-004 §2, TV-17..TV-21): modules, their input
values and the output values its RPDO vectors write; shared by the CiA 401 layout tests and
the NA-9161 special-module tests. Not a test module."""

from __future__ import annotations

from io_bench import BACK, Kind, make_image

from fieldgate.image import channel_id


def set_bits(image, address, kind, value, count):
    for i in range(count):
        cid = channel_id(BACK, address, kind, i)
        if kind.is_output:
            image.write_output(cid, bool(value >> i & 1))
        else:
            image.update_input(cid, bool(value >> i & 1))


NA_INPUTS = [
    (1, 4, 0, 0, 0),
    (2, 8, 0, 0, 0),
    (3, 0, 0, 2, 0),
    (4, 16, 0, 0, 0),
    (5, 4, 0, 0, 0),
    (6, 8, 0, 0, 0),
    (7, 4, 0, 0, 0),
    (8, 0, 0, 2, 0),
    (9, 16, 0, 0, 0),
]
NA_DI_VALUES = {
    1: (0xA, 4),
    2: (0x5C, 8),
    4: (0xBEEF, 16),
    5: (0x3, 4),
    6: (0x81, 8),
    7: (0x6, 4),
    9: (0x1234, 16),
}


def na_inputs(extra=()):
    image = make_image(NA_INPUTS + list(extra))
    for address, (value, count) in NA_DI_VALUES.items():
        set_bits(image, address, Kind.DI, value, count)
    for cid, value in (
        ("bus/m3/ai0", 0x1234),
        ("bus/m3/ai1", 0x0FFF),
        ("bus/m8/ai0", 0),
        ("bus/m8/ai1", -0x7FFF),
    ):
        image.update_input(cid, value)
    return image


NA_OUTPUTS = [
    (1, 0, 4, 0, 0),
    (2, 0, 8, 0, 0),
    (3, 0, 0, 0, 2),
    (4, 0, 16, 0, 0),
    (5, 0, 4, 0, 0),
    (6, 0, 8, 0, 0),
    (7, 0, 2, 0, 0),
    (8, 0, 2, 0, 0),
    (9, 0, 0, 0, 2),
    (10, 0, 16, 0, 0),
]
NA_DO_VALUES = {
    1: (0x5, 4),
    2: (0xF0, 8),
    4: (0x1234, 16),
    5: (0xC, 4),
    6: (0xAA, 8),
    7: (0b01, 2),
    8: (0b10, 2),
    10: (0xCAFE, 16),
}


def do_value(image, address, count):
    return sum(int(image.value(channel_id(BACK, address, Kind.DO, i))) << i for i in range(count))
