"""The status server's HTTP layer: aiohttp's low-level server, with fieldgate's budgets.

Why aiohttp (measured, ``bench/http_stacks.py``, docs/observability.md "Why aiohttp"):
the server was ours, on asyncio streams, and the attack cases of a new user's first try
broke it: 64 idle keep-alive connections held every slot and ``/healthz`` got 503 for as
long as they liked, slowloris connections did the same, two ``Content-Length`` or two
``Host`` headers were accepted (request smuggling behind a proxy). aiohttp's parser
(llhttp) refuses conflicting framing and duplicate singleton headers by design, with a
400; it embeds in the gateway's running loop without taking its signals; it costs about
half the CPU per request of uvicorn with h11 (116 us against 242 us per keep-alive
request in the comparison), and it does TLS. What it lacks for a gateway's status port
is kept here, on top of its public server API:

* **budgets, never a lock-out.** A new connection is always accepted: when more than
  ``max_connections`` are open (or more than ``max_per_peer`` from one address), the
  connection that has waited longest *without a request in progress* (an idle keep-alive
  or a slowloris head) is closed to make room. Requests being served and event streams
  are never evicted; event streams have their own limit (``sse_max_clients``, checked
  and taken in one step). So ``/healthz`` and ``/readyz`` are answered whatever idle,
  slow or streaming clients do;
* **head and idle timeouts.** A connection must complete its first request head within
  ``head_timeout`` (else 408 and close) and may idle ``idle_timeout`` between requests:
  a slowloris dribbling one byte a second is closed like any idle client;
* **read-only, no bodies.** GET and HEAD only (405, the service says so), a request with a
  body gets 413, HTTP/1.1 without ``Host`` gets 400, an undecodable query 400;
* **plain errors.** Every error is ``<code> <phrase>: <why>`` in text/plain with
  ``Connection: close``; a handler's exception is logged once and answered 500 without a
  traceback.

Handlers see a :class:`Request` and return a :class:`Response` or a :class:`Stream`
(Server-Sent Events); they never see aiohttp.
"""

from __future__ import annotations

import asyncio
import logging
import ssl
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from http import HTTPStatus
from typing import Any
from urllib.parse import parse_qsl, unquote

from aiohttp import web
from aiohttp.http_exceptions import LineTooLong
from aiohttp.web_protocol import RequestHandler

log = logging.getLogger("fieldgate.http")
logging.getLogger("aiohttp.server").setLevel(logging.CRITICAL)  # bad requests: our 4xx says it
logging.getLogger("aiohttp.access").setLevel(logging.CRITICAL)

MAX_REQUEST_LINE = 8190  # aiohttp's max_line_size
MAX_FIELD = 8190  # one header line
MAX_HEADERS = 64
HEAD_TIMEOUT = 10.0
IDLE_TIMEOUT = 30.0
WRITE_TIMEOUT = 10.0
MAX_CONNECTIONS = 256
MAX_PER_PEER = 128
SWEEP_S = 0.5
SERVER = "fieldgate"


@dataclass
class Request:
    method: str
    target: str  # as sent, e.g. /api/v1/points/rs485%2Fm1%2Fdi0?x=1
    path: str  # percent-decoded path
    query: dict[str, str]
    headers: dict[str, str]  # names in lower case; a repeated header keeps the last value
    peer: str = ""


@dataclass
class Response:
    status: int = 200
    body: bytes = b""
    content_type: str = "text/plain; charset=utf-8"
    headers: list[tuple[str, str]] = field(default_factory=list)


class StreamWriter:
    """What a stream body writes to: ``write`` buffers, ``drain`` sends (and waits while the
    client is behind)."""

    def __init__(self, response: web.StreamResponse) -> None:
        self._response = response
        self._buffer = bytearray()

    def write(self, data: bytes) -> None:
        self._buffer += data

    async def drain(self) -> None:
        if self._buffer:
            data, self._buffer = bytes(self._buffer), bytearray()
            await self._response.write(data)


StreamBody = Callable[[StreamWriter], Awaitable[None]]


