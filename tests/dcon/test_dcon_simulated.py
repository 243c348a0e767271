"""The simulated modules, sans-I/O: exact replies, silence on bad input, host watchdog, faults."""

import pytest

from fieldgate.plugins.dcon import codec
from fieldgate.plugins.dcon.formats import DataFormat
from fieldgate.plugins.dcon.profiles import find_profile
from fieldgate.plugins.dcon.simulated import Fault, SimBus, SimModule, Wire


def bus(*modules, checksum=False):
    b = SimBus(checksum=checksum)
    for address, model, *rest in modules:
        b.add(SimModule(find_profile(model), address, **(rest[0] if rest else {})))
    return b


def ask(b, text, now=0.0, checksum=None):
    use = b.checksum if checksum is None else checksum
    replies = b.feed(codec.frame(text, use), now)
    if not replies:
        return None
    ((raw, _delay),) = replies
    return codec.unframe(raw, b.checksum)


def test_identity_config_and_reset_status():
    b = bus((1, "I-7017", {"type_code": 0x08}))
    assert ask(b, "$01M") == "!017017"
    assert ask(b, "$012") == "!01080602"  # type 08, 9600 bit/s, hex format
    assert ask(b, "$01F").startswith("!01")
    assert (
        ask(b, "$015") == "!011" and ask(b, "$015") == "!010"
    )  # 1 only on the first read after power-on


def test_silence_on_unknown_commands_addresses_and_noise():
    b = bus((1, "I-7053"))
    assert ask(b, "$01Q") is None
    assert ask(b, "$022") is None  # nobody at 02
    assert ask(b, "@01FF") is None  # a DI-only module has no outputs
    assert b.feed(b"\x00\xffjunk\r", 0.0) == []
    assert b.dropped == 1  # the noise frame
    assert b.feed(b"$0", 0.0) == []  # a frame split over two reads is joined
    assert ask(b, "12") == "!01400600"


def test_checksum_line_ignores_frames_with_bad_or_missing_checksum():
    b = bus((1, "I-7060"), checksum=True)
    assert ask(b, "$012") == "!01400640"  # checksum bit 6 set in FF
    assert b.feed(b"$012\r", 0.0) == []  # no checksum: silence
    assert b.feed(b"$0120\r", 0.0) == []  # wrong checksum: silence
    raw, _ = b.feed(b"$012B7\r", 0.0)[0]
    assert raw.endswith(codec.checksum(raw[:-3].decode()).encode() + b"\r")


@pytest.mark.parametrize(
    "model, write, readback",
    [
        ("I-7060", "@01A", ">0A00"),
        ("I-7044", "@0181", ">8100"),
        ("I-7043", "@01F00F", ">F00F"),
        ("I-87041", "@0180000001", ">80000001"),
        ("I-7067", "@017F", ">7F00"),
    ],
)
def test_digital_outputs_and_readback(model, write, readback):
    b = bus((1, model))
    assert ask(b, write) == ">"
    assert ask(b, "@01") == readback
    assert ask(b, "$016") == "!" + readback[1:] + "00"


def test_digital_output_errors():
    b = bus((1, "I-7060"))
    assert ask(b, "@0110") == "?"  # two characters for a one-character module
    assert ask(b, "@01G") is None  # not hex: silence
    b = bus((1, "I-7065"))  # 5 outputs
    assert ask(b, "@0120") == "?"


def test_do_group_and_channel_commands():
    b = bus((1, "I-7043"))
    assert ask(b, "#010A34") == ">" and ask(b, "#010B12") == ">"
    assert ask(b, "@01") == ">1234"
    assert ask(b, "#011701") == ">" and ask(b, "#01B700") == ">"
    assert ask(b, "@01") == ">12B4"
    assert ask(b, "#011702") == "?"


