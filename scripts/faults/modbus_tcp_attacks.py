#!/usr/bin/env python3
"""The Modbus TCP front under hostile clients, on a running gateway: one line per case.

Run:  .venv/bin/python scripts/faults/modbus_tcp_attacks.py [--case d3-flood,d5-desync ...]
          [--flood 500]                   (about 25 s; every case PASS, exit 0)
      .venv/bin/python scripts/faults/modbus_tcp_attacks.py --port 5020 [--http-port 8430]
          (attack a gateway already running; its status API, when given, supplies the limits
          and the counters)

Without --port the probe starts ``fieldgate run examples/plant-northbound.yaml --simulate``
in a child process, every listener on a free 127.0.0.1 port, with the front's timeouts
shortened (``--idle-timeout 3``, ``--request-timeout 1``) so the campaign takes seconds;
the other limits keep their defaults. Every client is on 127.0.0.0/8.

Cases (each prints its measured outcome and PASS/FAIL against what docs/modbus-tcp.md says):

* d3-flood: --flood silent connections from 50 addresses, then 10 fresh clients each read
  once (2 s each); how many were served, how many silent sockets the server still holds.
* d3-slowloris: 12 connections (fewer than the per-peer cap) trickling an MBAP header a byte every 0.2 s; fresh clients
  served, and when the server closed the trickling ones (request timeout).
* d3-idle: one client reads once and goes silent: when the server closes it (idle timeout).
* per-peer: twice max_clients_per_peer silent connections from 127.0.0.1: how many are held;
  a client from 127.0.0.2 served.
* d5-*: a malformed MBAP header on a fresh connection (length 0, 1, 255, 65535, protocol id 1,
  random bytes; length 20 with 5 bytes sent): answered, closed (how fast), or left open.
* d5-desync: a header of length 0 and a valid FC3 request in one segment: what the request got.
* d6: every function code outside FC1-6/15/16/23 (and 0, 128-255): how many answered 01.
* pipeline: 100 requests in one segment, FC6 writes and FC3 reads of the register written:
  answered in order, each read seeing the write before it; reading paused (counter).
* no-reader: a client sends 20,000 requests and never reads: the gateway's RSS growth, a
  fresh client served, when the non-reader is closed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.append(str(ROOT / "tests"))
from netkit import free_port  # noqa: E402  (tests/netkit.py: one helper for tests, benches and scripts)

SERVED = {1, 2, 3, 4, 5, 6, 15, 16, 23}
READ = struct.pack(">BHH", 3, 0, 1)  # FC3, one holding register: every map has one here
BODIES = {43: bytes((0x0E, 0x01, 0x00))}  # FC 43/14: Read Device Identification, basic
LATE_S = 1.5  # a timeout counts as kept when the close comes within this after it (a busy host)


REPORT_LAG_S = 2.2  # a child's status report and the status API's copy of it, a second each


@dataclass
class Target:
    """The gateway attacked: where its Modbus TCP front listens and what it reports."""

    port: int
    status: Callable[[], dict[str, Any]]  # the front's status (limits, counters); {} if unknown
    pid: int | None = None  # the gateway process (for its RSS), when known
    host: str = "127.0.0.1"

    def limits(self) -> dict[str, Any]:
        return dict(self.status().get("limits") or {})

    def counters(self) -> dict[str, int]:
        return dict(self.status().get("counters") or {})

    async def counters_after(self) -> dict[str, int]:
        """The counters once what just happened is in them: the front's child reports once a
        second, and the status API gets the gateway's state once a second."""
        await asyncio.sleep(REPORT_LAG_S)
        return self.counters()


@dataclass
class Outcome:
    case: str
    text: str
    ok: bool
    figures: dict[str, Any] = field(default_factory=dict)

    def line(self) -> str:
        return f"{self.case:16} {'PASS' if self.ok else 'FAIL'}  {self.text}"


def mbap(pdu: bytes, tid: int = 1, unit: int = 1) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


async def connect(target: Target, source: str | None = None) -> tuple[Any, Any]:
    local = (source, 0) if source else None
    return await asyncio.open_connection(target.host, target.port, local_addr=local)


async def read_frame(reader: asyncio.StreamReader) -> tuple[int, bytes]:
    head = await reader.readexactly(7)
    tid, _proto, length, _unit = struct.unpack(">HHHB", head)
    return tid, await reader.readexactly(length - 1)


