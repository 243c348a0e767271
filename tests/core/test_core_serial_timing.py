"""The shared serial timing model, sans-I/O: an Exchange driven with numbers for the time."""

from __future__ import annotations

import pytest

from fieldgate.serial_timing import (
    BYTE_TIMEOUT_FLOOR_S,
    EchoState,
    Exchange,
    LineTiming,
    Result,
    default_byte_timeout,
)

T9600 = LineTiming.of(9600, 200, bits=10)  # 1.0417 ms a character
REQUEST = bytes.fromhex("01 04 00 00 00 7d 30 2b")


def length_at_third_byte(data: bytes) -> int | None:
    """As Modbus: a write's reply is 8 bytes, a read's length is in its third byte."""
    if len(data) >= 2 and data[1] in (5, 6):
        return 8
    return None if len(data) < 3 else 5 + data[2]


def exchange(echo=False, ambiguous=False, request=REQUEST, timing=T9600, assume=None) -> Exchange:
    return Exchange(
        request,
        timing,
        length_at_third_byte,
        sent_at=0.0,
        echo=echo,
        ambiguous=ambiguous,
        assume=assume,
    )


def reply(n_registers: int) -> bytes:
    return bytes([1, 4, 2 * n_registers]) + bytes(2 * n_registers) + b"\x00\x00"


def feed_paced(ex: Exchange, data: bytes, start: float, char: float):
    """Bytes one at a time, one character time apart; the first outcome and its time."""
    for i, byte in enumerate(data):
        now = start + i * char
        due = ex.deadline()
        if due < now:
            outcome = ex.check(due)
            if outcome is not None:
                return outcome, due
        outcome = ex.feed(bytes([byte]), now)
        if outcome is not None:
            return outcome, now
    due = ex.deadline()
    return ex.check(due), due


def test_default_inter_byte_timeout_has_a_floor_above_usb_adapter_latency():
    assert default_byte_timeout(115200) == BYTE_TIMEOUT_FLOOR_S == 0.030
    assert default_byte_timeout(9600) == BYTE_TIMEOUT_FLOOR_S  # 8 x 1.15 ms < 30 ms
    assert default_byte_timeout(1200) == pytest.approx(8 * 11 / 1200)  # 73 ms
    assert LineTiming.of(9600, 200, byte_timeout_ms=5).byte == 0.005


def test_line_silence_is_3_5_characters_and_at_least_the_byte_timeout():
    assert LineTiming.of(300, 1000, 10, bits=10).silence == pytest.approx(3.5 * 10 / 300)
    assert LineTiming.of(9600, 200).silence == BYTE_TIMEOUT_FLOOR_S


def test_a_266_ms_reply_that_starts_in_time_completes_at_its_last_byte():
    ex = exchange()
    frame = reply(125)  # 255 bytes
    outcome, at = feed_paced(ex, frame, start=0.020, char=T9600.char)
    assert outcome.result is Result.REPLY and outcome.frame == frame
    assert at == pytest.approx(0.020 + 254 * T9600.char)  # 0.285 s > the 200 ms timeout


def test_no_first_byte_within_the_response_timeout_is_a_timeout_counted_from_the_requests_end():
    ex = exchange()
    assert ex.deadline() == pytest.approx(8 * T9600.char + 0.200)
    assert ex.check(0.200) is None  # the request itself takes 8.3 ms on the wire
    assert ex.check(ex.deadline()).result is Result.TIMEOUT


def test_a_frame_broken_off_ends_at_the_inter_byte_timeout():
    ex = exchange()
    frame = reply(10)[:12]
    outcome, at = feed_paced(ex, frame, start=0.010, char=T9600.char)
    assert outcome.result is Result.TRUNCATED and outcome.frame == frame
    assert at == pytest.approx(0.010 + 11 * T9600.char + T9600.byte)


