"""The OPC UA Connection Protocol's framing (plugins/opcua/framing.py), sans-I/O: each rule
of Part 6 §7.1 the front enforces before buffering, with the messages built by hand
(scripts/faults/uaraw.py, no OPC UA library) and the answers read back the same way.
Issue 29: D2 (chunk floods), D7 (Hello buffer sizes), D8 (EndpointUrl length)."""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fieldgate.plugins.opcua import framing
from fieldgate.plugins.opcua.framing import Chunk, Framer, FramingLimits, Hello, Refusal

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts" / "faults"))
import uaraw  # noqa: E402

LIMITS = FramingLimits(max_chunk_size=65535, max_message_size=4 * 65535, max_chunk_count=8)


def opened(limits: FramingLimits = LIMITS) -> Framer:
    framer = Framer(limits)
    (hello,) = framer.feed(uaraw.hello())
    assert isinstance(hello, Hello)
    framer.acknowledge(hello)
    return framer


def msg(size: int, chunk: bytes = b"F", kind: bytes = b"MSG") -> bytes:
    return uaraw.header(kind, chunk, size) + b"\0" * (size - 8)


def refused(events: list[object]) -> Refusal:
    assert events and isinstance(events[-1], Refusal), events
    return events[-1]


def test_a_hello_is_acknowledged_with_the_smaller_buffers_the_spec_way_round():
    framer = Framer(LIMITS)
    (hello,) = framer.feed(
        uaraw.hello("opc.tcp://gw:4840/", receive_buffer=16384, send_buffer=70000)
    )
    assert isinstance(hello, Hello) and hello.endpoint_url == "opc.tcp://gw:4840/"
    ack = framer.acknowledge(hello)
    # ACK ReceiveBufferSize <= the client's SendBufferSize; ACK SendBufferSize <= its Receive
    assert (ack.receive_buffer, ack.send_buffer) == (65535, 16384)
    (answer,), _ = uaraw.parse_messages(ack.encode())
    assert answer.kind == "ACK" and answer.ack == (0, 65535, 16384, 4 * 65535, 8)
    assert framer.receive_buffer == 65535


@pytest.mark.parametrize(
    "fields",
    [
        {"receive_buffer": 0},
        {"send_buffer": 0},
        {"receive_buffer": 1, "send_buffer": 1},
        {"receive_buffer": 8191},
        {"max_message": 1},
    ],
)
def test_d7_hello_buffer_sizes_below_8192_are_refused(fields):
    refusal = refused(Framer(LIMITS).feed(uaraw.hello(**fields)))
    assert refusal.status == framing.BAD_TCP_NOT_ENOUGH_RESOURCES
    assert refusal.counter == "hello_invalid" and "8192" in refusal.reason
    (answer,), _ = uaraw.parse_messages(refusal.encode())
    assert answer.status_name == "Bad_TcpNotEnoughResources" and "8192" in answer.reason


@pytest.mark.parametrize(
    "message",
    [
        uaraw.hello(url_length=0x7FFF_FFFF),  # D8: the length the issue sent
        uaraw.hello(url_length=-2),
        uaraw.hello(url_length=3),  # does not match the bytes that follow
        uaraw.hello("opc.tcp://x/" + "a" * 4085),  # 4,097 bytes
        uaraw.header(b"HEL", b"F", 40)
        + struct.pack("<IIIIIi", 0, 65535, 65535, 0, 0, 8)
        + b"\xff" * 8,
    ],
)
def test_d8_endpoint_url_invalid_is_refused_not_raised(message):
    refusal = refused(Framer(LIMITS).feed(message))
    assert refusal.status == framing.BAD_TCP_ENDPOINT_URL_INVALID


def test_a_null_endpoint_url_is_accepted():
    hello = Framer(LIMITS).feed(uaraw.hello("", url_length=-1))
    assert isinstance(hello[0], Hello) and hello[0].endpoint_url is None


def test_d2_a_huge_chunk_is_refused_on_its_header_before_any_body_is_buffered():
    framer = opened()
    refusal = refused(framer.feed(uaraw.header(b"MSG", b"F", 0x7FFF_FFFF)))  # 8 bytes only
    assert (
        refusal.status == framing.BAD_TCP_MESSAGE_TOO_LARGE and refusal.counter == "chunk_too_large"
    )
    assert framer.buffered == 0 and framer.closed
    assert framer.feed(b"\0" * 1_000_000) == []  # nothing more is taken


def test_d2_a_flood_without_hello_is_refused_on_its_first_header():
    framer = Framer(LIMITS)
    refusal = refused(framer.feed(uaraw.header(b"MSG", b"F", 0x7FFF_FFFF) + b"\0" * 1_000_000))
    assert refusal.status == framing.BAD_TCP_MESSAGE_TYPE_INVALID
    assert refusal.counter == "not_hello_first" and framer.buffered == 0


def test_a_chunk_one_byte_over_the_negotiated_buffer_is_refused():
    framer = Framer(LIMITS)
    (hello,) = framer.feed(uaraw.hello(send_buffer=8192))
    framer.acknowledge(hello)
    assert isinstance(framer.feed(msg(8192))[0], Chunk)
    assert refused(framer.feed(msg(8193)[:8])).status == framing.BAD_TCP_MESSAGE_TOO_LARGE


