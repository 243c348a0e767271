"""Fuzz target of the OPC UA front's wire: the binary protocol's headers and the Hello.

The front runs as ``fieldgate run`` builds it (asyncua's server inside the front's guard)
in an event loop of the target's own; each input is one client connection: a few
messages built from the fuzz buffer (structure-aware: HEL, ACK, ERR, OPN, MSG, CLO, RHE
or three random letters; chunk types F, C, A or a random one; sizes exact, tiny, at the
limits, 0x7FFFFFFF; Hello fields at and around their limits; a valid Hello or secure
channel first, or a fuzzed Hello) fed in pieces to the connection's protocol object, whose
transport records what the server writes. After each input the invariant:

* nothing escaped the protocol (a crash) and the loop saw no unhandled exception;
* no request was answered Bad_InternalError (asyncua's answer to an exception of its own);
* what the server wrote is well framed; after an ERR nothing more, and the connection is
  closed (the server answered ERR or closed, or is waiting for the rest of a message);
* the server holds no more than its limits: the framer at most one message's bytes, no
  connection or session left behind once the client is gone;
* every 100 inputs, a fresh client over a real socket (Hello, OPN, CreateSession) is served.
"""

from __future__ import annotations

import asyncio
import socket
import struct
from collections import Counter
from typing import Any

import uaraw
from fuzz_base import Bytes, InvariantBroken, Target

from fieldgate import Gateway

MESSAGE_TYPES = [b"HEL", b"ACK", b"ERR", b"OPN", b"MSG", b"CLO", b"RHE"]
# the secure channel's most often; an exhausted buffer reads zeros: the first choice is MSG
LIKELY_TYPES = [b"MSG", b"OPN", b"MSG", b"CLO", b"MSG", *MESSAGE_TYPES]
CHUNK_TYPES = [b"F", b"C", b"A"]
INTERESTING = [0, 1, 7, 8, 12, 23, 24, 32, 1024, 8191, 8192, 65535, 65536, 65537, 100_000]
INTERESTING += [1 << 20, 0x7FFF_FFFF, 0x8000_0000, 0xFFFF_FFFF]
URL_LENGTHS = [-2, -1, 0, 1, 4096, 4097, 0x7FFF_FFFF, -0x8000_0000]
FRESH_EVERY = 100


class FakeTransport:
    """What the protocol writes, and whether it closed (no socket)."""

    def __init__(self, peer: tuple[str, int]):
        self.peer = peer
        self.written = bytearray()
        self.closed = False
        self.eof = False
        self.paused = False
        self.after_close = 0  # bytes written once closed: must stay 0

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return {"peername": self.peer, "sockname": ("127.0.0.1", 4840)}.get(name, default)

    def write(self, data: bytes) -> None:
        if self.closed or self.eof:
            self.after_close += len(data)
            return
        self.written += data

    def can_write_eof(self) -> bool:
        return True

    def write_eof(self) -> None:
        self.eof = True

    def pause_reading(self) -> None:
        self.paused = True

    def resume_reading(self) -> None:
        self.paused = False

    def close(self) -> None:
        self.closed = True

    def is_closing(self) -> bool:
        return self.closed


def rarely(b: Bytes) -> bool:
    """One time in eight (never on an exhausted buffer, which reads zeros)."""
    return b.u8() % 8 == 7


def hello_bytes(b: Bytes) -> bytes:
    fields = [65535 if b.chance(2) else b.pick(INTERESTING) for _ in range(2)]
    max_message = b.pick(INTERESTING) if b.chance(3) else 0
    max_chunks = b.pick(INTERESTING) if b.chance(3) else 0
    url = "opc.tcp://127.0.0.1:4840/" if b.chance(2) else b.take(b.u8() % 24).decode("latin-1")
    length = b.pick(URL_LENGTHS) if rarely(b) else None
    return uaraw.hello(url, fields[0], fields[1], max_message, max_chunks, b.u8() % 3, length)


def message_bytes(b: Bytes) -> bytes:
    kind = b.u8() % 8
    if kind == 6:
        return hello_bytes(b)
    if kind == 7:
        valid = bytearray(uaraw.open_secure_channel())
        for _ in range(b.u8() % 3):
            valid[b.u8() % len(valid)] ^= 1 << (b.u8() % 8)
        return bytes(valid)
    message_type = b.take(3) if rarely(b) else b.pick(LIKELY_TYPES)
    chunk_type = b.take(1) if rarely(b) else b.pick(CHUNK_TYPES)
    exact = b.chance(2)
    body = b.take(b.u8() % 48)
    if message_type in (b"OPN", b"MSG", b"CLO") and b.chance(2):
        # a channel id, the token id the server gives, a sequence header: headers that parse
        body = struct.pack("<IIII", b.u8() % 8, 13, 2 + b.u8() % 3, 2) + body
    size = 8 + len(body) if exact else b.pick(INTERESTING)
    return uaraw.header(message_type, chunk_type, size) + body


