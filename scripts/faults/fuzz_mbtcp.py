"""Fuzz target of the Modbus TCP front's server: MBAP headers and PDUs from hostile clients.

The front's real server (``ModbusTcpFront.build()``: the map, the PDU decoder, the MBAP
framing, admission, the timers, writes through ``context.set_outputs``) on an event loop of
its own, its connections on in-memory transports. Each input is a client action: open a few
silent connections from one of three addresses, move the clock (the sweep's timers), or send
a byte stream on a new or open connection, cut into chunks as TCP may: mostly well-formed
requests (every function code served, fields in and out of the map and of the standard's
limits, a wrong unit id now and then), sometimes other function codes, malformed headers,
wrong lengths, garbage.

The oracle is written from the Modbus Messaging on TCP/IP Implementation Guide, independent
of the server's code (:func:`reference_frames`, :func:`answer_error`): on every connection
the answers are, in order, one per request the client completed (same transaction and unit
id), each a valid answer to it or an exception the standard allows; a connection is closed
only after a malformed header, a timeout the clock passed, or to make room; nothing is
written after a close; the server never holds more connections, per address or in all, nor
more pending requests than its limits; no exception escapes; and after every input a fresh
client's read is answered. The socket-level version of the same check is
tests/faults/test_fuzz_mbtcp.py.
"""

from __future__ import annotations

import asyncio
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from fuzz_base import CO_TOPOLOGY_BACK, Bytes, InvariantBroken, Target

from fieldgate.plugin import GatewayContext
from fieldgate.topology import load_topology

SERVED = (1, 2, 3, 4, 5, 6, 15, 16, 23)
OTHER_CODES = (0, 7, 8, 11, 12, 17, 20, 21, 22, 24, 43, 0x41, 0x83)  # pymodbus's and odd ones
MAX_READ = {1: 2000, 2: 2000, 3: 125, 4: 125, 23: 125}
MAX_WRITE = {15: 1968, 16: 123, 23: 121}
UNIT = 1
PEERS = ("127.0.0.1", "127.0.0.2", "10.0.0.9")
FRESH_PEER = "192.0.2.1"
LIMITS = {"max_clients": 6, "max_clients_per_peer": 3, "max_pending_requests": 4}
HEADER = struct.Struct(">HHHB")


# -- the oracle (the standard, not the server's code) ---------------------------------------
@dataclass
class Parsed:
    frames: list[tuple[int, int, bytes]]  # (transaction id, unit, PDU) of complete requests
    malformed: bool  # a header with protocol id != 0 or length outside 2..254 follows them


def reference_frames(stream: bytes) -> Parsed:
    frames, at = [], 0
    while len(stream) - at >= 7:
        tid, protocol, length, unit = HEADER.unpack_from(stream, at)
        if protocol != 0 or not 2 <= length <= 254:
            return Parsed(frames, True)
        if len(stream) - at < 6 + length:
            break
        frames.append((tid, unit, stream[at + 7 : at + 6 + length]))
        at += 6 + length
    return Parsed(frames, False)


def well_formed(pdu: bytes) -> tuple[int, ...] | None:
    """The request's fields when its PDU is what the standard defines, else None."""
    fc, body = pdu[0], pdu[1:]
    if fc in (1, 2, 3, 4) and len(body) == 4:
        address, count = struct.unpack(">HH", body)
        return (address, count) if 1 <= count <= MAX_READ[fc] else None
    if fc in (5, 6) and len(body) == 4:
        address, value = struct.unpack(">HH", body)
        return (address, value) if fc == 6 or value in (0, 0xFF00) else None
    if fc in (15, 16) and len(body) >= 5:
        address, count, size = struct.unpack(">HHB", body[:5])
        need = (count + 7) // 8 if fc == 15 else 2 * count
        ok = 1 <= count <= MAX_WRITE[fc] and size == need == len(body) - 5
        return (address, count) if ok else None
    if fc == 23 and len(body) >= 9:
        raddr, rcount, waddr, wcount, size = struct.unpack(">HHHHB", body[:9])
        ok = 1 <= rcount <= 125 and 1 <= wcount <= 121 and size == 2 * wcount == len(body) - 9
        return (raddr, rcount, waddr, wcount) if ok else None
    return None