def test_analog_inputs_in_each_format():
    b = bus(
        (1, "I-7017", {"type_code": 0x08}),
        (2, "I-7012", {"type_code": 0x08, "data_format": DataFormat.ENGINEERING}),
        (3, "I-7013", {"data_format": DataFormat.OHMS}),
        (4, "I-7018", {"type_code": 0x0E, "data_format": DataFormat.PERCENT}),
    )
    b.modules[1].ai_raw = [0x1234, -1, 0, 0, 0, 0, 0, 0x7FFF]
    assert ask(b, "#01") == ">" + "1234" + "FFFF" + "0000" * 5 + "7FFF"
    assert ask(b, "#017") == ">7FFF" and ask(b, "#018") == "?01"
    b.modules[2].ai_raw = [0x3FF5]
    assert ask(b, "#02") == ">+04.997"
    b.modules[3].ai_raw = [0]  # 0 degC on -100..100
    assert ask(b, "#03") == ">+100.00"
    b.modules[4].ai_raw[0] = -9054  # J thermocouple at -210 degC
    assert ask(b, "#040") in (">-027.63", ">-027.64")


def test_aidio_family_commands():
    b = bus((1, "I-7012"))
    b.modules[1].di_bits = 1
    assert ask(b, "@01DO03") == "!01"
    assert ask(b, "@01DI") == "!0100301"
    assert ask(b, "@01DO07") == "?01"  # only 2 outputs
    assert ask(b, "~0150102") == "!01"  # ~AA5PPSS: power-on 01, safe 02
    assert ask(b, "~014") == "!010102"


def test_analog_outputs():
    b = bus((1, "I-7021"), (2, "I-7024", {"data_format": DataFormat.ENGINEERING}))
    assert ask(b, "#017FF") == ">" and b.modules[1].ao_raw == [0x7FF]
    assert ask(b, "#0117FF") is None or b.modules[1].ao_raw == [
        0x7FF
    ]  # a single-channel module takes no channel digit
    assert ask(b, "#021+05.000") == ">" and b.modules[2].ao_raw[1] == 16383
    assert ask(b, "#025+05.000") == "?"  # no channel 5
    assert ask(b, "#020+11.000") == "?"  # out of range


def test_host_watchdog_timeout_safe_values_and_recovery():
    b = bus((1, "I-7055"))
    m = b.modules[1]
    assert ask(b, "@0103") == ">" and ask(b, "~015S", 0.0) == "!01"  # 0x03 becomes the safe value
    assert ask(b, "~014S") == "!0103"
    assert ask(b, "@01F0") == ">"
    assert ask(b, "~013105", 0.0) == "!01"  # enable, 0.5 s
    assert ask(b, "~012") == "!01105"
    b.feed(codec.frame("~**", False), 0.4)  # host OK, no reply
    assert b.tick(0.8) == [] and m.do_bits == 0xF0
    assert b.tick(1.0) == [1] and m.do_bits == 0x03  # 0.6 s without ~**: safe value
    assert ask(b, "~010", 1.0) == "!0184"  # timeout bit 2 + enabled bit 7
    assert ask(b, "@01FF", 1.1) == "!" and m.do_bits == 0x03 and m.ignored_writes == 1
    b.feed(codec.frame("~**", False), 1.2)
    assert ask(b, "@01FF", 1.3) == "!"  # host OK does not clear the flag
    assert ask(b, "~011", 1.4) == "!01" and ask(b, "~010", 1.4) == "!0180"
    assert ask(b, "@01FF", 1.5) == ">" and m.do_bits == 0xFF
    m.power_cycle(2.0)
    assert m.do_bits == 0  # power-on value (never set): 0


def test_power_cycle_while_timed_out_loads_the_safe_value():
    b = bus((1, "I-7060"))
    m = b.modules[1]
    ask(b, "@0105"[:4])
    m.safe_do, m.power_on_do, m.timed_out = 0x9, 0x6, True
    m.power_cycle(0.0)
    assert m.do_bits == 0x9
    m.timed_out = False
    m.power_cycle(0.0)
    assert m.do_bits == 0x6