async def fresh_read(target: Target, timeout: float = 2.0, source: str | None = None) -> bool:
    """A new client connects and reads one register: answered (values) within ``timeout``."""
    try:
        async with asyncio.timeout(timeout):
            reader, writer = await connect(target, source)
            try:
                writer.write(mbap(READ, tid=7))
                tid, pdu = await read_frame(reader)
                return tid == 7 and pdu[:2] == b"\x03\x02"
            finally:
                writer.close()
    except (TimeoutError, OSError, asyncio.IncompleteReadError):
        return False


async def fresh_reads(target: Target, tries: int = 10, source: str | None = None) -> int:
    served = 0
    for _ in range(tries):
        served += await fresh_read(target, source=source)
        await asyncio.sleep(0.05)
    return served


async def is_closed(reader: asyncio.StreamReader, wait: float = 0.02) -> bool:
    """The server closed this connection (EOF or reset), as far as can be seen now."""
    if reader.at_eof():
        return True
    try:
        data = await asyncio.wait_for(reader.read(4096), wait)
    except TimeoutError:
        return False
    except OSError:
        return True
    return data == b""


async def wait_closed(reader: asyncio.StreamReader, limit: float) -> float | None:
    """Seconds until the server closes the connection, None if still open after ``limit``."""
    started = time.monotonic()
    try:
        async with asyncio.timeout(limit):
            while await reader.read(4096):
                pass
    except TimeoutError:
        return None
    except OSError:
        pass
    return time.monotonic() - started


async def open_silent(target: Target, n: int, source: str | None = None) -> list[Any]:
    conns = []
    for _ in range(n):
        try:
            conns.append(await connect(target, source))
        except OSError:
            break
    return conns


async def count_open(conns: list[Any]) -> int:
    closed = await asyncio.gather(*(is_closed(r) for r, _ in conns))
    return sum(1 for c in closed if not c)


def close_all(conns: list[Any]) -> None:
    for _, writer in conns:
        writer.close()


def rss_kib(pid: int | None) -> int | None:
    if pid is None:
        return None
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


# -- the cases ------------------------------------------------------------------------------
async def case_flood(target: Target, flood: int) -> Outcome:
    """From 50 addresses (127.0.0.10-59), so the cap in all is what holds them."""
    cap = target.limits().get("max_clients")
    conns = []
    for i in range(flood):
        conns += await open_silent(target, 1, source=f"127.0.0.{10 + i % 50}")
    await asyncio.sleep(0.3)
    served = await fresh_reads(target)
    held = await count_open(conns)
    close_all(conns)
    ok = served >= 9 and (cap is None or held <= cap)
    where = f" (max_clients {cap})" if cap else ""
    return Outcome(
        "d3-flood",
        f"{flood} silent connections from 50 addresses: fresh clients served {served}/10; the server holds "
        f"{held} of them{where}",
        ok,
        {"served": served, "held": held},
    )


async def case_slowloris(target: Target, n: int = 12) -> Outcome:
    limit = float(target.limits().get("request_timeout_s") or 5.0)
    conns = await open_silent(target, n)
    frame = mbap(READ)

    async def trickle(writer: Any) -> None:
        try:
            for byte in frame[:-1]:
                writer.write(bytes([byte]))
                await writer.drain()
                await asyncio.sleep(0.2)
        except OSError:
            pass

    tricklers = [asyncio.create_task(trickle(w)) for _, w in conns]
    closed_after = await asyncio.gather(*(wait_closed(r, limit + 3.0) for r, _ in conns))
    served = await fresh_reads(target, 5)
    for task in tricklers:
        task.cancel()
    close_all(conns)
    times = sorted(t for t in closed_after if t is not None)
    ok = served >= 5 and len(times) == len(conns)
    span = f"{times[0]:.1f}-{times[-1]:.1f} s" if times else "never"
    return Outcome(
        "d3-slowloris",
        f"{n} connections trickling a header: {len(times)} closed after {span} "
        f"(request_timeout_s {limit:g}), still open after {limit + 3:g} s: {n - len(times)}; "
        f"fresh clients served {served}/5",
        ok,
        {"closed": len(times), "served": served},
    )


async def case_idle(target: Target) -> Outcome:
    limit = float(target.limits().get("idle_timeout_s") or 60.0)
    reader, writer = await connect(target)
    writer.write(mbap(READ))
    await read_frame(reader)
    after = await wait_closed(reader, limit + 2.0)
    writer.close()
    text = f"closed {after:.1f} s after its last answer" if after is not None else "still open"
    return Outcome(
        "d3-idle",
        f"a client silent after one read: {text} (idle_timeout_s {limit:g})",
        after is not None and after <= limit + LATE_S,
        {"closed_after_s": after},
    )


