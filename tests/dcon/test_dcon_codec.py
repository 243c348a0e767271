"""DCON framing and reply parsing, with the checksum vectors of the public manuals."""

import pytest

from fieldgate import ErrorKind
from fieldgate.plugins.dcon import codec
from fieldgate.polling import CommError


@pytest.mark.parametrize(
    "text, expected",
    [
        ("$012", "B7"),  # I-7000 manuals, "checksum" section: $012 -> $012B7
        ("!01200600", "AA"),  # the reply in the same example: !01200600AA
    ],
)
def test_checksum_vectors_from_the_manuals(text, expected):
    assert codec.checksum(text) == expected
    assert codec.frame(text, True) == f"{text}{expected}\r".encode()


def test_checksum_is_the_byte_sum_modulo_256_in_upper_case_hex():
    assert codec.checksum("~**") == f"{(0x7E + 0x2A + 0x2A) & 0xFF:02X}" == "D2"
    assert codec.checksum("#01") == "84"  # 0x23 + 0x30 + 0x31 = 0x84
    assert codec.checksum("zzz") == f"{(3 * 0x7A) & 0xFF:02X}"  # wraps past 0xFF


def test_frame_without_checksum_is_text_and_cr():
    assert codec.frame("$012", False) == b"$012\r"


def test_unframe_checks_and_strips_the_checksum():
    assert codec.unframe(b"!01200600AA\r", True) == "!01200600"
    assert (
        codec.unframe(b"!01200600aa\r", True) == "!01200600"
    )  # lower-case hex accepted on receive
    with pytest.raises(CommError) as exc:
        codec.unframe(b"!01200600AB\r", True)
    assert exc.value.kind is ErrorKind.CRC


@pytest.mark.parametrize("raw", [b"!0120", b"\x00\xff!01\r", b"\r", b"!01\n\r", b"!\xe901\r"])
def test_unframe_rejects_garbage_and_truncation(raw):
    with pytest.raises(CommError) as exc:
        codec.unframe(raw, False)
    assert exc.value.kind is ErrorKind.GARBAGE


def test_checksum_frame_too_short_is_garbage():
    with pytest.raises(CommError) as exc:
        codec.unframe(b">\r", True)
    assert exc.value.kind is ErrorKind.GARBAGE


def test_commands_are_built_with_two_hex_address_digits():
    assert codec.command("$", 1, "2") == "$012"
    assert codec.command("#", 0xAB) == "#AB"
    assert codec.command("~", 0x0F, "1") == "~0F1"
    with pytest.raises(ValueError):
        codec.command("!", 1)
    with pytest.raises(ValueError):
        codec.command("$", 256)


def test_do_group_and_single_channel_commands():
    assert codec.set_do_group(1, 0x00, 0xFF) == "#0100FF"  # the manual's I-7044 example
    assert codec.set_do_group(2, 0x0B, 0x12) == "#020B12"
    assert codec.set_do_channel(1, 3, True) == "#011301"
    assert codec.set_do_channel(1, 10, False) == "#01B200"
    with pytest.raises(ValueError):
        codec.set_do_channel(1, 16, True)


def test_watchdog_setup_counts_tenths_of_a_second():
    assert codec.watchdog_setup(1, True, 2000) == "~013114"  # 20 x 0.1 s
    assert codec.watchdog_setup(2, False, 100) == "~023001"
    assert codec.watchdog_setup(3, True, 99_999) == "~0331FF"  # clamped to 25.5 s


def test_addressed_reply():
    assert codec.addressed("!01200600", 1) == "200600"
    with pytest.raises(CommError) as exc:
        codec.addressed("!02200600", 1)
    assert exc.value.kind is ErrorKind.WRONG_ADDRESS
    with pytest.raises(CommError) as exc:
        codec.addressed("?01", 1)
    assert exc.value.kind is ErrorKind.EXCEPTION
    with pytest.raises(CommError) as exc:
        codec.addressed(">0100", 1)
    assert exc.value.kind is ErrorKind.GARBAGE
    with pytest.raises(CommError) as exc:
        codec.addressed("!Z", 1)
    assert exc.value.kind is ErrorKind.GARBAGE