def test_ao_safe_and_power_on_latches():
    b = bus((1, "I-7022"))
    assert ask(b, "#011800") == ">" and ask(b, "~0151") == "!01" and ask(b, "$0141") == "!01"
    assert b.modules[1].safe_ao == [0, 0x800] and b.modules[1].power_on_ao == [0, 0x800]
    ask(b, "~013101", 0.0)
    b.tick(0.5)
    assert ask(b, "#010FFF", 0.6) == "!"


def test_faults():
    b = bus((1, "I-7052"), (2, "I-7052"), checksum=True)
    b.faults.append(Fault("silence", 1, count=1))
    assert ask(b, "@01") is None and ask(b, "@01") == ">0000"  # count 1: once
    b.faults.append(Fault("bad-checksum", 2))
    raw, _ = b.feed(codec.frame("@02", True), 0.0)[0]
    with pytest.raises(codec.CommError):
        codec.unframe(raw, True)
    b.faults[:] = [Fault("delay", None, delay=0.3)]
    assert b.feed(codec.frame("@01", True), 0.0)[0][1] == 0.3
    b.faults[:] = [Fault("wrong-address", 1)]
    raw, _ = b.feed(codec.frame("$012", True), 0.0)[0]
    assert codec.unframe(raw, True).startswith("!02")
    b.faults[:] = [Fault("truncate", 1)]
    raw, _ = b.feed(codec.frame("$01M", True), 0.0)[0]
    assert not raw.endswith(b"\r")


def test_wires_copy_outputs_to_inputs():
    b = bus((1, "I-7043"), (2, "I-7053"), (3, "I-7021"), (4, "I-7012", {"type_code": 0x08}))
    b.wires += [Wire((1, "do", n), (2, "di", n), invert=True) for n in range(16)] + [
        Wire((3, "ao", 0), (4, "ai", 0))
    ]
    ask(b, "@011234")
    assert b.modules[2].di_bits == 0xEDCB  # the I-7231D demo: DI = NOT DO
    ask(b, "#037FF")
    assert abs(b.modules[4].ai_raw[0] - 0x3FF5) < 10  # 0x7FF ~ 5 V ~ 0x3FF5 on +/-10 V


def test_config_change_moves_the_module():
    b = bus((1, "I-7017"))
    assert ask(b, "%0105090602") == "!05"
    assert ask(b, "$052") == "!05090602" and ask(b, "$012") is None
    assert ask(b, "%0506300602") == "?05"  # 0x30 is no I-7017 range


def test_animation_changes_inputs_visibly():
    b = bus((1, "I-7053"), (2, "I-7017", {"type_code": 0x08}), (3, "I-7043"))
    b.animate(0.0)
    first = (b.modules[1].di_bits, list(b.modules[2].ai_raw))
    b.animate(1.0)
    second = (b.modules[1].di_bits, list(b.modules[2].ai_raw))
    assert first[0] == 1 and second[0] == 2  # a walking bit, one step a second
    assert first[1] != second[1] and len(set(second[1])) > 1  # a sine per channel
    rng = b.modules[2].range
    assert all(rng.hmin < v < rng.hmax for v in first[1] + second[1])  # stays inside the range
    assert b.modules[3].do_bits == 0  # outputs are never animated


@pytest.mark.parametrize("model, command", [("I-7021", "#035P"), ("I-7024", "#060+1x")])
def test_a_malformed_analog_output_value_is_silence_not_a_crash(model, command):
    address = int(command[1:3], 16)
    fmt = DataFormat.HEX if model == "I-7021" else DataFormat.ENGINEERING
    b = bus((address, model, {"data_format": fmt}))
    assert ask(b, command) is None
    assert ask(b, f"${address:02X}M") == f"!{address:02X}{model[2:]}"  # still answering