@dataclass
class Stream:
    """A response whose body a coroutine writes until it returns (Server-Sent Events).

    The body is cancelled as soon as the client closes its end. ``release`` runs when the
    stream ends, however it ends (the slot it holds, taken when the request was accepted).
    """

    body: StreamBody
    content_type: str = "text/event-stream; charset=utf-8"
    headers: list[tuple[str, str]] = field(default_factory=list)
    release: Callable[[], None] = lambda: None


Handler = Callable[[Request], Awaitable[Response | Stream]]


def text_response(
    status: int, text: str = "", headers: list[tuple[str, str]] | None = None
) -> Response:
    """A plain-text answer: the status line's phrase, then ``text`` when given."""
    phrase = HTTPStatus(status).phrase
    body = f"{status} {phrase}" + (f": {text}" if text else "") + "\n"
    return Response(status, body.encode(), headers=list(headers or []))


class BadRequest(Exception):
    def __init__(self, status: int, text: str):
        super().__init__(text)
        self.status = status
        self.text = text


def parse_target(target: str) -> tuple[str, dict[str, str]]:
    """The percent-decoded path and the query of a request target; BadRequest if undecodable."""
    if not target.startswith("/"):
        raise BadRequest(400, "the target must be an absolute path")
    raw_path, _, raw_query = target.partition("?")
    try:
        path = unquote(raw_path, errors="strict") if "%" in raw_path else raw_path
        query = dict(parse_qsl(raw_query, keep_blank_values=True, errors="strict"))
    except (UnicodeDecodeError, ValueError):
        raise BadRequest(400, "malformed query string") from None
    return path, query


def _common_headers(content_type: str) -> dict[str, str]:
    return {"Server": SERVER, "Content-Type": content_type, "X-Content-Type-Options": "nosniff"}


def _to_aiohttp(response: Response, close: bool) -> web.Response:
    headers = _common_headers(response.content_type)
    for name, value in response.headers:
        headers[name] = value
    if close:
        headers["Connection"] = "close"
    out = web.Response(status=response.status, body=response.body, headers=headers)
    if close:
        out.force_close()
    return out


@dataclass
class _Conn:
    """One open connection, as the budgets see it."""

    handler: RequestHandler
    transport: asyncio.Transport
    peer: str
    opened: float
    waiting_since: float | None  # no request in progress since then (None: serving one)
    requests: int = 0
    refused: bool = False  # over the budget with nothing to evict: answer 503


class _Protocol(RequestHandler):
    """aiohttp's connection handler, with our error page."""

    def handle_error(
        self,
        request: web.BaseRequest,
        status: int = 500,
        exc: BaseException | None = None,
        message: str | None = None,
    ) -> web.StreamResponse:
        if status >= 500:
            text = "internal error (logged by the gateway)"
        elif isinstance(exc, LineTooLong) or "Too many headers" in str(exc):
            status, text = (
                431,
                f"request head too large (at most {MAX_HEADERS} fields of {MAX_FIELD} bytes)",
            )
        else:
            text = _reason(exc, message)
        owner = getattr(self._manager, "_owner", None)  # our _Server's HttpServer
        if owner is not None:
            owner.responses[status] += 1
        return _to_aiohttp(text_response(status, text), close=True)


def _reason(exc: BaseException | None, message: str | None) -> str:
    """The parser's reason, without the excerpt of the request it quotes."""
    text = str(getattr(exc, "message", None) or message or "")
    for cut in (" b'", ' b"', " bytearray("):
        text = text.split(cut)[0]
    return " ".join(text.split()).rstrip(":")[:200]


class _Server(web.Server):
    def __init__(self, owner: HttpServer, **kwargs: Any) -> None:
        super().__init__(owner._dispatch, handler_cancellation=True, **kwargs)
        self._owner = owner

    def __call__(self) -> RequestHandler:
        return _Protocol(self, loop=self._loop, **self._kwargs)

    def connection_made(self, handler: RequestHandler, transport: asyncio.Transport) -> None:
        super().connection_made(handler, transport)
        self._owner._opened(handler, transport)

    def connection_lost(self, handler: RequestHandler, exc: BaseException | None = None) -> None:
        super().connection_lost(handler, exc)
        self._owner._closed(handler)