async def case_per_peer(target: Target) -> Outcome:
    cap = target.limits().get("max_clients_per_peer")
    n = 2 * int(cap or 16)
    conns = await open_silent(target, n)
    await asyncio.sleep(0.3)
    held = await count_open(conns)
    other = await fresh_reads(target, 5, source="127.0.0.2")
    close_all(conns)
    ok = other >= 5 and (cap is None or held <= cap)
    return Outcome(
        "per-peer",
        f"{n} silent connections from 127.0.0.1: {held} held (max_clients_per_peer {cap}); "
        f"a client from 127.0.0.2 served {other}/5",
        ok,
        {"held": held, "served": other},
    )


MALFORMED = {
    "d5-length-0": struct.pack(">HHHB", 1, 0, 0, 1),
    "d5-length-1": struct.pack(">HHHB", 1, 0, 1, 1),
    "d5-length-255": struct.pack(">HHHB", 1, 0, 255, 1) + bytes(20),
    "d5-length-65535": struct.pack(">HHHB", 1, 0, 65535, 1) + bytes(20),
    "d5-protocol-1": struct.pack(">HHHB", 1, 1, 6, 1) + READ,
    "d5-garbage": random.Random(5).randbytes(64),
}


async def case_malformed(target: Target, name: str, data: bytes) -> Outcome:
    reader, writer = await connect(target)
    started = time.monotonic()
    writer.write(data)
    got = b""
    try:
        async with asyncio.timeout(1.0):
            got = await reader.read(4096)
        closed = got == b""
    except TimeoutError:
        closed = False
    except OSError:
        closed = True
    took = (time.monotonic() - started) * 1000
    writer.close()
    fresh = await fresh_read(target)
    if got:
        text = f"answered {got.hex()}"
    elif closed:
        text = f"closed in {took:.0f} ms, no answer"
    else:
        text = "neither answered nor closed within 1 s"
    return Outcome(name, f"{text}; a fresh client served: {fresh}", closed and fresh)


async def case_short_frame(target: Target) -> Outcome:
    limit = float(target.limits().get("request_timeout_s") or 5.0)
    reader, writer = await connect(target)
    writer.write(struct.pack(">HHHB", 1, 0, 20, 1) + bytes(5))
    after = await wait_closed(reader, limit + 2.0)
    writer.close()
    text = f"closed after {after:.1f} s" if after is not None else f"open after {limit + 2:g} s"
    return Outcome(
        "d5-length-20-short",
        f"length 20, 5 bytes sent: {text} (request_timeout_s {limit:g})",
        after is not None and after <= limit + LATE_S,
    )


async def case_desync(target: Target) -> Outcome:
    reader, writer = await connect(target)
    writer.write(struct.pack(">HHHB", 1, 0, 0, 1) + mbap(READ, tid=2))
    try:
        async with asyncio.timeout(1.0):
            got = await reader.read(4096)
    except TimeoutError:
        got = None
    except OSError:
        got = b""
    writer.close()
    if got is None:
        text, ok = "no answer, connection left open", False
    elif got == b"":
        text, ok = "closed, the request after it not answered", True
    else:
        tid = struct.unpack(">H", got[:2])[0] if len(got) >= 2 else None
        text, ok = f"answered {got.hex()} (transaction id {tid}; the request sent was 2)", False
    return Outcome("d5-desync", f"length-0 header, then a valid FC3: {text}", ok)


async def case_function_codes(target: Target) -> Outcome:
    codes = [fc for fc in range(256) if fc not in SERVED]
    wrong: dict[int, str] = {}
    conn: tuple[Any, Any] | None = None
    for fc in codes:
        if conn is None:
            conn = await connect(target)
        reader, writer = conn
        writer.write(mbap(bytes([fc]) + BODIES.get(fc, bytes(4)), tid=fc))
        try:
            async with asyncio.timeout(1.0):
                tid, pdu = await read_frame(reader)
            if tid != fc or pdu != bytes([fc | 0x80, 0x01]):
                wrong[fc] = pdu.hex() if tid == fc else f"tid {tid}: {pdu.hex()}"
        except (TimeoutError, OSError, asyncio.IncompleteReadError) as exc:
            wrong[fc] = "closed" if not isinstance(exc, TimeoutError) else "no answer"
            writer.close()
            conn = None
    if conn is not None:
        conn[1].close()
    right = len(codes) - len(wrong)
    shown = ", ".join(f"FC {fc}: {what}" for fc, what in list(wrong.items())[:6])
    return Outcome(
        "d6",
        f"{right}/{len(codes)} function codes outside the served set answered exception 01"
        + (f"; others: {shown}{' ...' if len(wrong) > 6 else ''}" if wrong else ""),
        not wrong,
        {"wrong": {str(k): v for k, v in wrong.items()}},
    )


