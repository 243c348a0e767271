"""The simulator's RTU responder (sans-I/O) and its module memory, wiring and animation."""

import asyncio

import pytest

from fieldgate.plugins.modbus import codec
from fieldgate.plugins.modbus.codec import Request
from fieldgate.plugins.modbus.config import ModbusBackConfig
from fieldgate.plugins.modbus.simulator import (
    Fault,
    ModbusSimulator,
    RtuResponder,
    SimModule,
    demo_wiring,
)

I7232D = [
    {"address": 1, "model": "M-7052D"},
    {"address": 3, "model": "M-7055D", "counts": {"di": 0}},
    {"address": 4, "model": "M-7024", "counts": {"ao": 1}},
    {"address": 5, "model": "M-7017R", "counts": {"ai": 1}},
]


def config(modules=I7232D):
    return ModbusBackConfig(name="rs485", port="unused", modules=modules)


def responder():
    return RtuResponder({a: SimModule(a, pts) for a, pts in config().points().items()}, gap=0.01)


def test_two_requests_in_one_chunk_get_two_replies():
    r = responder()
    replies = r.feed(Request(1, 2, 32, 8).encode() + Request(5, 4, 0, 1).encode(), now=0.0)
    assert [reply.frame[:2] for reply in replies] == [b"\x01\x02", b"\x05\x04"]


def test_a_request_split_over_chunks_is_reassembled_within_the_gap():
    r = responder()
    adu = Request(4, 16, 0, 1, (77,)).encode()
    assert r.feed(adu[:5], now=0.0) == []
    (reply,) = r.feed(adu[5:], now=0.005)
    assert reply.frame == codec.write_response(Request(4, 16, 0, 1, (77,)))


def test_a_partial_frame_followed_by_silence_is_dropped():
    r = responder()
    adu = Request(1, 2, 32, 8).encode()
    assert r.feed(adu[:4], now=0.0) == []
    (reply,) = r.feed(adu, now=0.5)  # after the gap: the old half is discarded
    assert reply.frame[:2] == b"\x01\x02" and r.dropped == 1


def test_unknown_units_stay_silent_and_bad_crcs_are_dropped():
    r = responder()
    assert r.feed(Request(2, 2, 32, 8).encode(), now=0.0) == []
    bad = Request(1, 2, 32, 8).encode()
    assert r.feed(bad[:-1] + bytes([bad[-1] ^ 0x55]), now=1.0) == []
    assert r.dropped == 1 and r.served == 0


def test_an_unknown_function_with_a_good_crc_gets_illegal_function():
    r = responder()
    (reply,) = r.feed(codec.frame(3, bytes([0x2B, 0x0E, 0x01, 0x00])), now=0.0)
    assert reply.frame == codec.exception_response(3, 0x2B, 1)


def test_protocol_errors_are_answered_with_exceptions():
    r = responder()
    answers = {
        "illegal address": Request(5, 4, 1, 1),  # the module serves ai0 only (counts: ai 1)
        "count 0": Request(5, 4, 0, 0),
        "too many": Request(1, 2, 32, 2001),
        "write to input": Request(1, 5, 32, 1, (True,)),
    }
    codes = {
        name: r.feed(req.encode(), now=i)[0].frame[2]
        for i, (name, req) in enumerate(answers.items())
    }
    assert codes == {"illegal address": 2, "count 0": 3, "too many": 3, "write to input": 2}
    bad_coil = codec.frame(3, bytes.fromhex("05 00 00 12 34"))
    assert r.feed(bad_coil, now=10)[0].frame == codec.exception_response(3, 5, 3)


@pytest.mark.parametrize(
    "kind", ["no_answer", "crc", "garbage", "truncate", "wrong_address", "delay", "exception"]
)
def test_faults_shape_the_reply(kind):
    r = responder()
    good = r.feed(Request(1, 2, 32, 8).encode(), now=0.0)[0].frame
    r.modules[1].faults.append(Fault(kind, count=1, delay=0.3, code=6))
    replies = r.feed(Request(1, 2, 32, 8).encode(), now=1.0)
    if kind == "no_answer":
        assert replies == []
        return
    (reply,) = replies
    expected = {
        "crc": lambda f: f[:-2] == good[:-2] and not codec.crc_ok(f),
        "garbage": lambda f: not codec.crc_ok(f),
        "truncate": lambda f: good.startswith(f) and len(f) < len(good),
        "wrong_address": lambda f: codec.crc_ok(f) and f[0] != 1 and f[1:-2] == good[1:-2],
        "delay": lambda f: f == good and reply.delay == 0.3,
        "exception": lambda f: f == codec.exception_response(1, 2, 6),
    }[kind]
    assert expected(reply.frame)
    assert r.feed(Request(1, 2, 32, 8).encode(), now=2.0)[0].frame == good  # used up


