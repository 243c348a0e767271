"""The status server under attack on a running gateway: /healthz and /readyz latency while
idle, slowloris and would-be streaming clients crowd the port, and the framing cases.

Run:  .venv/bin/python scripts/faults/http_attacks.py [--idle 500] [--slow 100] [--streams 100]
      [--checks 200]   (about 30 s; goal: every check answered, p99 under 100 ms)

A real gateway (examples/i7232d-style.yaml, simulated modules, the CANopen front on the
virtual bus) with its HTTP server on 127.0.0.1 runs in a child process (its own loop, as
``fieldgate run``); this process attacks it from 127.0.0.1, so every client is the same
peer (a local attacker, or a crowded reverse proxy): ``--idle`` keep-alive connections
that send one request and then a new one every 25 s with no token, ``--slow`` slowloris
connections trickling a request head a byte a second, ``--streams`` clients opening
``/api/v1/events`` at the same moment and never reading. Meanwhile ``--checks`` fresh
``/healthz`` and ``/readyz`` requests, 20 a second, are timed (2 s at most each). Printed:
answered, p50/p99/max, what the attackers got (streams accepted vs refused, connections
the server evicted or timed out), the framing cases' status lines.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

FRAMING = {
    "two Content-Length": b"GET /api/v1/status HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 0\r\n"
    b"Content-Length: 7\r\n\r\nGET / H",
    "two Host": b"GET /api/v1/status HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\n\r\n",
    "HTTP/1.0 without Host": b"GET /api/v1/status HTTP/1.0\r\n\r\n",
    "empty Host": b"GET /api/v1/status HTTP/1.1\r\nHost:\r\nConnection: close\r\n\r\n",
}
EXPECTED = {
    "two Content-Length": "400",
    "two Host": "400",
    "HTTP/1.0 without Host": "421",
    "empty Host": "421",
}


def serve_gateway(state_dir: str) -> None:
    """The child: a gateway with its HTTP server; prints its URL, runs until stdin closes."""
    sys.path.insert(0, str(ROOT))
    from fieldgate.runtime import Gateway

    async def main() -> None:
        gateway = Gateway.load(
            ROOT / "examples" / "i7232d-style.yaml",
            overrides={
                "gateway.state_dir": state_dir,
                "gateway.http.listen": "127.0.0.1:0",
                "fronts.can.channel": f"http-attacks-{os.getpid()}",
            },
            simulate=True,
            animate=True,
        )
        await gateway.start()
        assert gateway.http is not None
        print(gateway.http.url, flush=True)
        await asyncio.to_thread(sys.stdin.read)
        status = gateway.status()
        print(json.dumps(gateway.http.stats() | {"ready": status.get("ready")}), flush=True)
        await gateway.stop()

    asyncio.run(main())


async def status_line(port: int, data: bytes) -> str:
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


async def idle(port: int, held: list[asyncio.StreamWriter]) -> None:
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        held.append(writer)
        while True:
            writer.write(b"GET /api/v1/status HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            await reader.readuntil(b"\r\n\r\n")
            await asyncio.sleep(25)
    except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
        pass


async def slowloris(port: int, held: list[asyncio.StreamWriter]) -> None:
    try:
        _, writer = await asyncio.open_connection("127.0.0.1", port)
        held.append(writer)
        for byte in b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-a: " + b"a" * 3600:
            writer.write(bytes([byte]))
            await writer.drain()
            await asyncio.sleep(1.0)
    except OSError:
        pass


async def stream(port: int, held: list[asyncio.StreamWriter], got: dict[str, int]) -> None:
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        held.append(writer)
        writer.write(b"GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        line = await reader.readline()
        got[line.split(b" ")[1].decode() if line else "closed"] += 1
        await asyncio.sleep(3600)  # and never read again
    except (OSError, IndexError):
        got["error"] += 1


async def check(port: int, path: str) -> float | None:
    started = time.perf_counter()
    try:
        async with asyncio.timeout(2):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(
                f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode()
            )
            line = await reader.readline()
            writer.close()
    except (TimeoutError, OSError):
        return None
    return time.perf_counter() - started if line.startswith(b"HTTP/1.1 200") else None


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


async def attack(port: int, args: argparse.Namespace) -> dict[str, object]:
    framing = {name: await status_line(port, data) for name, data in FRAMING.items()}
    quiet = [t for t in [await check(port, "/healthz") for _ in range(20)] if t is not None]
    held: list[asyncio.StreamWriter] = []
    got: dict[str, int] = {"200": 0, "503": 0, "closed": 0, "error": 0}
    tasks = [asyncio.create_task(idle(port, held)) for _ in range(args.idle)]
    tasks += [asyncio.create_task(slowloris(port, held)) for _ in range(args.slow)]
    tasks += [asyncio.create_task(stream(port, held, got)) for _ in range(args.streams)]
    await asyncio.sleep(2.0)  # the crowd is in
    times: dict[str, list[float]] = {"/healthz": [], "/readyz": []}
    failed = 0
    for i in range(args.checks):
        path = "/healthz" if i % 2 == 0 else "/readyz"
        t = await check(port, path)
        if t is None:
            failed += 1
        else:
            times[path].append(t)
        await asyncio.sleep(0.05)
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    for writer in held:
        writer.close()
    return {"framing": framing, "quiet": quiet, "times": times, "failed": failed, "streams": got}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--idle", type=int, default=500)
    parser.add_argument("--slow", type=int, default=100)
    parser.add_argument("--streams", type=int, default=100)
    parser.add_argument("--checks", type=int, default=200)
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve_gateway(args.serve)
        return 0
    with tempfile.TemporaryDirectory() as state:
        proc = subprocess.Popen(
            [sys.executable, __file__, "--serve", state],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert proc.stdout is not None and proc.stdin is not None
        url = proc.stdout.readline().strip()
        port = int(url.rstrip("/").rsplit(":", 1)[1])
        result = asyncio.run(attack(port, args))
        out, _ = proc.communicate("", timeout=30)
        server = json.loads(out.strip().splitlines()[-1])
    print(
        f"gateway status server under {args.idle} idle keep-alive, {args.slow} slowloris and "
        f"{args.streams} would-be event-stream clients (all from 127.0.0.1)"
    )
    ok = True
    quiet = result["quiet"]
    print(
        f"  quiet /healthz: p50 {pct(quiet, 0.5) * 1e3:.1f} ms, p99 {pct(quiet, 0.99) * 1e3:.1f} ms"
    )
    for path, values in result["times"].items():
        if values:
            print(
                f"  {path:9} under attack: answered {len(values)}, p50 {pct(values, 0.5) * 1e3:.1f} ms, "
                f"p99 {pct(values, 0.99) * 1e3:.1f} ms, max {max(values) * 1e3:.1f} ms"
            )
            ok = ok and pct(values, 0.99) < 0.1
    print(f"  checks not answered with 200 within 2 s: {result['failed']} of {args.checks}")
    ok = ok and result["failed"] == 0
    print(f"  stream clients: {result['streams']} (limit sse_max_clients 16: the rest 503 at once)")
    print(
        f"  server: evicted {server['evicted']} idle or half-sent connections, timed out "
        f"{server['timed_out']}, responses {server['responses']}"
    )
    for name, line in result["framing"].items():
        good = line.split(" ")[1:2] == [EXPECTED[name]]
        ok = ok and good
        print(f"  {name:24} -> {line}{'' if good else '   (expected ' + EXPECTED[name] + ')'}")
    print(
        "verdict:",
        "PASS" if ok else "FAIL",
        "(every check answered, p99 < 100 ms, framing refused)",
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