class OpcUaTarget(Target):
    name = "opcua"
    max_len = 160

    def setup(self) -> None:
        from fieldgate.plugins.opcua.front import OpcUaFront

        self.close()
        self.loop = asyncio.new_event_loop()
        self.unhandled: list[str] = []
        self.loop.set_exception_handler(
            lambda loop, context: self.unhandled.append(str(context.get("exception") or context))
        )
        self.port = uaraw_free_port()
        topology = {
            "gateway": {"name": "fuzz", "state_dir": str(self.work_dir)},
            "fronts": [
                {"name": "ua", "type": "opcua", "listen": f"127.0.0.1:{self.port}"},
            ],
            "backs": [
                {
                    "name": "rs485",
                    "type": "dcon",
                    "port": "/dev/null",
                    "modules": [{"address": 1, "model": "I-7055"}],
                }
            ],
        }
        gateway = Gateway.load(topology, registry=self.registry)
        self.front = OpcUaFront(gateway.topology.fronts[0], gateway.context)
        self.loop.run_until_complete(self.front.start())
        self.runs = 0
        self.answers: Counter[str] = Counter()  # what the server answered, by message type

    def close(self) -> None:
        """Stop the front and its loop (before a new setup, and at the end)."""
        loop = getattr(self, "loop", None)
        if loop is None or loop.is_closed():
            return

        async def stop() -> None:
            await self.front.stop()
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        loop.run_until_complete(stop())
        loop.close()

    @property
    def guard(self) -> Any:
        return self.front.guard

    def run(self, data: bytes) -> None:
        b = Bytes(data)
        self.runs += 1
        stream = bytearray()
        first = b.u8() % 4
        if first == 0:  # (an exhausted buffer: a valid Hello)
            stream += uaraw.hello()
        elif first == 1:
            stream += uaraw.hello() + uaraw.open_secure_channel()
        elif first == 2:
            stream += hello_bytes(b)
        for _ in range(1 + b.u8() % 3):
            stream += message_bytes(b)
        steps = [max(1, (b.u8() * 7) % 64) if b.chance(2) else len(stream) for _ in range(8)]
        self.loop.run_until_complete(self._connection(bytes(stream), steps))

    async def _connection(self, stream: bytes, steps: list[int]) -> None:
        """One client connection: the stream fed in pieces, then the client goes away."""
        protocol = self.front.server.bserver._make_protocol()
        transport = FakeTransport(("127.0.0.9", 40000 + self.runs % 20000))
        protocol.connection_made(transport)
        pos = 0
        for i in range(len(steps) + 1):
            if pos >= len(stream) or transport.closed or transport.eof:
                break
            step = steps[i] if i < len(steps) else len(stream)  # the rest in one piece
            protocol.data_received(stream[pos : pos + step])
            pos += step
            await asyncio.sleep(0)
        for _ in range(3):
            await asyncio.sleep(0)
        self.held = protocol.framer.buffered
        self._check_written(transport)
        protocol.connection_lost(None)
        for _ in range(3):
            await asyncio.sleep(0)

    def _check_written(self, transport: FakeTransport) -> None:
        if transport.after_close:
            raise InvariantBroken(f"{transport.after_close} bytes written after the close")
        messages = uaraw.split_messages(bytes(transport.written))
        if sum(len(m) for m in messages) != len(transport.written):
            raise InvariantBroken(f"badly framed answer {bytes(transport.written[:64])!r}")
        kinds = [m[:3] for m in messages]
        self.answers.update(k.decode("latin-1") for k in kinds)
        if any(k not in (b"ACK", b"ERR", b"OPN", b"MSG", b"CLO") for k in kinds):
            raise InvariantBroken(f"answered {kinds}")
        if b"ERR" in kinds and (kinds.index(b"ERR") != len(kinds) - 1 or not transport.eof):
            raise InvariantBroken(f"ERR not the last answer before the close: {kinds}")

    def check(self) -> None:
        if self.unhandled:
            raise InvariantBroken(f"unhandled in the loop: {self.unhandled[:2]}")
        guard = self.guard
        if guard.faults.get("BadInternalError"):
            raise InvariantBroken(f"answered Bad_InternalError: {dict(guard.faults)}")
        limit = max(self.front.config.max_chunk_size, 4128) + 160
        if self.held > limit:
            raise InvariantBroken(f"held {self.held} bytes of an unfinished message")
        if guard.protocols or guard.admission.connections:
            raise InvariantBroken(f"{len(guard.protocols)} connections left after the client left")
        alive = [s for s in self.front.server.iserver._external_sessions.values()]
        if len(alive) > self.front.config.max_sessions:
            raise InvariantBroken(f"{len(alive)} sessions held")
        if self.runs % FRESH_EVERY == 0:
            self.fresh_client()

    def fresh_client(self) -> None:
        async def serve() -> None:
            reader, writer, channel, token = await uaraw.open_channel("127.0.0.1", self.port)
            writer.close()

        try:
            self.loop.run_until_complete(asyncio.wait_for(serve(), 5))
        except (ConnectionError, OSError, TimeoutError) as exc:
            raise InvariantBroken(f"a fresh client is not served: {exc!r}") from None


def uaraw_free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