def test_bytes_after_a_complete_frame_are_handed_back_as_rest():
    ex = exchange()
    outcome = ex.feed(reply(1) + b"\x55\xaa", 0.05)
    assert (
        outcome.result is Result.REPLY and outcome.frame == reply(1) and outcome.rest == b"\x55\xaa"
    )


def test_echo_on_the_echo_is_compared_dropped_and_never_the_reply():
    ex = exchange(echo=True)
    assert ex.feed(REQUEST, 0.009) is None
    assert ex.deadline() == pytest.approx(
        8 * T9600.char + 0.200
    )  # the echo does not start the reply
    outcome = ex.feed(reply(1), 0.030)
    assert (
        outcome.result is Result.REPLY and outcome.frame == reply(1) and outcome.echo_seen is True
    )


def test_echo_on_a_different_echo_is_a_collision():
    ex = exchange(echo=True)
    outcome = ex.feed(REQUEST[:3] + b"\xff", 0.005)
    assert outcome.result is Result.ECHO_MISMATCH


def test_echo_on_no_echo_at_all_says_so():
    ex = exchange(echo=True)
    assert ex.check(ex.deadline()).result is Result.NO_ECHO


def test_echo_on_a_write_whose_reply_equals_its_echo_without_a_reply_is_a_timeout():
    write = bytes.fromhex("04 06 00 00 04 d2 00 00")
    ex = exchange(echo=True, ambiguous=True, request=write)
    assert ex.feed(write, 0.009) is None  # the echo alone is not the answer
    assert ex.check(ex.deadline()).result is Result.TIMEOUT


def test_auto_a_reply_that_does_not_begin_like_the_request_means_no_echo():
    ex = exchange(echo=None)
    outcome = ex.feed(reply(1), 0.02)
    assert outcome.result is Result.REPLY and outcome.echo_seen is False


def test_auto_the_request_coming_back_means_echo():
    ex = exchange(echo=None)
    assert ex.feed(REQUEST, 0.009) is None
    outcome = ex.feed(reply(1), 0.03)
    assert outcome.result is Result.REPLY and outcome.echo_seen is True


def test_auto_fc6_two_copies_mean_echo_one_copy_is_the_reply_and_decides_nothing():
    write = bytes.fromhex("04 06 00 00 04 d2 00 00")
    ex = exchange(echo=None, ambiguous=True, request=write)
    assert ex.feed(write, 0.009) is None
    outcome = ex.feed(write, 0.030)
    assert outcome.result is Result.REPLY and outcome.echo_seen is True
    ex = exchange(echo=None, ambiguous=True, request=write)
    assert ex.feed(write, 0.020) is None  # echo or reply? wait one inter-byte timeout
    outcome = ex.check(ex.deadline())
    assert outcome.result is Result.REPLY and outcome.frame == write and outcome.echo_seen is None


def test_auto_fc6_follows_what_the_line_showed_last():
    write = bytes.fromhex("04 06 00 00 04 d2 00 00")
    ex = exchange(echo=None, ambiguous=True, request=write, assume=True)
    assert ex.feed(write, 0.009) is None  # an echo: the reply is still to come
    assert ex.check(ex.deadline()).result is Result.TIMEOUT
    ex = exchange(echo=None, ambiguous=True, request=write, assume=False)
    assert ex.feed(write, 0.020).result is Result.REPLY  # no echo on this line: at once


def test_echo_state_follows_the_line_and_forgets_on_reopen():
    state = EchoState("auto")
    assert state.expect is None and state.assume is None
    assert state.learn(exchange(echo=None).feed(REQUEST + reply(1), 0.03)) is True
    assert state.assume is True and state.describe() == "auto: echo detected"
    assert state.learn(exchange(echo=None).feed(REQUEST + reply(1), 0.03)) is False
    # the adapter's echo suppression came on: auto follows (a reply is never the request)
    assert state.learn(exchange(echo=None).feed(reply(1), 0.03)) is True
    assert state.assume is False
    state.reset()
    assert state.assume is None
    assert EchoState(False).expect is False and EchoState(True).describe() == "on"
