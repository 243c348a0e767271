"""MBAP framing, a connection's timers and the admission rule, without a socket: bytes and
the time are fed by hand (issue 29: D3 and D5)."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import pytest

from fieldgate.plugins.modbus_tcp.mbap import (
    IDLE,
    MALFORMED,
    MAX_FRAME,
    REQUEST_TIMEOUT,
    Frame,
    Limits,
    MbapConnection,
    admit,
    answer,
)

LIMITS = Limits(idle_timeout=60.0, request_timeout=5.0, max_pending=4)
READ = struct.pack(">BHH", 3, 0, 1)


def mbap(pdu: bytes, tid: int = 1, unit: int = 1, protocol: int = 0) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1, unit) + pdu


def feed(conn: MbapConnection, data: bytes, now: float = 0.0) -> None:
    """As the socket does: into the connection's buffer, as much as it offers at a time."""
    while data:
        buf = conn.buffer()
        assert len(buf) > 0, "the connection must pause reading before its buffer is full"
        n = min(len(buf), len(data))
        buf[:n] = data[:n]
        data = data[n:]
        conn.received(n, now)
        if conn.close_reason is not None or not conn.wants_reading:
            return


def frames(conn: MbapConnection, now: float = 0.0) -> list[Frame]:
    out = []
    while (frame := conn.next_frame()) is not None:
        out.append(frame)
        conn.served(now)
    return out


def test_frames_split_anywhere_and_pipelined_come_out_whole_and_in_order():
    stream = b"".join(mbap(READ + bytes([i]), tid=i, unit=i) for i in range(1, 4))
    for step in (1, 2, 5, 7, 13, len(stream)):
        conn = MbapConnection(LIMITS, 0.0)
        got = []
        for k in range(0, len(stream), step):
            feed(conn, stream[k : k + step])
            got += frames(conn)
        assert [(f.tid, f.unit, f.pdu) for f in got] == [
            (i, i, READ + bytes([i])) for i in range(1, 4)
        ]
        assert conn.close_reason is None and conn.requests == 3


@pytest.mark.parametrize(
    "header",
    [
        struct.pack(">HHHB", 1, 0, 0, 1),  # length 0
        struct.pack(">HHHB", 1, 0, 1, 1),  # length 1: a unit id and no function code
        struct.pack(">HHHB", 1, 0, 255, 1),  # one more than unit id + 253-byte PDU
        struct.pack(">HHHB", 1, 0, 65535, 1),
        struct.pack(">HHHB", 1, 1, 6, 1),  # protocol id 1
        bytes.fromhex("474554202f20485454"),  # "GET / HTT"
    ],
)
def test_a_malformed_header_closes_on_its_seven_bytes(header):
    conn = MbapConnection(LIMITS, 0.0)
    feed(conn, header[:6])
    assert conn.close_reason is None  # not yet a header
    feed(conn, header[6:7])
    assert conn.close_reason == MALFORMED
    assert conn.next_frame() is None and not conn.wants_reading


def test_length_0_then_a_valid_request_is_closed_not_answered_from_leftovers():
    """D5: pymodbus took the request after a length-0 header from the wrong offset and
    answered transaction id 1 with a reply built from leftover bytes."""
    conn = MbapConnection(LIMITS, 0.0)
    feed(conn, struct.pack(">HHHB", 1, 0, 0, 1) + mbap(READ, tid=2))
    assert conn.close_reason == MALFORMED and frames(conn) == []


def test_the_buffer_is_one_frame_whatever_the_header_says():
    conn = MbapConnection(LIMITS, 0.0)
    assert len(conn.buffer()) == MAX_FRAME == 260
    feed(conn, struct.pack(">HHHB", 1, 0, 254, 1) + bytes(100))  # the largest frame, half sent
    assert len(conn.buffer()) == MAX_FRAME - 107


def test_a_frame_begun_must_complete_within_the_request_timeout():
    conn = MbapConnection(LIMITS, 100.0)
    feed(conn, mbap(READ)[:3], now=101.0)
    assert conn.deadline() == 106.0
    feed(conn, mbap(READ)[3:5], now=104.0)  # a byte now and then does not reset it
    assert conn.deadline() == 106.0
    assert conn.expire(105.9) is None
    assert conn.expire(106.0) == REQUEST_TIMEOUT