def answer_error(unit: int, pdu: bytes, answer: bytes) -> str | None:
    """What is wrong with ``answer`` as the server's answer to ``pdu`` (None: nothing)."""
    fc = pdu[0]
    if unit not in (UNIT, 0, 255):
        return None if answer == bytes((fc | 0x80, 0x0B)) else "another unit: 0B expected"
    if fc not in SERVED:
        return None if answer == bytes((fc | 0x80, 0x01)) else "unknown function: 01 expected"
    fields = well_formed(pdu)
    if answer[:1] == bytes((fc | 0x80,)):
        if len(answer) != 2 or answer[1] not in (1, 2, 3):
            return "an exception other than 01-03"
        if fields is None and answer[1] != 3:
            return "a malformed PDU must be 03"
        return None
    if fields is None:
        return "a normal answer to a malformed PDU"
    if fc in (5, 6):
        return None if answer == pdu else "FC5/6 must echo the request"
    if fc in (15, 16):
        return None if answer == pdu[:5] else "FC15/16 must echo address and quantity"
    count = fields[1]
    size = (count + 7) // 8 if fc in (1, 2) else 2 * count
    if answer[:2] != bytes((fc, size)) or len(answer) != 2 + size:
        return f"FC{fc} of {count}: byte count or length wrong"
    if fc in (1, 2) and count % 8 and answer[-1] >> (count % 8):
        return "bits past the quantity must be 0"
    return None


def split_answers(data: bytes) -> list[tuple[int, int, bytes]]:
    out, at = [], 0
    while at < len(data):
        if len(data) - at < 7:
            raise InvariantBroken(f"a partial answer: {data[at:].hex()}")
        tid, protocol, length, unit = HEADER.unpack_from(data, at)
        if protocol != 0 or not 2 <= length <= 254 or len(data) - at < 6 + length:
            raise InvariantBroken(f"a malformed answer: {data[at : at + 16].hex()}")
        out.append((tid, unit, data[at + 7 : at + 6 + length]))
        at += 6 + length
    return out


def check_stream(sent: bytes, written: bytes, closed: bool, drained: bool) -> Parsed:
    """The answers on one connection against what its client sent (module docstring)."""
    parsed = reference_frames(sent)
    answers = split_answers(written)
    if len(answers) > len(parsed.frames):
        raise InvariantBroken(f"{len(answers)} answers to {len(parsed.frames)} requests")
    for (tid, unit, pdu), (atid, aunit, apdu) in zip(parsed.frames, answers, strict=False):
        if (atid, aunit) != (tid, unit):
            raise InvariantBroken(f"desynchronised: answer {atid}/{aunit} to request {tid}/{unit}")
        problem = answer_error(unit, pdu, apdu)
        if problem:
            raise InvariantBroken(f"{problem}: request {pdu.hex()}, answer {apdu.hex()}")
    if not closed and drained and len(answers) != len(parsed.frames):
        raise InvariantBroken(f"{len(parsed.frames) - len(answers)} requests left unanswered")
    if parsed.malformed and drained and not closed:
        raise InvariantBroken("a malformed header left the connection open")
    return parsed


# -- the inputs (a zero byte, what an exhausted buffer reads, picks the common case) ------------
def rare(b: Bytes, one_in: int) -> bool:
    return b.u8() % one_in == one_in - 1


def request_pdu(b: Bytes) -> bytes:
    fc = b.pick(SERVED) if not rare(b, 6) else b.pick((*OTHER_CODES, b.u8()))
    address = b.u8() % 24 if not rare(b, 6) else b.u16()
    count = 1 + b.u8() % 12 if not rare(b, 6) else b.u16()
    if fc in (1, 2, 3, 4):
        body = struct.pack(">HH", address, count)
    elif fc == 5:
        body = struct.pack(">HH", address, b.pick((0xFF00, 0x0000, 0xFF00, b.u16())))
    elif fc == 6:
        body = struct.pack(">HH", address, b.u16())
    elif fc in (15, 16, 23):
        size = (count + 7) // 8 if fc == 15 else 2 * count
        if rare(b, 8):
            size = b.u8()
        head = struct.pack(">HH", address, count) + bytes((size & 0xFF,))
        if fc == 23:
            head = struct.pack(">HH", b.u8() % 24, 1 + b.u8() % 10) + head
        body = head + b.take(min(size, 240))
    else:
        body = b.take(b.u8() % 10)
    pdu = bytes((fc,)) + body
    if rare(b, 10):
        pdu = pdu[: 1 + b.u8() % len(pdu)] if b.chance(2) else pdu + b.take(1 + b.u8() % 4)
    return pdu[:253]


