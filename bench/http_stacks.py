"""Which asyncio HTTP stack for the status server: the attack cases against each candidate.

Run:  .venv/bin/python bench/http_stacks.py [--stacks own,aiohttp,uvicorn] [--checks 50]
      (about 1 minute per stack)

Each candidate serves the same two endpoints in a child process of its own (one event
loop, as the gateway's): ``/healthz`` (a few bytes) and ``/api/v1/events`` (an event
stream that writes a line every 100 ms and never ends). Then, from this process, on
127.0.0.1 (every client is the same peer, as a local attacker or a crowded proxy is):

1. the framing cases: two conflicting ``Content-Length`` headers, two ``Host`` headers,
   HTTP/1.0 without Host, an empty Host: the status line of each answer;
2. 500 idle keep-alive connections (one request each, then silence), 100 slowloris
   connections (a request head trickled a byte a second) and 100 would-be event-stream
   clients that open the stream and never read;
3. meanwhile, ``--checks`` fresh ``/healthz`` requests, one at a time: how many got a 200
   within 2 s, and their p50/p99;
4. before the attack: the server process's CPU time per keep-alive ``/healthz`` request
   (5,000 of them): what a request takes from the loop the gateway's engines share.

The stacks: ``own`` (fieldgate's server on asyncio streams, before this comparison, with
its 64-connection limit), ``aiohttp`` (aiohttp.web's low-level server, llhttp parser),
``uvicorn`` (an ASGI app on uvicorn with h11). Each runs with its defaults, plus what a
deployment would set without writing a server: aiohttp's and uvicorn's keep-alive timeout.
The figures are written down in docs/observability.md ("Why aiohttp").
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

IDLE, SLOW, STREAMS = 500, 100, 100
REQUESTS = 5000  # keep-alive /healthz requests for the server's CPU time per request


# -- the candidates, each in its own process --------------------------------------------
def serve_own(port: int) -> None:
    from fieldgate.http.server import HttpServer, Response, Stream

    async def events(writer: asyncio.StreamWriter) -> None:
        while True:
            writer.write(b"data: x\n\n")
            await writer.drain()
            await asyncio.sleep(0.1)

    async def handler(request):
        if request.path == "/api/v1/events":
            return Stream(events)
        return Response(200, b"ok\n")

    async def main() -> None:
        server = HttpServer(handler, "127.0.0.1", port)
        await server.start()
        print("ready", flush=True)
        await asyncio.Event().wait()

    asyncio.run(main())


def serve_aiohttp(port: int) -> None:
    from aiohttp import web

    async def handler(request: web.BaseRequest) -> web.StreamResponse:
        if request.path == "/api/v1/events":
            response = web.StreamResponse(headers={"Content-Type": "text/event-stream"})
            await response.prepare(request)
            while True:
                await response.write(b"data: x\n\n")
                await asyncio.sleep(0.1)
        return web.Response(text="ok\n")

    async def main() -> None:
        server = web.Server(handler, keepalive_timeout=30)
        await asyncio.get_running_loop().create_server(server, "127.0.0.1", port)
        print("ready", flush=True)
        await asyncio.Event().wait()

    asyncio.run(main())


def serve_uvicorn(port: int) -> None:
    import uvicorn

    async def app(scope, receive, send):  # type: ignore[no-untyped-def]
        if scope["type"] != "http":
            return
        if scope["path"] == "/api/v1/events":
            await send(
                {
                    "type": "http.response.start",
                    "status": 200,
                    "headers": [(b"content-type", b"text/event-stream")],
                }
            )
            while True:
                await send(
                    {"type": "http.response.body", "body": b"data: x\n\n", "more_body": True}
                )
                await asyncio.sleep(0.1)
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok\n"})

    config = uvicorn.Config(
        app, host="127.0.0.1", port=port, http="h11", log_level="error", timeout_keep_alive=30
    )
    server = uvicorn.Server(config)

    async def main() -> None:
        task = asyncio.create_task(server.serve())
        while not server.started:
            await asyncio.sleep(0.01)
        print("ready", flush=True)
        await task

    asyncio.run(main())


SERVERS = {"own": serve_own, "aiohttp": serve_aiohttp, "uvicorn": serve_uvicorn}


# -- the attacks ----------------------------------------------------------------------------
async def status_of(port: int, data: bytes) -> str:
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
    except OSError as exc:
        return f"refused ({exc.strerror})"
    try:
        writer.write(data)
        await writer.drain()
        async with asyncio.timeout(3):
            line = await reader.readline()
        return line.decode("latin-1").strip() or "closed"
    except (TimeoutError, ConnectionError):
        return "no answer"
    finally:
        writer.close()


FRAMING = {
    "two Content-Length": b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 0\r\n"
    b"Content-Length: 5\r\n\r\nhello",
    "two Host": b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\n\r\n",
    "HTTP/1.0 without Host": b"GET /healthz HTTP/1.0\r\n\r\n",
    "empty Host": b"GET /healthz HTTP/1.1\r\nHost:\r\n\r\n",
}


async def hold(port: int, opened: list[asyncio.StreamWriter], kind: str) -> None:
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
    except OSError:
        return
    opened.append(writer)
    try:
        if kind == "idle":
            writer.write(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            await reader.readuntil(b"ok\n")
            await asyncio.sleep(3600)
        elif kind == "slow":
            for byte in b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-a: " + b"a" * 3600:
                writer.write(bytes([byte]))
                await asyncio.sleep(1.0)
        else:  # a stream client that never reads
            writer.write(b"GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            await asyncio.sleep(3600)
    except (ConnectionError, asyncio.IncompleteReadError, OSError):
        pass


async def healthz(port: int) -> float | None:
    started = time.perf_counter()
    try:
        async with asyncio.timeout(2):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
            line = await reader.readline()
            writer.close()
    except (TimeoutError, OSError):
        return None
    return time.perf_counter() - started if line.startswith(b"HTTP/1.1 200") else None


async def attack(port: int, checks: int) -> dict[str, object]:
    framing = {name: await status_of(port, data) for name, data in FRAMING.items()}
    opened: list[asyncio.StreamWriter] = []
    tasks = [asyncio.create_task(hold(port, opened, "idle")) for _ in range(IDLE)]
    tasks += [asyncio.create_task(hold(port, opened, "slow")) for _ in range(SLOW)]
    tasks += [asyncio.create_task(hold(port, opened, "stream")) for _ in range(STREAMS)]
    await asyncio.sleep(3.0)  # every attacker connected and settled
    times: list[float] = []
    for _ in range(checks):
        t = await healthz(port)
        if t is not None:
            times.append(t)
        await asyncio.sleep(0.1)
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    for writer in opened:
        writer.close()
    ordered = sorted(times)
    return {
        "framing": framing,
        "healthz_ok": len(times),
        "p50_ms": statistics.median(ordered) * 1000 if ordered else None,
        "p99_ms": ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))] * 1000
        if ordered
        else None,
    }


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def keep_alive_requests(port: int, n: int) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    for _ in range(n):
        writer.write(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        await reader.readuntil(b"ok\n")
    writer.close()


def run_stack(name: str, checks: int) -> dict[str, object]:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(
        [sys.executable, __file__, "--serve", name, "--port", str(port)],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert proc.stdout is not None
        if proc.stdout.readline().strip() != "ready":
            raise SystemExit(f"{name} did not start")
        asyncio.run(keep_alive_requests(port, 500))  # warm-up
        before = cpu_seconds(proc.pid)
        asyncio.run(keep_alive_requests(port, REQUESTS))
        cpu = (cpu_seconds(proc.pid) - before) / REQUESTS
        return {**asyncio.run(attack(port, checks)), "cpu_us": cpu * 1e6}
    finally:
        proc.kill()
        proc.wait()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stacks", default="own,aiohttp,uvicorn")
    parser.add_argument("--checks", type=int, default=50)
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        SERVERS[args.serve](args.port)
        return 0
    print(
        f"/healthz during {IDLE} idle keep-alive, {SLOW} slowloris and {STREAMS} non-reading "
        f"event-stream connections ({args.checks} checks, 2 s each at most)"
    )
    for name in args.stacks.split(","):
        result = run_stack(name, args.checks)
        p50, p99 = result["p50_ms"], result["p99_ms"]
        print(f"\n{name}: /healthz answered {result['healthz_ok']}/{args.checks}", end="")
        print(f", p50 {p50:.1f} ms, p99 {p99:.1f} ms" if p50 is not None else "")
        print(f"  server CPU per keep-alive request (on its event loop): {result['cpu_us']:.0f} us")
        for case, line in result["framing"].items():  # type: ignore[attr-defined]
            print(f"  {case:24} -> {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
