"""The Modbus TCP listener: asyncio sockets (and TLS) around :mod:`.mbap`'s framing.

Each connection is a :class:`asyncio.BufferedProtocol` that reads into its
:class:`~.mbap.MbapConnection`'s one-frame buffer, so the kernel keeps whatever a client
sends beyond it (TCP flow control) and nothing is buffered on a header's word. Admission
(:func:`~.mbap.admit`) runs when a connection is made: at once for TCP, after the handshake
for TLS (asyncio's ``ssl_handshake_timeout``, set to the request timeout, closes a handshake
that does not finish: until then a TLS connection holds no slot, as in the HTTP server;
uvloop's ``start_tls`` on an accepted connection loses the ClientHello, so admission cannot
come before it). A sweep every :data:`SWEEP_S` closes the connections whose timers ran out.

The server hands each request to ``handler`` (the front): it returns the answer PDU, or an
awaitable of it for a write (answered once the write is applied). Requests of one connection
are served in order, one at a time; reads are answered in the same loop turn.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
import ssl
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from .mbap import MALFORMED, Frame, Limits, MbapConnection, admit, answer
from .pdu import SERVER_DEVICE_FAILURE, exception

SWEEP_S = 0.25
WRITE_BUFFER_HIGH = 16 * 1024  # answers a client has not read: past this, its requests wait
SOCKET_RCVBUF = 16 * 1024  # the kernel's buffers per connection (Linux doubles them), so a
SOCKET_SNDBUF = 32 * 1024  # client that sends without reading holds little there either
BACKLOG = 128
WARN_PEERS = 32  # refused addresses logged (each once); past them, refusals are counted only
GRACEFUL = (MALFORMED,)  # closed with a FIN; a timeout or an eviction resets (below)

Handler = Callable[[Frame], bytes | Awaitable[bytes]]


@dataclass(frozen=True)
class ServerLimits:
    max_clients: int
    max_per_peer: int
    connection: Limits


class Connection(asyncio.BufferedProtocol):
    def __init__(self, server: ModbusTcpServer):
        self.server = server
        self.engine = MbapConnection(server.limits.connection, time.monotonic())
        self.transport: Any = None
        self.peer = ""
        self.address = ""  # peer:port
        self.busy = False  # a write is being applied
        self.write_paused = False
        self.reading_paused = False
        self.closed = False

    # -- asyncio protocol -----------------------------------------------------------------
    def connection_made(self, transport: Any) -> None:
        self.transport = transport
        peername = transport.get_extra_info("peername")
        self.peer = str(peername[0]) if isinstance(peername, tuple) else str(peername or "")
        self.address = f"{peername[0]}:{peername[1]}" if isinstance(peername, tuple) else self.peer
        self.server.accepted(self)

    def get_buffer(self, sizehint: int) -> memoryview:
        return self.engine.buffer()

    def buffer_updated(self, nbytes: int) -> None:
        if self.closed:
            return
        now = time.monotonic()
        self.engine.received(nbytes, now)
        self.serve(now)

    def eof_received(self) -> bool:
        return False  # the client is done sending: close

    def pause_writing(self) -> None:
        self.write_paused = True

    def resume_writing(self) -> None:
        self.write_paused = False
        if not self.closed:
            self.serve(time.monotonic())

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed = True
        self.server.forget(self)

    # -- serving --------------------------------------------------------------------------
    def serve(self, now: float) -> None:
        engine = self.engine
        while not self.busy and not self.write_paused:
            frame = engine.next_frame()
            if frame is None:
                break
            try:
                result = self.server.handler(frame)
            except Exception:  # noqa: BLE001  (a bug in a front must not stop the server)
                self.server.internal_error(frame)
                result = exception(frame.pdu[0], SERVER_DEVICE_FAILURE)
            if isinstance(result, bytes):
                self.transport.write(answer(frame, result))
                engine.served(now)
            else:
                self.busy = True
                self.server.track(asyncio.ensure_future(self._finish(frame, result)))
        if engine.close_reason is not None:
            self.close(engine.close_reason)
        else:
            self._flow()

    async def _finish(self, frame: Frame, pending: Awaitable[bytes]) -> None:
        try:
            result = await pending
        except Exception:  # noqa: BLE001
            self.server.internal_error(frame)
            result = exception(frame.pdu[0], SERVER_DEVICE_FAILURE)
        self.busy = False
        if self.closed:
            return  # applied; the client left before its answer
        now = time.monotonic()
        self.transport.write(answer(frame, result))
        self.engine.served(now)
        self.serve(now)

    def _flow(self) -> None:
        wanted = self.engine.wants_reading
        if wanted and self.reading_paused:
            self.reading_paused = False
            self.transport.resume_reading()
        elif not wanted and not self.reading_paused:
            self.reading_paused = True
            self.server.counters["pipeline_full"] += 1
            self.transport.pause_reading()

    def close(self, reason: str | None = None) -> None:
        """Close now. A malformed frame gets a FIN after the answers already sent; an idle,
        slow or evicted connection a reset, which also drops what the kernel still holds for
        it (a client that never reads would keep a closing socket and its unsent answers)."""
        if self.closed:
            return
        self.closed = True
        if reason is not None:
            self.server.counters[f"closed_{reason}"] += 1
        self.server.forget(self)
        transport = self.transport
        if transport is None:
            return
        if reason in GRACEFUL and not transport.get_write_buffer_size() and not self.write_paused:
            transport.close()
        else:
            transport.abort()

    def state(self) -> dict[str, Any]:
        return {
            "peer": self.address,
            "requests": self.engine.requests,
            "idle_s": round(max(0.0, time.monotonic() - self.engine.last_activity), 1),
        }


class ModbusTcpServer:
    """Accepts Modbus TCP (or TLS) connections within ``limits`` and serves their requests."""

    def __init__(
        self,
        handler: Handler,
        host: str,
        port: int,
        limits: ServerLimits,
        *,
        ssl_context: ssl.SSLContext | None = None,
        allowed_peers: list[str] | None = None,
        counters: Counter[str] | None = None,
        log: logging.Logger | None = None,
    ):
        self.handler = handler
        self.host = host
        self.port = port
        self.limits = limits
        self.ssl_context = ssl_context
        self.networks = [ipaddress.ip_network(p, strict=False) for p in allowed_peers or []]
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self.log = log or logging.getLogger("fieldgate.front.modbus-tcp")
        self.connections: list[Connection] = []
        self._tasks: set[asyncio.Future[Any]] = set()
        self._server: asyncio.Server | None = None
        self._sweeper: asyncio.Task[None] | None = None
        self._errors_logged = 0
        self._warned: set[str] = set()  # refused addresses already logged

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            lambda: Connection(self),
            sock=_listening_socket(self.host, self.port),
            ssl=self.ssl_context,
            ssl_handshake_timeout=(
                self.limits.connection.request_timeout if self.ssl_context else None
            ),
        )
        self.port = self._server.sockets[0].getsockname()[1]
        self._sweeper = loop.create_task(self._sweep(), name="fieldgate:modbus-tcp-timers")

    async def serve_forever(self) -> None:
        assert self._server is not None
        await self._server.serve_forever()

    async def stop(self) -> None:
        if self._sweeper is not None:
            self._sweeper.cancel()
            await asyncio.gather(self._sweeper, return_exceptions=True)
            self._sweeper = None
        if self._server is not None:
            self._server.close()
        for conn in list(self.connections):
            conn.close()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None

    # -- admission ------------------------------------------------------------------------
    def peer_allowed(self, host: str) -> bool:
        if not self.networks:
            return True
        try:
            address = ipaddress.ip_address(host.split("%")[0])
        except ValueError:
            return False
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
            address = address.ipv4_mapped  # an IPv4 client of a dual-stack listener
        return any(address in net for net in self.networks)

    def accepted(self, conn: Connection) -> None:
        if not self.peer_allowed(conn.peer):
            self.counters["refused_peer"] += 1
            if conn.peer not in self._warned and len(self._warned) < WARN_PEERS:
                self._warned.add(conn.peer)  # once per address: a scan must not flood the log
                self.log.warning(
                    "Modbus TCP connection from %s refused: not in allowed_peers%s",
                    conn.peer,
                    " (further refusals are only counted)"
                    if len(self._warned) == WARN_PEERS
                    else "",
                )
            conn.closed = True
            conn.transport.close()
            return
        limits = self.limits
        evict = admit(
            conn.peer,
            self.connections,
            limits.max_clients,
            min(limits.max_per_peer, limits.max_clients),
        )
        if evict is None:
            self.counters["refused_busy"] += 1
            conn.closed = True
            conn.transport.close()
            return
        for other in evict:
            other.close("evicted")
        self.connections.append(conn)
        self.counters["connections"] += 1
        conn.transport.set_write_buffer_limits(high=WRITE_BUFFER_HIGH)

    def forget(self, conn: Connection) -> None:
        try:
            self.connections.remove(conn)
        except ValueError:
            pass

    def track(self, future: asyncio.Future[Any]) -> None:
        self._tasks.add(future)
        future.add_done_callback(self._tasks.discard)

    def internal_error(self, frame: Frame) -> None:
        self.counters["internal_errors"] += 1
        if self._errors_logged < 3:
            self._errors_logged += 1
            self.log.exception("Modbus TCP request %s failed (answered 04)", frame.pdu[:8].hex())

    def sweep(self, now: float) -> None:
        """Close the connections whose idle or request timer ran out by ``now``."""
        for conn in list(self.connections):
            reason = conn.engine.expire(now)
            if reason is not None:
                conn.close(reason)

    async def _sweep(self) -> None:
        while True:
            await asyncio.sleep(SWEEP_S)
            self.sweep(time.monotonic())


def _listening_socket(host: str, port: int) -> socket.socket:
    """The listener, with small kernel buffers that accepted connections inherit."""
    family, kind, proto, _, address = socket.getaddrinfo(
        host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
    )[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if family == socket.AF_INET6:
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SOCKET_RCVBUF)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SOCKET_SNDBUF)
        sock.bind(address)
        sock.listen(BACKLOG)
        sock.setblocking(False)
    except OSError:
        sock.close()
        raise
    return sock