def stream_from(b: Bytes) -> bytes:
    out = bytearray()
    for _ in range(1 + b.u8() % 4):
        kind = b.u8() % 20
        if kind == 19:
            out += b.take(b.u8() % 24)  # garbage
        elif kind == 18:
            length = b.pick((0, 1, 255, 256, 65535, b.u16()))
            out += HEADER.pack(b.u16(), 0, length, UNIT) + b.take(b.u8() % 8)
        else:
            unit = b.pick((UNIT, UNIT, UNIT, UNIT, 0, 255, b.u8()))
            pdu = request_pdu(b)
            protocol = 0 if not rare(b, 24) else b.u16()
            length = len(pdu) + 1 if not rare(b, 24) else b.u8()
            out += HEADER.pack(b.u16(), protocol, length, unit) + pdu
    if rare(b, 8):
        del out[b.u16() % (len(out) + 1) :]  # the client stops mid-frame
    return bytes(out)


# -- in-memory transport ---------------------------------------------------------------------
class FakeTransport:
    def __init__(self, peer: str, protocol: Any, loop: asyncio.AbstractEventLoop):
        self.peer = peer
        self.protocol = protocol
        self.loop = loop
        self.written = bytearray()
        self.closed = False
        self.reading = True

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return (self.peer, 50_000) if name == "peername" else default

    def write(self, data: bytes) -> None:
        if self.closed:
            raise InvariantBroken("written after the connection was closed")
        self.written += data

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.loop.call_soon(self.protocol.connection_lost, None)

    abort = close

    def pause_reading(self) -> None:
        self.reading = False

    def resume_reading(self) -> None:
        self.reading = True

    def get_write_buffer_size(self) -> int:
        return 0

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        pass

    def is_closing(self) -> bool:
        return self.closed


@dataclass
class Client:
    conn: Any
    transport: FakeTransport
    sent: bytearray = field(default_factory=bytearray)
    forced: bool = False  # closed by the clock or to make room: what follows is not checked