def test_the_demo_wiring_pairs_do_to_di_and_ao_to_ai():
    assert demo_wiring(config()) == [(f"rs485/m3/do{i}", f"rs485/m1/di{i}") for i in range(8)] + [
        ("rs485/m4/ao0", "rs485/m5/ai0")
    ]
    # a DI+DO module is not a wiring target, only a source
    assert (
        demo_wiring(
            config([{"address": 2, "model": "M-7055D"}, {"address": 6, "model": "M-7060D"}])
        )
        == []
    )


def test_writes_propagate_through_the_wiring_when_animated():
    sim = ModbusSimulator(config(), "unused", animate=True)
    seen = []
    sim.output_listeners.append(lambda cid, value: seen.append((cid, value)))
    r = sim.responder
    r.feed(
        Request(3, 15, 0, 8, (False, False, True, False, True, True, False, False)).encode(),
        now=0.0,
    )  # DO byte 0x34
    assert [sim.get(f"rs485/m1/di{i}") for i in range(8)] == [
        False,
        False,
        True,
        False,
        True,
        True,
        False,
        False,
    ]
    r.feed(Request(4, 6, 0, 1, (0x3FFF,)).encode(), now=1.0)  # 5 V on 0..10 V
    assert sim.get("rs485/m5/ai0") == 0x3FFF  # 5 V on +-10 V: the same raw value
    assert ("rs485/m3/do2", True) in seen and ("rs485/m4/ao0", 0x3FFF) in seen


def test_set_input_and_get_output_by_channel_id():
    sim = ModbusSimulator(config(), "unused")
    sim.set_input("rs485/m5/ai0", -5)
    assert sim.get("rs485/m5/ai0") == -5
    with pytest.raises(ValueError, match="is an output"):
        sim.set_input("rs485/m3/do0", True)
    with pytest.raises(ValueError, match="outside int16"):
        sim.set_input("rs485/m5/ai0", 40000)
    with pytest.raises(KeyError, match="no simulated channel"):
        sim.get_output("rs485/m9/do0")
    with pytest.raises(ValueError, match="unknown fault"):
        Fault("smoke")


async def test_animated_inputs_move_until_the_gateway_drives_them():
    from fieldgate.serial_link import PtyPair

    with PtyPair() as pair:
        sim = ModbusSimulator(config(), pair.b, animate=True, animate_period=0.005)
        await sim.start()
        try:
            seen = set()
            for _ in range(100):
                await asyncio.sleep(0.005)
                seen.add(sim.get("rs485/m5/ai0"))
            assert len(seen) > 3  # the AI ramps while the M-7024 has not been written
            sim.responder.feed(Request(4, 6, 0, 1, (1000,)).encode(), now=0.0)
            sim.responder.feed(Request(3, 5, 1, 1, (True,)).encode(), now=1.0)
            await asyncio.sleep(0.05)
            assert sim.get("rs485/m5/ai0") == 1000 and sim.get("rs485/m1/di1") is True
            assert sim.get("rs485/m1/di0") is False  # wired to do0, which is off
        finally:
            await sim.stop()


def test_a_write_that_is_not_a_value_of_the_point_gets_illegal_data_value_and_changes_nothing():
    r = RtuResponder(
        {
            8: SimModule(
                8,
                config(
                    [
                        {
                            "address": 8,
                            "channels": [
                                {
                                    "kind": "ao",
                                    "table": "holding_registers",
                                    "address": 10,
                                    "type": "float32",
                                }
                            ],
                        }
                    ]
                ).points()[8],
            )
        },
        gap=0.01,
    )

    def ask(pdu: str, now: float) -> list[bytes]:
        return [reply.frame for reply in r.feed(codec.frame(8, bytes.fromhex(pdu)), now=now)]

    assert ask("06 00 0A 7F C0", 0.0) == [
        codec.frame(8, bytes.fromhex("86 03"))
    ]  # the high word of a NaN
    assert ask("03 00 0A 00 02", 1.0) == [
        codec.frame(8, bytes.fromhex("03 04 00 00 00 00"))
    ]  # nothing was written


def test_wiring_clamps_to_the_target_type_range():
    sim = ModbusSimulator(
        config(
            [
                {"address": 4, "model": "M-7024", "counts": {"ao": 1}},
                {
                    "address": 10,
                    "channels": [
                        {"kind": "ai", "table": "input_registers", "address": 0, "type": "uint16"}
                    ],
                },
            ]
        ),
        "unused",
        animate=True,
    )
    assert sim.responder.feed(
        Request(4, 6, 0, 1, (0xFFFB,)).encode(), now=0.0
    )  # -5 on an int16 AO: answered
    assert sim.get("rs485/m10/ai0") == 0  # a uint16 input cannot go below 0
