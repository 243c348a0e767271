"""A small, strict HTTP/1.1 server on asyncio streams, for read-only status endpoints.

Why our own and not aiohttp: the gateway serves a handful of GET endpoints to a few
clients; a server on ``asyncio.start_server`` is ~250 lines we can bound exactly (request
line, header block, header count, timeouts, connections), while aiohttp would bring a
dozen transitive packages and its own idea of the event loop's load.

Limits (a client that breaks one gets a plain-text 4xx and the connection is closed):

* the request line and headers together at most :data:`MAX_HEAD` bytes (431), the
  request line at most :data:`MAX_REQUEST_LINE` (414), at most :data:`MAX_HEADERS`
  headers (431), read within :data:`HEAD_TIMEOUT` (408);
* no request bodies (read-only: 413), GET and HEAD only (405 with ``Allow``);
* keep-alive idle connections close after :data:`IDLE_TIMEOUT`; writes that cannot drain
  within :data:`WRITE_TIMEOUT` close the connection;
* at most ``max_connections`` at once: beyond that a 503 and close.

Handlers never see a malformed request and any exception in one is logged once and
answered with a 500 without a traceback.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import Counter
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from email.utils import formatdate
from http import HTTPStatus
from urllib.parse import parse_qsl, unquote

log = logging.getLogger("fieldgate.http")

MAX_HEAD = 16 * 1024
MAX_REQUEST_LINE = 8 * 1024
MAX_HEADERS = 64
HEAD_TIMEOUT = 10.0
IDLE_TIMEOUT = 30.0
WRITE_TIMEOUT = 10.0
MAX_CONNECTIONS = 64
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


StreamBody = Callable[[asyncio.StreamWriter], Awaitable[None]]


@dataclass
class Stream:
    """A response whose body a coroutine writes until it returns (Server-Sent Events).

    The body is cancelled as soon as the client closes its end (or sends anything more:
    an event stream takes no further requests on its connection).
    """

    body: StreamBody
    content_type: str = "text/event-stream; charset=utf-8"
    headers: list[tuple[str, str]] = field(default_factory=list)


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


def parse_head(data: bytes, peer: str = "") -> Request:
    """The request line and headers (``data`` ends with the blank line), or BadRequest."""
    try:
        text = data.decode("latin-1")
    except UnicodeDecodeError:  # pragma: no cover - latin-1 decodes every byte
        raise BadRequest(400, "undecodable request") from None
    lines = text[:-4].split("\r\n") if text.endswith("\r\n\r\n") else text.split("\r\n")
    request_line = lines[0]
    if len(request_line) > MAX_REQUEST_LINE:
        raise BadRequest(414, f"request line longer than {MAX_REQUEST_LINE} bytes")
    parts = request_line.split(" ")
    if len(parts) != 3:
        raise BadRequest(400, "malformed request line")
    method, target, version = parts
    if version not in ("HTTP/1.1", "HTTP/1.0"):
        raise BadRequest(505 if version.startswith("HTTP/") else 400, "HTTP/1.1 or HTTP/1.0 only")
    if not method.isalpha() or not method.isupper():
        raise BadRequest(400, "malformed method")
    if not target.startswith("/") or any(ord(c) <= 32 or ord(c) >= 127 for c in target):
        raise BadRequest(400, "the target must be an absolute path")
    headers_lines = lines[1:]
    if len(headers_lines) > MAX_HEADERS:
        raise BadRequest(431, f"more than {MAX_HEADERS} header fields")
    headers: dict[str, str] = {}
    for line in headers_lines:
        name, sep, value = line.partition(":")
        if not sep or not name or name != name.strip() or " " in name:
            raise BadRequest(400, "malformed header field")
        headers[name.lower()] = value.strip()
    if version == "HTTP/1.1" and "host" not in headers:
        raise BadRequest(400, "HTTP/1.1 requests need a Host header")
    raw_path, _, raw_query = target.partition("?")
    try:
        path = unquote(raw_path, errors="strict") if "%" in raw_path else raw_path
        query = dict(parse_qsl(raw_query, keep_blank_values=True, errors="strict"))
    except (UnicodeDecodeError, ValueError):
        raise BadRequest(400, "malformed query string") from None
    request = Request(method, target, path, query, headers, peer)
    request.headers[":version"] = version
    return request


class HttpServer:
    """Accepts connections and hands each well-formed request to ``handler``."""

    def __init__(
        self,
        handler: Handler,
        host: str,
        port: int,
        *,
        max_connections: int = MAX_CONNECTIONS,
        head_timeout: float = HEAD_TIMEOUT,
        idle_timeout: float = IDLE_TIMEOUT,
    ):
        self.handler = handler
        self.host = host
        self.port = port
        self.max_connections = max_connections
        self.head_timeout = head_timeout
        self.idle_timeout = idle_timeout
        self.responses: Counter[int] = Counter()  # by status code
        self.connections = 0
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._handler_errors_logged = False

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._connected, self.host, self.port, limit=MAX_HEAD, reuse_address=True
        )
        sock = self._server.sockets[0]
        self.port = sock.getsockname()[1]

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.wait(self._tasks, timeout=2.0)

    async def _connected(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self.connections += 1
        try:
            if self.connections > self.max_connections:
                # read the request first: closing on unread data would reset the connection
                # and the client would never see the answer
                with contextlib.suppress(Exception):
                    async with asyncio.timeout(1.0):
                        await reader.readuntil(b"\r\n\r\n")
                await self._send(writer, text_response(503, "too many connections"), close=True)
                return
            await self._serve(reader, writer)
        except (ConnectionError, TimeoutError, asyncio.IncompleteReadError):
            pass
        except asyncio.CancelledError:
            # stop() cancels open connections; ending here keeps asyncio's start_server
            # callback (Python 3.11) from logging the cancellation as an error
            pass
        finally:
            self.connections -= 1
            self._tasks.discard(task)
            writer.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        peer_text = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        first = True
        while True:
            try:
                # the first request must arrive in full within head_timeout; between
                # keep-alive requests the connection may idle for idle_timeout
                async with asyncio.timeout(self.head_timeout if first else self.idle_timeout):
                    data = await reader.readuntil(b"\r\n\r\n")
            except asyncio.LimitOverrunError:
                await self._send(
                    writer, text_response(431, f"request head longer than {MAX_HEAD} bytes"), True
                )
                return
            except TimeoutError:
                if first:
                    await self._send(
                        writer, text_response(408, "request head not received in time"), True
                    )
                return
            except asyncio.IncompleteReadError:
                return  # the client closed between requests
            first = False
            try:
                request = parse_head(data, peer_text)
                keep_alive = self._keep_alive(request)
                if "transfer-encoding" in request.headers or request.headers.get(
                    "content-length", "0"
                ) not in ("0", ""):
                    raise BadRequest(413, "this server accepts no request bodies")
            except BadRequest as exc:
                await self._send(writer, text_response(exc.status, exc.text), close=True)
                return
            try:
                result = await self.handler(request)
            except Exception:
                if not self._handler_errors_logged:
                    log.exception("HTTP handler failed on %s %s", request.method, request.path)
                    self._handler_errors_logged = True
                result = text_response(500, "internal error (logged by the gateway)")
            if isinstance(result, Stream):
                await self._stream(reader, writer, result)
                return
            await self._send(writer, result, close=not keep_alive, head=request.method == "HEAD")
            if not keep_alive:
                return

    @staticmethod
    def _keep_alive(request: Request) -> bool:
        connection = request.headers.get("connection", "").lower()
        if request.headers[":version"] == "HTTP/1.0":
            return connection == "keep-alive"
        return connection != "close"

    async def _send(
        self, writer: asyncio.StreamWriter, response: Response, close: bool, head: bool = False
    ) -> None:
        self.responses[response.status] += 1
        lines = [
            f"HTTP/1.1 {response.status} {HTTPStatus(response.status).phrase}",
            f"Server: {SERVER}",
            f"Date: {formatdate(usegmt=True)}",
            f"Content-Type: {response.content_type}",
            f"Content-Length: {len(response.body)}",
            "X-Content-Type-Options: nosniff",
            *(f"{name}: {value}" for name, value in response.headers),
        ]
        if close:
            lines.append("Connection: close")
        head_bytes = ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")
        writer.write(head_bytes if head else head_bytes + response.body)
        async with asyncio.timeout(WRITE_TIMEOUT):
            await writer.drain()

    async def _stream(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, stream: Stream
    ) -> None:
        self.responses[200] += 1
        lines = [
            "HTTP/1.1 200 OK",
            f"Server: {SERVER}",
            f"Content-Type: {stream.content_type}",
            "Cache-Control: no-store",
            "X-Content-Type-Options: nosniff",
            "Connection: close",
            *(f"{name}: {value}" for name, value in stream.headers),
        ]
        writer.write(("\r\n".join(lines) + "\r\n\r\n").encode("latin-1"))
        async with asyncio.timeout(WRITE_TIMEOUT):
            await writer.drain()
        body = asyncio.ensure_future(stream.body(writer))
        gone = asyncio.ensure_future(reader.read(1))  # EOF (b"") when the client closes
        try:
            await asyncio.wait({body, gone}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (body, gone):
                task.cancel()
            await asyncio.gather(body, gone, return_exceptions=True)