class ModbusTcpTarget(Target):
    name = "modbus_tcp"
    max_len = 256

    def setup(self) -> None:
        from fieldgate.plugins.modbus_tcp.server import Connection

        self.connection = Connection
        topology = load_topology(
            {
                "gateway": {"name": "fuzz", "state_dir": str(self.work_dir)},
                "fronts": [
                    {
                        "name": "mb",
                        "type": "modbus-tcp",
                        "writable": ["rs485/m1/do*", "rs485/m3/ao*"],
                        **LIMITS,
                    }
                ],
                "backs": [CO_TOPOLOGY_BACK],
            },
            self.registry,
        )
        self.context = GatewayContext.build(topology)
        front_type = self.registry.lookup("front", "modbus-tcp")
        assert front_type is not None
        self.front: Any = front_type.factory(topology.fronts[0], self.context)
        self.server = self.front.build()
        if getattr(self, "loop", None) is not None:
            self.loop.close()
        self.loop = asyncio.new_event_loop()
        self.unhandled: list[str] = []
        self.loop.set_exception_handler(lambda _, ctx: self.unhandled.append(str(ctx)[:300]))
        self.clients: list[Client] = []
        self.offset = 0.0  # the clock moved by the inputs

    def run(self, data: bytes) -> None:
        self.loop.run_until_complete(self._run(Bytes(data)))

    async def _run(self, b: Bytes) -> None:
        action = b.u8() % 16
        if action == 15:
            for _ in range(1 + b.u8() % 4):
                self._open(b.pick(PEERS))
        elif action == 14:
            self.offset += b.pick((0.5, 2.0, 6.0, 61.0))
            before = {id(c.conn) for c in self.clients if not c.transport.closed}
            self.server.sweep(time.monotonic() + self.offset)
            for c in self.clients:
                c.forced |= id(c.conn) in before and c.transport.closed
        else:
            open_clients = [c for c in self.clients if not c.transport.closed]
            if open_clients and b.chance(2):
                client = b.pick(open_clients)
            else:
                client = self._open(b.pick(PEERS))
            await self._send(client, stream_from(b), b)
        await self._drain()
        self._check_all()

    def _open(self, peer: str) -> Client:
        before = {id(c.conn) for c in self.clients if not c.transport.closed}
        conn = self.connection(self.server)
        transport = FakeTransport(peer, conn, self.loop)
        conn.connection_made(transport)
        client = Client(conn, transport, forced=transport.closed)  # refused: every slot busy
        self.clients.append(client)
        for c in self.clients:
            c.forced |= id(c.conn) in before and c.transport.closed  # evicted
        return client

    async def _send(self, client: Client, stream: bytes, b: Bytes) -> None:
        at = 0
        while at < len(stream) and not client.transport.closed:
            if not client.transport.reading:
                await self._drain()
                if not client.transport.reading and not client.transport.closed:
                    raise InvariantBroken("reading paused with no request in progress")
                continue
            buffer = client.conn.get_buffer(-1)
            if len(buffer) == 0:
                raise InvariantBroken("an empty receive buffer while reading")
            n = min(len(buffer), len(stream) - at, 1 + b.u8() % 64)
            buffer[:n] = stream[at : at + n]
            client.sent += stream[at : at + n]
            at += n
            client.conn.buffer_updated(n)
            self._check_limits()

    async def _drain(self) -> None:
        for _ in range(20):
            await asyncio.sleep(0)
            if not self.server._tasks:
                break
        await asyncio.sleep(0)  # connection_lost callbacks

    def _check_limits(self) -> None:
        conns = self.server.connections
        if len(conns) > LIMITS["max_clients"]:
            raise InvariantBroken(f"{len(conns)} connections held")
        for peer in PEERS:
            if sum(1 for c in conns if c.peer == peer) > LIMITS["max_clients_per_peer"]:
                raise InvariantBroken(f"more than the per-peer cap from {peer}")
        for c in conns:
            if c.engine.pending > LIMITS["max_pending_requests"]:
                raise InvariantBroken(f"{c.engine.pending} pending requests")

    def _check_all(self) -> None:
        self._check_limits()
        drained = not self.server._tasks
        for client in self.clients:
            if client.forced:
                continue
            parsed = check_stream(
                bytes(client.sent),
                bytes(client.transport.written),
                client.transport.closed,
                drained,
            )
            if client.transport.closed and not parsed.malformed:
                raise InvariantBroken("closed without a malformed header, timeout or eviction")
        self.clients = [
            c for c in self.clients if not c.transport.closed and len(c.sent) < 4096
        ]  # a long-lived client's history is checked up to 4 KiB, then left alone

    def check(self) -> None:
        if self.unhandled:
            raise InvariantBroken(f"unhandled in the loop: {self.unhandled[0]}")
        if self.server.counters["internal_errors"]:
            raise InvariantBroken("the front raised on a request (answered 04)")
        self.loop.run_until_complete(self._fresh())

    async def _fresh(self) -> None:
        client = self._open(FRESH_PEER)
        request = HEADER.pack(0x4242, 0, 6, UNIT) + struct.pack(">BHH", 4, 0, 1)
        buffer = client.conn.get_buffer(-1)
        buffer[: len(request)] = request
        client.conn.buffer_updated(len(request))
        await self._drain()
        if bytes(client.transport.written[:9]) != HEADER.pack(0x4242, 0, 5, UNIT) + b"\x04\x02":
            raise InvariantBroken(
                f"a fresh client was not served: {client.transport.written.hex()}"
            )
        client.transport.close()
        await self._drain()
        self.clients.remove(client)


