"""The HTTP tests' kit: a simulated gateway with its status server on a free loopback port,
and a small HTTP client written here (not the server's code) that shows exactly what went
over the wire."""

from __future__ import annotations

import asyncio
import itertools
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fieldgate import Gateway

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
_channels = itertools.count()


@dataclass
class Reply:
    status: int
    headers: dict[str, str]
    body: bytes
    raw: bytes = b""

    @property
    def text(self) -> str:
        return self.body.decode()

    def json(self) -> Any:
        return json.loads(self.body)


def parse_reply(raw: bytes, head_only: bool = False) -> Reply:
    head, _, body = raw.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    version, status, *_ = lines[0].split(" ")
    assert version.startswith("HTTP/"), lines[0]  # errors to HTTP/1.0 (or worse) requests echo it
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    if "content-length" in headers and not head_only:
        assert len(body) == int(headers["content-length"]), (len(body), headers)
    return Reply(int(status), headers, body, raw)


async def send_raw(
    port: int, data: bytes, host: str = "127.0.0.1", head_only: bool = False
) -> Reply:
    """Send bytes as they are; read the answer until the server closes the connection."""
    reader, writer = await asyncio.open_connection(host, port)
    try:
        writer.write(data)
        await writer.drain()
        async with asyncio.timeout(20):
            raw = await reader.read()
    finally:
        writer.close()
    return parse_reply(raw, head_only)


async def get(
    port: int, path: str, headers: dict[str, str] | None = None, method: str = "GET"
) -> Reply:
    lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1", "Connection: close"]
    lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
    data = ("\r\n".join(lines) + "\r\n\r\n").encode()
    return await send_raw(port, data, head_only=method == "HEAD")


async def wait_for(predicate: Callable[[], bool], timeout: float = 15.0) -> None:
    """Poll ``predicate`` on the loop until it holds (fails the test after ``timeout``)."""
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0.02)


@dataclass
class Running:
    gateway: Gateway
    port: int
    channel: str
    events: list[Any] = field(default_factory=list)

    async def get(
        self, path: str, headers: dict[str, str] | None = None, method: str = "GET"
    ) -> Reply:
        return await get(self.port, path, headers, method)


def load_gateway(tmp_path: Path, example: str = "i7232d-style.yaml", **http: Any) -> Gateway:
    channel = f"fieldgate-http-test-{next(_channels)}"
    overrides: dict[str, Any] = {
        "gateway.state_dir": str(tmp_path / "state"),
        "gateway.http.listen": "127.0.0.1:0",
        "gateway.http.metrics_max_age_ms": 0,  # the tests want every scrape fresh
        "fronts.0.interface": "virtual",
        "fronts.0.channel": channel,
    }
    for key, value in http.items():
        overrides[f"gateway.http.{key}"] = value
    return Gateway.load(EXAMPLES / example, overrides=overrides, simulate=True)


async def start(gw: Gateway) -> Running:
    """The status server under test runs in this process, on the gateway itself as its view:
    the tests read its internals (streams, caches, budgets). A gateway runs it in a child
    process of its own against a mirror (tests/isolation/test_isolation_http.py)."""
    from fieldgate.http.service import HttpService

    gw.http = HttpService(gw, gw.topology.gateway.http)
    await gw.http.start()
    await gw.start()
    running = Running(gw, gw.http.server.port, gw.topology.fronts[0].channel)
    gw.context.events.subscribe(running.events.append)
    # every module answered once: the image holds read values
    await wait_for(lambda: all(m.requests for m in gw.health.modules()))
    return running