def test_a_completed_frame_stops_the_request_timer_and_the_idle_one_runs():
    conn = MbapConnection(LIMITS, 100.0)
    data = mbap(READ) + mbap(READ)[:4]
    feed(conn, data, now=101.0)
    assert len(frames(conn, now=101.0)) == 1
    assert conn.deadline() == 106.0  # the second frame begun at 101
    feed(conn, mbap(READ)[4:], now=102.0)
    assert len(frames(conn, now=102.0)) == 1
    assert conn.deadline() == 162.0  # idle since its answer
    assert conn.expire(161.9) is None and conn.expire(162.0) == IDLE


def test_no_timer_runs_while_a_request_is_served():
    conn = MbapConnection(LIMITS, 0.0)
    feed(conn, mbap(READ))
    assert conn.next_frame() is not None
    assert conn.deadline() is None and conn.expire(10_000.0) is None
    assert conn.idle_since() is None  # admission may not evict it
    conn.served(500.0)
    assert conn.deadline() == 560.0 and conn.idle_since() == 500.0


def test_pipelined_requests_beyond_max_pending_wait_in_the_socket():
    conn = MbapConnection(LIMITS, 0.0)
    stream = b"".join(mbap(READ, tid=i) for i in range(10))
    feed(conn, stream)
    assert conn.pending == 4 and not conn.wants_reading  # the adapter pauses reading
    taken = conn.next_frame()
    assert taken is not None and taken.tid == 0
    assert not conn.wants_reading  # still 4: one in progress, 3 waiting
    conn.served(0.0)
    assert conn.pending == 4  # a frame left in the buffer took the freed place
    assert conn.wants_reading is False
    rest = frames(conn)
    assert [f.tid for f in rest] == list(range(1, 10))  # the rest, taken from the buffer in order
    assert conn.wants_reading


def test_answer_echoes_transaction_and_unit():
    frame = Frame(0x1234, 7, READ)
    assert answer(frame, b"\x03\x02\x00\x05") == bytes.fromhex("1234000000050703020005")


@dataclass
class Conn:
    peer: str
    engine: MbapConnection = field(default_factory=lambda: MbapConnection(LIMITS, 0.0))

    @classmethod
    def idle(cls, peer: str, since: float) -> Conn:
        return cls(peer, MbapConnection(LIMITS, since))

    @classmethod
    def busy(cls, peer: str) -> Conn:
        conn = cls(peer)
        feed(conn.engine, mbap(READ))
        conn.engine.next_frame()
        return conn


def test_admission_below_the_caps_evicts_nobody():
    assert admit("10.0.0.1", [Conn.idle("10.0.0.2", 1.0)], 2, 2) == []


def test_at_the_total_cap_the_longest_idle_goes_never_a_busy_one():
    """D3: silent sockets no longer lock everyone out; a connection being served stays."""
    silent, polling, serving = Conn.idle("a", 1.0), Conn.idle("b", 50.0), Conn.busy("c")
    assert admit("d", [polling, serving, silent], 3, 3) == [silent]
    slowloris = Conn.idle("e", 2.0)
    feed(slowloris.engine, mbap(READ)[:3], now=55.0)  # bytes that never make a request
    assert admit("d", [polling, serving, slowloris], 3, 3) == [slowloris]
    assert admit("d", [Conn.busy("a"), Conn.busy("b")], 2, 2) is None  # refused


def test_at_the_per_peer_cap_that_peer_gives_up_its_own_longest_idle():
    mine_old, mine_new, other = Conn.idle("a", 1.0), Conn.idle("a", 9.0), Conn.idle("b", 0.5)
    assert admit("a", [other, mine_old, mine_new], 10, 2) == [mine_old]
    assert admit("a", [other, Conn.busy("a"), Conn.busy("a")], 10, 2) is None
    # at both caps: one eviction of its own makes room in all
    assert admit("a", [other, mine_old, mine_new], 3, 2) == [mine_old]