class HttpServer:
    """Accepts connections and hands each well-formed request to ``handler``."""

    def __init__(
        self,
        handler: Handler,
        host: str,
        port: int,
        *,
        max_connections: int = MAX_CONNECTIONS,
        max_per_peer: int = MAX_PER_PEER,
        head_timeout: float = HEAD_TIMEOUT,
        idle_timeout: float = IDLE_TIMEOUT,
        ssl_context: ssl.SSLContext | None = None,
    ):
        self.handler = handler
        self.host = host
        self.port = port
        self.max_connections = max_connections
        self.max_per_peer = max_per_peer
        self.head_timeout = head_timeout
        self.idle_timeout = idle_timeout
        self.ssl_context = ssl_context
        self.responses: Counter[int] = Counter()  # by status code
        self.evicted = 0  # idle or slow connections closed to make room
        self.timed_out = 0  # connections closed by the head or idle timeout
        self._conns: dict[RequestHandler, _Conn] = {}
        self._server: asyncio.Server | None = None
        self._web: _Server | None = None
        self._sweeper: asyncio.Task[None] | None = None
        self._handler_errors_logged = False

    @property
    def connections(self) -> int:
        return len(self._conns)

    async def start(self) -> None:
        self._web = _Server(
            self,
            max_line_size=MAX_REQUEST_LINE,
            max_field_size=MAX_FIELD,
            max_headers=MAX_HEADERS,
            keepalive_timeout=self.idle_timeout,
            access_log=None,
        )
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            self._web, self.host, self.port, ssl=self.ssl_context, reuse_address=True
        )
        self.port = self._server.sockets[0].getsockname()[1]
        self._sweeper = loop.create_task(self._sweep(), name="fieldgate:http-timeouts")

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        scheme = "https" if self.ssl_context is not None else "http"
        return f"{scheme}://{host}:{self.port}/"

    async def stop(self) -> None:
        if self._sweeper is not None:
            self._sweeper.cancel()
            await asyncio.gather(self._sweeper, return_exceptions=True)
            self._sweeper = None
        if self._server is not None:
            self._server.close()
        if self._web is not None:
            await self._web.shutdown(timeout=1.0)
            self._web = None
        for conn in list(self._conns.values()):
            conn.transport.close()
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None

    # -- budgets --------------------------------------------------------------------------
    def _opened(self, handler: RequestHandler, transport: asyncio.Transport) -> None:
        peername = transport.get_extra_info("peername")
        peer = peername[0] if isinstance(peername, tuple) else str(peername)
        now = time.monotonic()
        conn = _Conn(handler, transport, peer, now, now)
        self._conns[handler] = conn
        if len(self._conns) > self.max_connections:
            self._make_room(lambda c: c is not conn)
        if sum(1 for c in self._conns.values() if c.peer == peer) > self.max_per_peer:
            self._make_room(lambda c: c is not conn and c.peer == peer)
        if len(self._conns) > self.max_connections:  # nothing to evict: every slot is busy
            conn.refused = True  # its request gets a 503 (read first: closing on unread data
            # would reset the connection and the client would never see the answer)

    def _make_room(self, which: Callable[[_Conn], bool]) -> None:
        """Close the connection that has waited longest without a request in progress."""
        waiting = [c for c in self._conns.values() if c.waiting_since is not None and which(c)]
        if waiting:
            oldest = min(waiting, key=lambda c: c.waiting_since or 0.0)
            self.evicted += 1
            self._close(oldest)

    def _refuse(self, conn: _Conn, status: int, text: str) -> None:
        self.responses[status] += 1
        body = text_response(status, text).body
        head = (
            f"HTTP/1.1 {status} {HTTPStatus(status).phrase}\r\nServer: {SERVER}\r\n"
            f"Content-Type: text/plain; charset=utf-8\r\nContent-Length: {len(body)}\r\n"
            "Connection: close\r\n\r\n"
        )
        try:
            conn.transport.write(head.encode("latin-1") + body)
        except Exception:  # noqa: BLE001  (a connection already going away)
            pass
        self._close(conn)

    def _close(self, conn: _Conn) -> None:
        self._conns.pop(conn.handler, None)
        conn.handler.force_close()
        conn.transport.close()

    def _closed(self, handler: RequestHandler) -> None:
        self._conns.pop(handler, None)

    async def _sweep(self) -> None:
        """Close connections past their head or idle timeout (a slowloris is one of them)."""
        while True:
            await asyncio.sleep(SWEEP_S)
            now = time.monotonic()
            for conn in list(self._conns.values()):
                if conn.waiting_since is None:
                    continue
                if conn.requests == 0 and now - conn.waiting_since > self.head_timeout:
                    self.timed_out += 1
                    self._refuse(conn, 408, "request head not received in time")
                elif conn.requests and now - conn.waiting_since > self.idle_timeout:
                    self.timed_out += 1
                    self._close(conn)

    # -- requests -------------------------------------------------------------------------
    async def _dispatch(self, raw: web.BaseRequest) -> web.StreamResponse:
        conn = self._conns.get(raw.protocol) if raw.protocol is not None else None
        if conn is not None:
            conn.waiting_since = None
            conn.requests += 1
        try:
            if conn is not None and conn.refused:
                return self._count(
                    _to_aiohttp(text_response(503, "too many connections busy"), close=True)
                )
            return await self._answer(raw)
        finally:
            if conn is not None:
                conn.waiting_since = time.monotonic()

    async def _answer(self, raw: web.BaseRequest) -> web.StreamResponse:
        try:
            request = self._request(raw)
        except BadRequest as exc:
            return self._count(_to_aiohttp(text_response(exc.status, exc.text), close=True))
        try:
            result = await self.handler(request)
        except asyncio.CancelledError:
            raise
        except Exception:
            if not self._handler_errors_logged:
                log.exception("HTTP handler failed on %s %s", request.method, request.path)
                self._handler_errors_logged = True
            result = text_response(500, "internal error (logged by the gateway)")
        if isinstance(result, Stream):
            return await self._stream(raw, result)
        return self._count(_to_aiohttp(result, close=result.status >= 400 or not raw.keep_alive))

    def _request(self, raw: web.BaseRequest) -> Request:
        headers: dict[str, str] = {}
        for name, value in raw.headers.items():
            headers[name.lower()] = value
        if raw.version not in ((1, 0), (1, 1)):
            if raw.version < (1, 0):
                raise BadRequest(400, "malformed request line (no HTTP version)")
            raise BadRequest(505, "HTTP/1.1 or HTTP/1.0 only")
        if raw.version >= (1, 1) and "host" not in headers:
            raise BadRequest(400, "HTTP/1.1 requests need a Host header")
        if raw.body_exists or "transfer-encoding" in headers:
            raise BadRequest(413, "this server accepts no request bodies")
        if headers.get("content-length", "0") not in ("0", ""):
            raise BadRequest(413, "this server accepts no request bodies")
        path, query = parse_target(raw.raw_path)
        peer = raw.remote or ""
        return Request(raw.method, raw.raw_path, path, query, headers, peer)

    def _count(self, response: web.Response) -> web.Response:
        self.responses[response.status] += 1
        return response

    async def _stream(self, raw: web.BaseRequest, stream: Stream) -> web.StreamResponse:
        headers = _common_headers(stream.content_type)
        headers["Cache-Control"] = "no-store"
        for name, value in stream.headers:
            headers[name] = value
        response = web.StreamResponse(status=200, headers=headers)
        response.force_close()  # an event stream takes no further requests
        try:
            self.responses[200] += 1
            await response.prepare(raw)
            await stream.body(StreamWriter(response))
        except (ConnectionError, RuntimeError):
            pass  # the client went away: nothing more to send
        finally:
            stream.release()
        return response
