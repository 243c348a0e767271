"""Bad requests get a plain HTTP error, never a traceback; budgets and timeouts hold; no
client can lock the status port (the server is aiohttp's, our budgets on top)."""

from __future__ import annotations

import asyncio

import pytest
from httpkit import get, parse_reply, send_raw

from fieldgate.http import server as http_server
from fieldgate.http.server import HttpServer, Request, Response, Stream


@pytest.fixture
async def server():
    async def stream_body(writer):
        while True:
            writer.write(b"data: x\n\n")
            await writer.drain()
            await asyncio.sleep(0.05)

    async def handler(request: Request) -> Response | Stream:
        if request.path == "/boom":
            raise RuntimeError("secret internals")
        if request.path == "/stream":
            return Stream(stream_body)
        return Response(
            200, f"{request.method} {request.path} {sorted(request.query.items())}".encode()
        )

    srv = HttpServer(
        handler,
        "127.0.0.1",
        0,
        max_connections=4,
        max_per_peer=4,
        head_timeout=0.3,
        idle_timeout=0.6,
    )
    await srv.start()
    yield srv
    await srv.stop()


def request(line: str = "GET / HTTP/1.1", *headers: str, close: bool = True) -> bytes:
    extra = ["Connection: close"] if close else []
    return ("\r\n".join([line, "Host: x", *extra, *headers]) + "\r\n\r\n").encode()


@pytest.mark.parametrize(
    ("data", "status", "why"),
    [
        (request("GET /%zz HTTP/1.1"), 200, None),  # a stray % stays literal (no valid escape)
        (request("GET /%ff%fe HTTP/1.1"), 400, "malformed query string"),
        (request("GET / HTTP/2.0"), 505, "HTTP/1.1 or HTTP/1.0 only"),
        (request("GET / FOO/1.1"), 400, "Bad status line"),
        (request("GET /"), 400, "no HTTP version"),
        (request("get / HTTP/1.1"), 400, "Invalid method"),
        (request("GET http://x/ HTTP/1.1"), 400, "absolute path"),
        (b"GET / HTTP/1.1\r\n\r\n", 400, "Host"),
        (request("GET / HTTP/1.1", "Bad Header: x"), 400, "Invalid header"),
        (request("GET / HTTP/1.1", "Content-Length: 5"), 413, "no request bodies"),
        (request("GET / HTTP/1.1", "Transfer-Encoding: chunked"), 413, "no request bodies"),
        (b"\x00\xff\xfe garbage\r\n\r\n", 400, None),
        (request("GET /" + "a" * 9000 + " HTTP/1.1"), 431, "request head too large"),
        (
            request("GET / HTTP/1.1", *[f"X-{i}: y" for i in range(70)]),
            431,
            "request head too large",
        ),
        (request("GET / HTTP/1.1", "X-Big: " + "y" * 20000), 431, "request head too large"),
        (request("GET /boom HTTP/1.1"), 500, "internal error"),
        # request smuggling behind a proxy: conflicting framing, two Host headers
        (
            request("GET / HTTP/1.1", "Content-Length: 0", "Content-Length: 5"),
            400,
            "Content-Length",
        ),
        (b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\n\r\n", 400, "Host"),
    ],
)
async def test_bad_requests_get_plain_errors(server, data, status, why):
    reply = await send_raw(server.port, data)
    assert reply.status == status, reply.raw[:200]
    if status != 200:
        assert reply.headers["content-type"] == "text/plain; charset=utf-8"
        assert reply.headers["connection"] == "close"
        assert reply.text.startswith(f"{status} ")
        assert "Traceback" not in reply.text and "secret internals" not in reply.text
        assert "yyyy" not in reply.text  # the request is not quoted back
    if why:
        assert why in reply.text


async def test_query_and_percent_decoding(server):
    reply = await get(server.port, "/a%20b?x=1&y=%C3%A9")
    assert reply.text == "GET /a b [('x', '1'), ('y', 'é')]"
    assert reply.headers["server"] == "fieldgate"


async def test_a_slow_client_gets_408(server):
    reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
    writer.write(b"GET / HTTP/1.1\r\nHost: x\r\n")  # never finishes its head
    await writer.drain()
    async with asyncio.timeout(10):
        raw = await reader.read()
    writer.close()
    assert parse_reply(raw).status == 408
    assert server.timed_out == 1


async def test_a_slowloris_dribbling_bytes_is_closed_all_the_same(server):
    reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
    async with asyncio.timeout(10):
        try:
            for byte in b"GET / HTTP/1.1\r\nHost: x\r\nX-a: " + b"a" * 100:
                writer.write(bytes([byte]))
                await writer.drain()
                await asyncio.sleep(0.02)  # 2 s in all: far past head_timeout
        except ConnectionError:
            pass  # closed by the server while we were still sending (its 408 may be lost)
    writer.close()
    assert server.timed_out == 1


async def test_keep_alive_serves_several_requests_then_idles_out(server):
    reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
    try:
        for path in ("/one", "/two"):
            writer.write(request(f"GET {path} HTTP/1.1", close=False))
            head = await reader.readuntil(b"\r\n\r\n")
            length = int(
                next(
                    h for h in head.split(b"\r\n") if h.lower().startswith(b"content-length")
                ).split(b":")[1]
            )
            body = await reader.readexactly(length)
            assert b"Connection: close" not in head
            assert body.startswith(f"GET {path}".encode())
        async with asyncio.timeout(10):
            assert await reader.read() == b""  # closed after idle_timeout
    finally:
        writer.close()


async def test_idle_and_slow_connections_never_lock_out_a_new_request(server):
    held = []
    for i in range(6):  # more than max_connections: idle keep-alive and half-sent heads
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        if i % 2:
            writer.write(request("GET /idle HTTP/1.1", close=False))
            await reader.readuntil(b"GET /idle []")
        else:
            writer.write(b"GET / HTTP/1.1\r\nHost: x\r\n")
        held.append(writer)
    try:
        for _ in range(5):
            reply = await get(server.port, "/healthz")
            assert reply.status == 200
        assert server.evicted >= 3 and server.connections <= 4
    finally:
        for writer in held:
            writer.close()


async def test_when_every_slot_serves_a_stream_a_new_client_gets_503_at_once(server):
    streams = []
    for _ in range(4):
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(request("GET /stream HTTP/1.1", close=False))
        await reader.readuntil(b"data: x")
        streams.append(writer)
    try:
        reply = await get(server.port, "/healthz")
        assert reply.status == 503 and "busy" in reply.text
    finally:
        for writer in streams:
            writer.close()


def test_limits_are_documented_values():
    assert http_server.MAX_REQUEST_LINE == 8190 and http_server.MAX_HEADERS == 64
    assert (http_server.HEAD_TIMEOUT, http_server.IDLE_TIMEOUT) == (10.0, 30.0)