async def case_pipeline(target: Target, n: int = 100) -> Outcome:
    """FC6 writes to holding register 1 (rs485/m4/ao1 in the example) and FC3 reads of it,
    pipelined: each read must see the write before it."""
    before = target.counters().get("pipeline_full", 0)
    reader, writer = await connect(target)
    requests = []
    for i in range(1, n + 1):
        pdu = struct.pack(">BHH", 6, 1, 1000 + i) if i % 2 else struct.pack(">BHH", 3, 1, 1)
        requests.append(mbap(pdu, tid=i))
    writer.write(b"".join(requests))
    answers: list[tuple[int, bytes]] = []
    try:
        async with asyncio.timeout(5.0):
            for _ in range(n):
                answers.append(await read_frame(reader))
    except (TimeoutError, OSError, asyncio.IncompleteReadError):
        pass
    writer.close()
    paused = (await target.counters_after()).get("pipeline_full", 0) - before
    cap = target.limits().get("max_pending_requests")
    in_order = [tid for tid, _ in answers] == list(range(1, n + 1))
    consistent = all(
        pdu == struct.pack(">BBH", 3, 2, 1000 + tid - 1) for tid, pdu in answers if tid % 2 == 0
    )
    return Outcome(
        "pipeline",
        f"{n} requests (FC6 write, FC3 read of it, ...) in one segment: {len(answers)} "
        f"answered, in order: {in_order}, each read saw the write before it: "
        f"{consistent and len(answers) == n}; reading paused {paused} times "
        f"(max_pending_requests {cap})",
        in_order and consistent and len(answers) == n,
        {"answered": len(answers), "paused": paused},
    )


async def case_no_reader(target: Target, n: int = 20_000) -> Outcome:
    limit = float(target.limits().get("idle_timeout_s") or 60.0)
    rss_before = rss_kib(target.pid)
    loop = asyncio.get_running_loop()
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # and never read from it
    sock.setblocking(False)
    await loop.sock_connect(sock, (target.host, target.port))
    started = time.monotonic()
    sending = asyncio.create_task(
        loop.sock_sendall(sock, b"".join(mbap(READ, tid=i & 0xFFFF) for i in range(n)))
    )
    await asyncio.sleep(1.0)
    rss_after = rss_kib(target.pid)
    served = await fresh_reads(target, 5)
    closed = None
    while time.monotonic() - started < limit + 3.0:
        if _peer_gone(sock):
            closed = time.monotonic() - started
            break
        await asyncio.sleep(0.1)
    sending.cancel()
    await asyncio.gather(sending, return_exceptions=True)
    sock.close()
    grew = (
        f"gateway RSS {rss_before / 1024:.1f} -> {rss_after / 1024:.1f} MB; "
        if rss_before and rss_after
        else ""
    )
    text = f"closed {closed:.1f} s after it began" if closed is not None else "still open"
    return Outcome(
        "no-reader",
        f"{n} requests ({n * 12 // 1024} KiB) never read: {grew}fresh clients served "
        f"{served}/5; the non-reader {text} (idle_timeout_s {limit:g})",
        served >= 5 and closed is not None,
        {"rss_kib": (rss_before, rss_after), "closed_after_s": closed},
    )


def _peer_gone(sock: socket.socket) -> bool:
    """The server reset or closed this socket (it is never read, so only TCP_INFO shows it)."""
    try:
        info = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 1)
    except OSError:
        return True
    return info[0] in (7, 8)  # TCP_CLOSE (reset), TCP_CLOSE_WAIT (the server's FIN)


def cases_of(target: Target, flood: int) -> dict[str, Callable[[], Awaitable[Outcome]]]:
    """Each case, by name, ready to run against ``target``."""
    return {
        "d3-flood": lambda: case_flood(target, flood),
        "d3-slowloris": lambda: case_slowloris(target),
        "d3-idle": lambda: case_idle(target),
        "per-peer": lambda: case_per_peer(target),
        **{
            name: (lambda n=name, d=data: case_malformed(target, n, d))
            for name, data in MALFORMED.items()
        },
        "d5-length-20-short": lambda: case_short_frame(target),
        "d5-desync": lambda: case_desync(target),
        "d6": lambda: case_function_codes(target),
        "pipeline": lambda: case_pipeline(target),
        "no-reader": lambda: case_no_reader(target),
    }