def test_the_message_size_is_checked_at_the_chunk_that_would_exceed_it():
    framer = opened()
    body = 65535 - framing.SECURE_BODY_OFFSET
    for _ in range(3):
        assert isinstance(framer.feed(msg(65535, b"C"))[0], Chunk)
    # 4 chunks of 65,511 bytes of body = 262,044 <= 262,140: the 4th passes, a 5th would not
    assert isinstance(framer.feed(msg(65535, b"C"))[0], Chunk)
    refusal = refused(framer.feed(msg(65535, b"F")[:8]))
    assert (
        refusal.status == framing.BAD_REQUEST_TOO_LARGE and refusal.counter == "message_too_large"
    )
    assert body * 5 > LIMITS.max_message_size


def test_the_chunk_count_is_checked_and_a_final_or_abort_chunk_starts_again():
    framer = opened()
    for _ in range(2):
        for _ in range(7):
            assert isinstance(framer.feed(msg(24, b"C"))[0], Chunk)
        assert isinstance(framer.feed(msg(24, b"A"))[0], Chunk)  # 8 chunks: abandoned
    for _ in range(8):
        framer.feed(msg(24, b"C"))
    refusal = refused(framer.feed(msg(24, b"F")))
    assert refusal.counter == "too_many_chunks" and refusal.status == framing.BAD_REQUEST_TOO_LARGE


@pytest.mark.parametrize(
    ("data", "counter"),
    [
        (uaraw.open_secure_channel(), "not_hello_first"),
        (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", "not_hello_first"),
        (uaraw.header(b"HEL", b"C", 40), "message_type_invalid"),
    ],
)
def test_a_first_message_other_than_a_hello_is_refused(data, counter):
    refusal = refused(Framer(LIMITS).feed(data))
    assert refusal.status == framing.BAD_TCP_MESSAGE_TYPE_INVALID and refusal.counter == counter


@pytest.mark.parametrize(
    "data",
    [
        uaraw.hello(),  # a second Hello
        msg(28, kind=b"ACK"),
        msg(28, kind=b"ERR"),
        msg(28, kind=b"RHE"),
        msg(40, b"C", kind=b"OPN"),  # OPN and CLO come in one F chunk
        msg(40, b"A", kind=b"CLO"),
        msg(40, b"X"),
    ],
)
def test_after_the_hello_only_opn_msg_clo_with_their_chunk_types(data):
    refusal = refused(opened().feed(data))
    assert refusal.status == framing.BAD_TCP_MESSAGE_TYPE_INVALID


def test_a_chunk_shorter_than_its_headers_is_a_decoding_error():
    refusal = refused(opened().feed(msg(23)))
    assert refusal.status == framing.BAD_DECODING_ERROR


def test_many_small_chunks_in_one_read_come_out_whole_and_in_order():
    framer = opened()
    chunks = [
        uaraw.secure_chunk(1, 13, i, i, bytes([i % 256]) * (i % 7), b"F") for i in range(5000)
    ]
    out = framer.feed(b"".join(chunks))
    assert [c.data for c in out if isinstance(c, Chunk)] == chunks and framer.buffered == 0


def test_bytes_after_a_hello_wait_for_its_acknowledgement():
    framer = Framer(LIMITS)
    (hello,) = framer.feed(uaraw.hello() + uaraw.open_secure_channel())
    framer.acknowledge(hello)
    (opn,) = framer.feed(b"")
    assert isinstance(opn, Chunk) and opn.message_type == b"OPN"


def test_the_error_message_reason_is_capped_at_4096_bytes():
    (answer,), _ = uaraw.parse_messages(framing.error_message(framing.BAD_TIMEOUT, "x" * 10_000))
    assert answer.status_name == "Bad_Timeout" and len(answer.reason) == 4096


streams = st.lists(
    st.one_of(
        st.binary(max_size=64),
        st.builds(
            uaraw.hello,
            receive_buffer=st.sampled_from([0, 8192, 65535]),
            url_length=st.sampled_from([None, -1, 0x7FFF_FFFF]),
        ),
        st.builds(
            uaraw.header,
            st.sampled_from([b"HEL", b"ACK", b"ERR", b"OPN", b"MSG", b"CLO", b"RHE", b"XYZ"]),
            st.sampled_from([b"F", b"C", b"A", b"Z"]),
            st.sampled_from([0, 7, 8, 24, 32, 65535, 65536, 0x7FFF_FFFF, 0xFFFF_FFFF]),
        ),
    ),
    max_size=12,
)


@settings(
    max_examples=400, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True
)
@given(streams)
def test_any_byte_stream_is_cut_refused_or_waited_for_never_raised_nor_hoarded(parts):
    """The framer's invariant under arbitrary input: no exception, a refusal is the last
    thing it says, and it never holds more than one message's bytes once a feed is done."""
    framer = Framer(LIMITS)
    for part in parts:
        events = framer.feed(part)
        while events and isinstance(events[-1], Hello):
            framer.acknowledge(events[-1])
            events = framer.feed(b"")
        assert all(not isinstance(e, Refusal) for e in events[:-1])
        if framer.closed:
            assert framer.buffered == 0 and framer.feed(b"MSGF") == []
            return
        assert framer.buffered < max(LIMITS.max_chunk_size, framing.MAX_HELLO)