def test_data_replies():
    assert codec.data(">0F00") == "0F00"
    assert codec.data(">+05.123+04.153") == "+05.123+04.153"
    with pytest.raises(CommError) as exc:
        codec.data("?01", 1)
    assert exc.value.kind is ErrorKind.EXCEPTION
    with pytest.raises(CommError) as exc:
        codec.data("?03", 1)
    assert exc.value.kind is ErrorKind.WRONG_ADDRESS
    with pytest.raises(CommError) as exc:
        codec.data("!0F0000")
    assert exc.value.kind is ErrorKind.GARBAGE
    assert codec.status_data("!0F0000") == "0F0000"  # $AA6 of a digital module: no address


@pytest.mark.parametrize(
    "text, kind",
    [
        (">", None),
        ("!", ErrorKind.WATCHDOG),
        ("?", ErrorKind.EXCEPTION),
        (">00", ErrorKind.GARBAGE),
        ("#", ErrorKind.GARBAGE),
    ],
)
def test_write_acknowledgement(text, kind):
    if kind is None:
        codec.write_ack(text)
    else:
        with pytest.raises(CommError) as exc:
            codec.write_ack(text)
        assert exc.value.kind is kind


def test_config_reply():
    reply = codec.parse_config("!01080642", 1)
    assert (reply.type_code, reply.baud_code, reply.data_format, reply.checksum) == (
        0x08,
        0x06,
        2,
        True,
    )
    assert codec.BAUD_CODES[reply.baud_code] == 9600
    with pytest.raises(CommError) as exc:
        codec.parse_config("!010806", 1)
    assert exc.value.kind is ErrorKind.GARBAGE
    with pytest.raises(CommError) as exc:
        codec.parse_config("!0108G600", 1)
    assert exc.value.kind is ErrorKind.GARBAGE


def test_random_input_only_ever_raises_comm_error():
    """Bad input from the wire is counted, never an unexpected exception (fixed seed: reproducible)."""
    import random

    from fieldgate.plugins.dcon.formats import DataFormat, split_values, text_to_raw
    from fieldgate.plugins.dcon.profiles import find_profile
    from fieldgate.plugins.dcon.simulated import SimBus, SimModule
    from fieldgate.plugins.dcon.tables import TABLES

    rng = random.Random(6)
    alphabet = b"!?>$#@%~*0123456789ABCDEFabcdef+-.\r\x00\xff GXZ"
    profile, table = find_profile("I-7055"), TABLES["group-a"].get(0x08)
    bus = SimBus(checksum=False)
    for address, model in ((1, "I-7055"), (2, "I-7017"), (3, "I-7024"), (4, "I-7012")):
        bus.add(SimModule(find_profile(model), address))
    parsers = [
        lambda t: codec.addressed(t, 1),
        lambda t: codec.data(t, 1),
        lambda t: codec.status_data(t, 1),
        codec.write_ack,
        lambda t: codec.parse_config(t, 1),
        lambda t: profile.decode_dio(t[1:]),
        lambda t: split_values(t[1:], DataFormat.ENGINEERING, 2),
        lambda t: text_to_raw(t[1:], DataFormat.HEX, table),
        lambda t: text_to_raw(t[1:], DataFormat.ENGINEERING, table),
    ]
    for _ in range(3000):
        raw = bytes(rng.choice(alphabet) for _ in range(rng.randint(0, 14)))
        bus.feed(raw, 0.0)  # the simulator never raises either
        for checksum in (False, True):
            try:
                text = codec.unframe(raw + b"\r", checksum)
            except CommError:
                continue
            for parse in parsers:
                try:
                    parse(text)
                except CommError:
                    pass
