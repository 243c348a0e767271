"""Bad requests get a plain HTTP error, never a traceback; limits hold."""

from __future__ import annotations

import asyncio

import pytest
from httpkit import get, parse_reply, send_raw

from fieldgate.http import server as http_server
from fieldgate.http.server import HttpServer, Request, Response, parse_head


@pytest.fixture
async def server():
    async def handler(request: Request) -> Response:
        if request.path == "/boom":
            raise RuntimeError("secret internals")
        return Response(
            200, f"{request.method} {request.path} {sorted(request.query.items())}".encode()
        )

    srv = HttpServer(handler, "127.0.0.1", 0, max_connections=3, head_timeout=0.3)
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
        (request("GET / FOO/1.1"), 400, "HTTP/1.1 or HTTP/1.0 only"),
        (request("GET /"), 400, "malformed request line"),
        (request("get / HTTP/1.1"), 400, "malformed method"),
        (request("GET http://x/ HTTP/1.1"), 400, "absolute path"),
        (b"GET / HTTP/1.1\r\n\r\n", 400, "Host header"),
        (request("GET / HTTP/1.1", "Bad Header: x"), 400, "malformed header"),
        (request("GET / HTTP/1.1", "Content-Length: 5"), 413, "no request bodies"),
        (request("GET / HTTP/1.1", "Transfer-Encoding: chunked"), 413, "no request bodies"),
        (b"\x00\xff\xfe garbage\r\n\r\n", 400, None),
        (request("GET /" + "a" * 9000 + " HTTP/1.1"), 414, "request line longer"),
        (request("GET / HTTP/1.1", *[f"X-{i}: y" for i in range(70)]), 431, "header fields"),
        (request("GET / HTTP/1.1", "X-Big: " + "y" * 20000), 431, "request head longer"),
        (request("GET /boom HTTP/1.1"), 500, "internal error"),
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
    if why:
        assert why in reply.text


async def test_query_and_percent_decoding(server):
    reply = await get(server.port, "/a%20b?x=1&y=%C3%A9")
    assert reply.text == "GET /a b [('x', '1'), ('y', 'é')]"


async def test_a_slow_client_gets_408(server):
    reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
    writer.write(b"GET / HTTP/1.1\r\nHost: x\r\n")  # never finishes its head
    await writer.drain()
    async with asyncio.timeout(10):
        raw = await reader.read()
    writer.close()
    assert parse_reply(raw).status == 408


async def test_keep_alive_serves_several_requests_on_one_connection(server):
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
    finally:
        writer.close()


async def test_connections_beyond_the_limit_get_503(server):
    held = [await asyncio.open_connection("127.0.0.1", server.port) for _ in range(3)]
    try:
        async with asyncio.timeout(10):
            while server.connections < 3:
                await asyncio.sleep(0.01)
        reply = await get(server.port, "/")
        assert reply.status == 503 and "too many connections" in reply.text
    finally:
        for _, writer in held:
            writer.close()


def test_parse_head_keeps_the_last_of_repeated_headers():
    req = parse_head(b"GET /x?a=1 HTTP/1.0\r\nA: 1\r\na: 2\r\n\r\n")
    assert (req.method, req.path, req.query, req.headers["a"]) == ("GET", "/x", {"a": "1"}, "2")


def test_limits_are_documented_values():
    assert http_server.MAX_HEAD == 16384 and http_server.MAX_REQUEST_LINE == 8192