async def campaign(target: Target, cases: list[str], flood: int) -> list[Outcome]:
    table = cases_of(target, flood)
    unknown = [c for c in cases if c not in table]
    if unknown:
        raise SystemExit(f"unknown case(s) {', '.join(unknown)}; known: {', '.join(table)}")
    out = []
    for name in cases or list(table):
        outcome = await table[name]()
        print(outcome.line(), flush=True)
        out.append(outcome)
        await asyncio.sleep(0.3)  # the closes of one case are done before the next
    return out


CASES = [
    "d3-flood",
    "d3-slowloris",
    "d3-idle",
    "per-peer",
    *MALFORMED,
    "d5-length-20-short",
    "d5-desync",
    "d6",
    "pipeline",
    "no-reader",
]


# -- a gateway of its own --------------------------------------------------------------------


def start_gateway(
    state: str, idle_timeout: float, request_timeout: float
) -> tuple[subprocess.Popen[str], int, int]:
    """``fieldgate run examples/plant-northbound.yaml --simulate`` on free loopback ports:
    (the process, the Modbus TCP port, the status API's port)."""
    mb, http = free_port(), free_port()
    sets = {
        "gateway.state_dir": state,
        "fronts.modbus.listen": f"127.0.0.1:{mb}",
        "fronts.opcua.listen": f"127.0.0.1:{free_port()}",
        "fronts.can.channel": f"mbtcp-attacks-{os.getpid()}",
        "fronts.plant.brokers.0.port": str(free_port()),  # no broker: Sparkplug keeps trying
        "fronts.modbus.idle_timeout_s": str(idle_timeout),
        "fronts.modbus.request_timeout_s": str(request_timeout),
    }
    command = [
        sys.executable,
        "-m",
        "fieldgate",
        "run",
        str(ROOT / "examples" / "plant-northbound.yaml"),
        "--simulate",
        "--http",
        f"127.0.0.1:{http}",
        "--log-level",
        "warning",
    ]
    for key, value in sets.items():
        command += ["--set", f"{key}={value}"]
    proc = subprocess.Popen(command, cwd=state, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"the gateway exited with {proc.returncode}")
        if status_of(http):
            return proc, mb, http
        time.sleep(0.2)
    proc.kill()
    raise SystemExit("the gateway did not start within 60 s")


def status_of(http: int | None) -> dict[str, Any]:
    """The Modbus TCP front's part of the gateway's /api/v1/status ({} if unreachable)."""
    if http is None:
        return {}
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{http}/api/v1/status", timeout=2) as r:
            data = json.loads(r.read())
    except (OSError, ValueError):
        return {}
    fronts = data.get("fronts", {})
    return next((f for f in fronts.values() if str(f.get("endpoint", "")).startswith("modbus")), {})


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="", help=f"comma-separated, of: {', '.join(CASES)}")
    parser.add_argument("--flood", type=int, default=500)
    parser.add_argument("--port", type=int, help="attack a gateway already running here")
    parser.add_argument("--http-port", type=int, help="its status API (limits and counters)")
    parser.add_argument("--pid", type=int, help="its process id (RSS)")
    parser.add_argument("--idle-timeout", type=float, default=3.0)
    parser.add_argument("--request-timeout", type=float, default=1.0)
    args = parser.parse_args()
    cases = [c for c in args.case.split(",") if c] or CASES
    with tempfile.TemporaryDirectory(prefix="mbtcp-attacks-") as state:
        proc = None
        if args.port is None:
            proc, port, http = start_gateway(state, args.idle_timeout, args.request_timeout)
            pid: int | None = proc.pid
        else:
            port, http, pid = args.port, args.http_port, args.pid
        target = Target(port, lambda: status_of(http), pid)
        print(f"Modbus TCP front at 127.0.0.1:{port}; limits {target.limits() or 'unknown'}")
        try:
            outcomes = asyncio.run(campaign(target, cases, args.flood))
            counters = asyncio.run(target.counters_after())
        finally:
            if proc is not None:
                proc.terminate()
                proc.wait(timeout=30)
    if counters:
        print(f"front counters: {counters}")
    failed = [o.case for o in outcomes if not o.ok]
    print("verdict:", "PASS" if not failed else f"FAIL ({', '.join(failed)})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
