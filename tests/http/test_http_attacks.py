"""The status server under the bug report's attacks, on a running gateway: Host rules for
empty and missing names, the event-stream limit under a rush, TLS, and /healthz answered
while idle, slowloris and would-be streaming clients crowd the port. Behaviour only; the
figures are the probe's (scripts/faults/http_attacks.py, docs/reliability.md)."""

from __future__ import annotations

import asyncio
import ssl
import subprocess

import pytest
from httpkit import load_gateway, send_raw, start

from fieldgate.runtime import GatewayStartError


async def test_an_empty_or_missing_host_is_not_a_loopback_name(running):
    for data in (
        b"GET /api/v1/status HTTP/1.1\r\nHost:\r\nConnection: close\r\n\r\n",
        b"GET /api/v1/status HTTP/1.0\r\n\r\n",
    ):
        reply = await send_raw(running.port, data)
        assert reply.status == 421, data
    assert (await send_raw(running.port, b"GET /healthz HTTP/1.0\r\n\r\n")).status == 200


async def test_event_streams_rushing_in_together_get_exactly_the_limit(tmp_path):
    gw = load_gateway(tmp_path, sse_max_clients=4)
    running = await start(gw)
    try:

        async def client() -> tuple[int, asyncio.StreamWriter]:
            reader, writer = await asyncio.open_connection("127.0.0.1", running.port)
            writer.write(b"GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            line = await reader.readline()
            return int(line.split()[1]), writer

        results = await asyncio.gather(*(client() for _ in range(20)))
        statuses = sorted(status for status, _ in results)
        assert statuses == [200] * 4 + [503] * 16
        assert len(gw.http.streams.clients) == 4
        for _, writer in results:
            writer.close()
        async with asyncio.timeout(10):
            while gw.http.streams.clients:
                await asyncio.sleep(0.02)  # slots come back when the clients go
    finally:
        await gw.stop()


async def test_healthz_is_answered_while_idle_slow_and_streaming_clients_crowd_the_port(running):
    held: list[asyncio.StreamWriter] = []

    async def idle() -> None:
        reader, writer = await asyncio.open_connection("127.0.0.1", running.port)
        held.append(writer)
        writer.write(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        try:
            await reader.readuntil(b"late\n")
        except (ConnectionError, asyncio.IncompleteReadError):
            pass  # evicted to make room: expected once the port is crowded

    async def slow() -> None:
        _, writer = await asyncio.open_connection("127.0.0.1", running.port)
        held.append(writer)
        writer.write(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-a: a")

    async def stream() -> None:
        _, writer = await asyncio.open_connection("127.0.0.1", running.port)
        held.append(writer)
        writer.write(b"GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")

    await asyncio.gather(
        *(idle() for _ in range(300)), *(slow() for _ in range(60)), *(stream() for _ in range(60))
    )
    try:
        server = running.gateway.http.server
        for _ in range(10):
            assert (await running.get("/healthz")).status == 200
            assert (await running.get("/readyz")).status == 200
        assert server.connections <= server.max_connections
        assert len(running.gateway.http.streams.clients) <= 16
    finally:
        for writer in held:
            writer.close()


@pytest.fixture
def certificate(tmp_path):
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        [
            "openssl",
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-days",
            "1",
            "-subj",
            "/CN=localhost",
            "-keyout",
            str(key),
            "-out",
            str(cert),
        ],
        check=True,
        capture_output=True,
    )
    return cert, key


async def test_tls_serves_https_and_refuses_plain_http(tmp_path, certificate):
    cert, key = certificate
    gw = load_gateway(tmp_path, tls_cert_file=str(cert), tls_key_file=str(key))
    running = await start(gw)
    try:
        assert gw.http.url.startswith("https://127.0.0.1:")
        context = ssl.create_default_context(cafile=str(cert))
        context.check_hostname = False
        reader, writer = await asyncio.open_connection("127.0.0.1", running.port, ssl=context)
        writer.write(b"GET /readyz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
        assert (await reader.readline()).startswith(b"HTTP/1.1 200")
        writer.close()
        reader, writer = await asyncio.open_connection("127.0.0.1", running.port)
        writer.write(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
        async with asyncio.timeout(10):
            data = await reader.read()
        assert not data.startswith(b"HTTP/1.1 200")  # no answer in clear text
        writer.close()
    finally:
        await gw.stop()


async def test_an_unusable_certificate_is_one_line(tmp_path):
    bad = tmp_path / "bad.pem"
    bad.write_text("not a certificate")
    gw = load_gateway(tmp_path, tls_cert_file=str(bad), tls_key_file=str(bad))
    with pytest.raises(GatewayStartError, match="tls_cert_file .* cannot use them"):
        await gw.start()