class ModbusTcpSocketTarget(Target):
    """The same streams and oracle over real TCP: a gateway (the front and the never-polled
    DCON back) on its own thread and event loop (uvloop where installed, as ``fieldgate run``),
    a blocking client socket per input sending the stream in the input's chunks."""

    name = "modbus_tcp_socket"
    max_len = 256
    answer_wait_s = 2.0

    def setup(self) -> None:
        import socket
        import threading

        from fieldgate.runtime import Gateway
        from fieldgate.testing import in_this_process

        self.close()
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.gateway = Gateway.load(
            {
                "gateway": {"name": "fuzz", "state_dir": str(self.work_dir)},
                "fronts": [
                    {
                        "name": "mb",
                        "type": "modbus-tcp",
                        "listen": f"127.0.0.1:{self.port}",
                        "writable": ["rs485/m1/do*", "rs485/m3/ao*"],
                        **LIMITS,
                    }
                ],
                "backs": [{**CO_TOPOLOGY_BACK, "port": "/dev/null"}],
            },
            # the front in this process: the target reads its counters (in a gateway it runs
            # in a child process of its own; its server's code is the same)
            registry=in_this_process(self.registry, "modbus-tcp"),
            simulate=True,
        )
        try:
            import uvloop

            self.gw_loop: asyncio.AbstractEventLoop = uvloop.new_event_loop()
        except ImportError:
            self.gw_loop = asyncio.new_event_loop()
        self.unhandled: list[str] = []
        self.gw_loop.set_exception_handler(lambda _, ctx: self.unhandled.append(str(ctx)[:300]))
        started = threading.Event()

        def serve() -> None:
            asyncio.set_event_loop(self.gw_loop)
            self.gw_loop.run_until_complete(self.gateway.start())
            started.set()
            self.gw_loop.run_forever()

        self.thread = threading.Thread(target=serve, name="fuzz-gateway", daemon=True)
        self.thread.start()
        if not started.wait(30):
            raise RuntimeError("the gateway did not start")

    def close(self) -> None:
        """Stop the gateway and its thread."""
        if getattr(self, "thread", None) is None:
            return
        future = asyncio.run_coroutine_threadsafe(self.gateway.stop(), self.gw_loop)
        future.result(30)
        self.gw_loop.call_soon_threadsafe(self.gw_loop.stop)
        self.thread.join(30)
        self.gw_loop.close()
        self.thread = None

    def counters(self) -> dict[str, int]:
        front = self.gateway.component("mb")
        return dict(front.counters)

    def run(self, data: bytes) -> None:
        import socket

        b = Bytes(data)
        stream = stream_from(b)
        parsed = reference_frames(stream)
        with socket.create_connection(("127.0.0.1", self.port), timeout=self.answer_wait_s) as s:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            at = 0
            try:
                while at < len(stream):
                    n = 1 + b.u8() % 64
                    s.sendall(stream[at : at + n])
                    at += n
            except OSError:
                pass  # closed by the server while sending (after a malformed header)
            written, closed = self._read(s, parsed)
        check_stream(stream, written, closed, drained=True)

    def _read(self, s: Any, parsed: Parsed) -> tuple[bytes, bool]:
        """What the server sent until it closed or answered every request (the stream's
        partial frame, if any, is left waiting: the connection then stays open)."""

        data = b""
        deadline = time.monotonic() + self.answer_wait_s
        while time.monotonic() < deadline:
            if not parsed.malformed and len(split_complete(data)) >= len(parsed.frames):
                return data, False
            s.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                chunk = s.recv(65536)
            except TimeoutError:
                break
            except OSError:
                return data, True
            if not chunk:
                return data, True
            data += chunk
        return data, False

    def check(self) -> None:
        import socket

        if self.unhandled:
            raise InvariantBroken(f"unhandled in the gateway's loop: {self.unhandled[0]}")
        if self.counters().get("internal_errors"):
            raise InvariantBroken("the front raised on a request (answered 04)")
        request = HEADER.pack(0x4242, 0, 6, UNIT) + struct.pack(">BHH", 4, 0, 1)
        with socket.create_connection(("127.0.0.1", self.port), timeout=self.answer_wait_s) as s:
            s.sendall(request)
            answer = b""
            while len(answer) < 11:
                chunk = s.recv(64)
                if not chunk:
                    break
                answer += chunk
        if answer[:9] != HEADER.pack(0x4242, 0, 5, UNIT) + b"\x04\x02":
            raise InvariantBroken(f"a fresh client was not served: {answer.hex()}")


def split_complete(data: bytes) -> list[bytes]:
    """The complete MBAP frames at the start of ``data`` (the rest may still be coming)."""
    out, at = [], 0
    while len(data) - at >= 7:
        length = struct.unpack_from(">H", data, at + 4)[0]
        if len(data) - at < 6 + length:
            break
        out.append(data[at : at + 6 + length])
        at += 6 + length
    return out
