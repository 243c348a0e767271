#!/usr/bin/env python3
"""Every hostile north-facing client of issue 29 at once, against a real `fieldgate run`.

Run:  .venv/bin/python scripts/faults/north_campaign.py [--duration 60] [--topology FILE]
      (the issue's figure: one minute; CI runs a short version, tests/faults/test_north_campaign.py)

Runs examples/plant-northbound.yaml with simulated modules in this process, as ``fieldgate
run`` would (its loop in a thread; its north-facing parts in their child processes; its
listeners on free loopback ports; every log line, the children's too, to a file), lets it
settle, then runs together, for ``--duration`` seconds, in an attacker process:

* D1: 4 OPC UA sessions, each a subscription at publishing interval 0 with 10,000 monitored
  items at sampling 0, whose clients then stop sending Publish requests (the subscriptions
  expire while connected)
* D2: 4 connections sending a Hello and an OPC UA chunk announcing 0x7FFFFFFF bytes, in 1 MB
  blocks, reconnecting when closed (and the same without a Hello)
* D3/D4: 500 idle connections to each of the OPC UA, Modbus TCP and HTTP ports, 16 Modbus TCP
  slowloris connections (a request's first bytes, then nothing), 32 OPC UA sessions asking
  for a 600,000 ms session timeout
* D5/D6: malformed MBAP headers (length 0, 1, 20 with fewer bytes, 65535, protocol id 1,
  garbage) and function codes outside FC1-6/15/16 (8, 17, 24, 43), over and over
* D7/D8: Hellos with buffer sizes 0 and 1, and with an endpoint-URL length of 0x7FFFFFFF

Meanwhile this process checks what the plant must see (the issue's "done when"):

The attackers connect from 10 other loopback addresses (127.0.0.2-11: machines elsewhere on the
plant network), the plant's fresh clients from 127.0.0.1.

* the RS-485 points never older than 2 poll periods (every input's age in the fieldbus
  process's image, sampled every 50 ms; what the status page shows is printed beside it);
* a fresh Modbus TCP client (FC3) and a fresh OPC UA client (connect, read one value) each
  served in at least 9 of 10 tries, spread over the run;
* the gateway's log grows by less than 20 MB;
* the fieldbus process's resident memory does not grow (its RSS at the end against after
  the warm-up, with 5 % for the allocator).

Prints one line per check and a verdict (exit 0 when every check holds).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))
sys.path.append(str(ROOT / "tests"))
from netkit import free_port  # noqa: E402  (tests/netkit.py: one helper for tests, benches and scripts)

POLL_MS = 100  # examples/plant-northbound.yaml's poll period
TRIES = 10


# == the attacker process =====================================================================
async def modbus_garbage(host: str, port: int, counts: dict[str, int]) -> None:
    """D5 and D6 over and over: each malformed header or odd function code on a connection."""
    frames = [
        struct.pack(">HHHB", 1, 0, 0, 1),  # length 0
        struct.pack(">HHHB", 2, 0, 1, 1),  # length 1: a unit id and no function code
        struct.pack(">HHHB", 3, 0, 20, 1) + b"\x03\x00",  # 20 announced, 2 sent
        struct.pack(">HHHB", 4, 0, 65535, 1) + b"\x03" * 64,
        struct.pack(">HHHB", 5, 1, 6, 1) + b"\x03\x00\x00\x00\x01",  # protocol id 1
        b"\xde\xad\xbe\xef" * 16,
    ] + [struct.pack(">HHHBB", 10 + fc, 0, 2, 1, fc) for fc in (8, 17, 24, 43)]
    await each_on_a_connection(host, port, frames, 2.0, 0.05, counts, "modbus_garbage")


async def each_on_a_connection(
    host: str,
    port: int,
    messages: list[bytes],
    answer_s: float,
    pause_s: float,
    counts: dict[str, int],
    key: str,
) -> None:
    """Over and over: each message on a new connection, up to ``answer_s`` for the server's
    answer (or its close), then the next; ``pause_s`` after each round. Counted as ``key`` or
    ``key_failed``."""
    while True:
        for message in messages:
            try:
                reader, writer = await asyncio.open_connection(host, port)
                writer.write(message)
                await writer.drain()
                await asyncio.wait_for(reader.read(300), answer_s)
                writer.close()
                counts[key] += 1
            except (OSError, TimeoutError, ConnectionError):
                counts[f"{key}_failed"] += 1
        await asyncio.sleep(pause_s)


async def modbus_slowloris(host: str, port: int, counts: dict[str, int]) -> None:
    while True:
        try:
            reader, writer = await asyncio.open_connection(host, port)
            writer.write(b"\x00\x01\x00")  # the first bytes of a header, then nothing
            await writer.drain()
            counts["slowloris"] += 1
            await reader.read()
            writer.close()
        except (OSError, ConnectionError):
            await asyncio.sleep(0.2)


async def bad_hellos(host: str, port: int, counts: dict[str, int]) -> None:
    """D7 and D8: buffer sizes 0 and 1; an endpoint URL announcing 0x7FFFFFFF bytes."""
    from isolation import ua_hello

    bodies = [ua_hello(f"opc.tcp://{host}:{port}/", size) for size in (0, 1)]
    url = struct.pack("<IIIII", 0, 65535, 65535, 0, 0) + struct.pack("<i", 0x7FFFFFFF) + b"x" * 64
    bodies.append(b"HELF" + struct.pack("<I", 8 + len(url)) + url)
    await each_on_a_connection(host, port, bodies, 3.0, 0.1, counts, "bad_hellos")


async def long_sessions(url: str, count: int, counts: dict[str, int]) -> None:
    from asyncua import Client

    clients = []
    for _ in range(count):
        client = Client(url, timeout=10)
        client.session_timeout = 600_000
        try:
            await client.connect()
            clients.append(client)
            counts["long_sessions"] += 1
        except Exception:
            counts["long_sessions_refused"] += 1
    await asyncio.Event().wait()


def probe(ports: dict[str, int], duration: float) -> None:
    """The plant's fresh clients, in a process of their own (not the fieldbus process's
    memory): TRIES Modbus TCP and OPC UA clients spread over ``duration``, and what the
    status page shows every 2 s; prints the counts (JSON)."""
    result = {"modbus_ok": 0, "opcua_ok": 0, "http_oldest": 0.0, "http_failed": 0}

    async def main() -> None:
        started = asyncio.get_running_loop().time()
        for i in range(TRIES):
            await asyncio.sleep(
                max(
                    0.0,
                    started + duration * (i + 1) / (TRIES + 1) - asyncio.get_running_loop().time(),
                )
            )
            result["modbus_ok"] += await fresh_modbus(ports["modbus"])
            result["opcua_ok"] += await fresh_opcua(ports["opcua"])

    async def page() -> None:
        while True:
            try:
                points = (await asyncio.to_thread(status, ports["http"]))["points"]
                ages = [p["age_s"] for p in points if p["age_s"] is not None]
                result["http_oldest"] = max([result["http_oldest"], *ages])
            except Exception:
                result["http_failed"] += 1
            await asyncio.sleep(2.0)

    async def both() -> None:
        watcher = asyncio.ensure_future(page())
        await main()
        watcher.cancel()

    asyncio.run(both())
    print(json.dumps(result), flush=True)


def attack(ports: dict[str, int]) -> None:
    import resource

    from isolation import chunk_flood, from_other_addresses, hold_idle, monitored

    resource.setrlimit(resource.RLIMIT_NOFILE, (resource.getrlimit(resource.RLIMIT_NOFILE)[1],) * 2)
    counts: dict[str, int] = {}

    class Counts(dict):  # type: ignore[type-arg]
        def __missing__(self, key: str) -> int:
            return 0

    counts = Counts()
    host = "127.0.0.1"
    ua = f"opc.tcp://{host}:{ports['opcua']}/"

    async def main() -> None:
        from_other_addresses(asyncio.get_running_loop())  # elsewhere on the plant network
        jobs = [monitored(ua, 10_000, True, counts) for _ in range(4)]
        if os.environ.get("FIELDGATE_CAMPAIGN_QUIET"):  # the baseline: every check, no attack
            jobs = []
        jobs += [chunk_flood(host, ports["opcua"], counts) for _ in range(4)]
        jobs += [hold_idle(host, ports[p], 500, counts) for p in ("opcua", "modbus", "http")]
        jobs += [modbus_slowloris(host, ports["modbus"], counts) for _ in range(16)]
        jobs += [long_sessions(ua, 32, counts), modbus_garbage(host, ports["modbus"], counts)]
        jobs.append(bad_hellos(host, ports["opcua"], counts))
        tasks = [asyncio.ensure_future(_quiet(job)) for job in jobs]
        print("ready", flush=True)
        await asyncio.to_thread(sys.stdin.read)
        for t in tasks:
            t.cancel()

    asyncio.run(main())
    print(json.dumps(counts), flush=True)


async def _quiet(job: Any) -> None:
    try:
        await job
    except asyncio.CancelledError:
        raise
    except Exception as exc:
        print(f"attack job ended: {type(exc).__name__}: {exc}", file=sys.stderr)


# == the checks ================================================================================
def status(http: int) -> dict[str, Any]:
    with urllib.request.urlopen(f"http://127.0.0.1:{http}/api/v1/points?kind=di", timeout=3) as r:
        di = json.loads(r.read())["points"]
    with urllib.request.urlopen(f"http://127.0.0.1:{http}/api/v1/points?kind=ai", timeout=3) as r:
        ai = json.loads(r.read())["points"]
    return {"points": di + ai}


async def fresh_modbus(port: int) -> bool:
    from pymodbus.client import AsyncModbusTcpClient

    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
    try:
        if not await client.connect():
            return False
        reply = await client.read_holding_registers(0, count=4, device_id=1)
        return not reply.isError()
    except Exception:
        return False
    finally:
        client.close()


async def fresh_opcua(port: int) -> bool:
    from asyncua import Client

    client = Client(f"opc.tcp://127.0.0.1:{port}/", timeout=5)
    try:
        await asyncio.wait_for(client.connect(), 10)
        node = client.get_node("ns=2;s=rs485/m1/di0")
        await asyncio.wait_for(node.read_value(), 5)
        return True
    except Exception:
        return False
    finally:
        try:
            await asyncio.wait_for(client.disconnect(), 5)
        except Exception:
            pass


def run(args: argparse.Namespace) -> int:
    """The gateway runs in this process (a thread with its own loop, as `fieldgate run` would
    run it): this process is the fieldbus process, whose image this checker reads directly;
    every log line, the children's too, goes to a file whose growth is measured."""
    from isolation import GatewayThread

    ports = {p: free_port() for p in ("opcua", "modbus", "http", "mqtt")}
    with tempfile.TemporaryDirectory() as work:
        log_path = Path(work) / "gateway.log"
        saved = os.dup(2)
        log_fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
        os.dup2(log_fd, 2)  # this process's log and the children's (they inherit fd 2)
        os.close(log_fd)
        import logging

        logging.basicConfig(level=logging.INFO, stream=sys.stderr, force=True)
        gw = GatewayThread(
            "auto", f"{work}/state", ports, fast=False, fieldbus_nice=args.fieldbus_nice
        )
        try:
            gw.start()
            return campaign(args, gw, ports, log_path)
        finally:
            gw.stop()
            os.dup2(saved, 2)
            os.close(saved)


def input_ages(gw: Any) -> list[float]:
    """How old each RS-485 input is in the fieldbus process's image (s)."""
    now = gw.gateway.image.clock()
    return [
        now - c.timestamp
        for c in list(gw.gateway.image)
        if not c.kind.is_output and c.timestamp is not None
    ]


def campaign(args: argparse.Namespace, gw: Any, ports: dict[str, int], log_path: Path) -> int:
    time.sleep(args.warmup_s)
    from fieldgate.procstat import resident_bytes

    me = os.getpid()
    rss_before, log_before = resident_bytes(me) or 0, log_path.stat().st_size
    attacker = subprocess.Popen(
        [sys.executable, __file__, "--attack", json.dumps(ports)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    assert attacker.stdout is not None
    if attacker.stdout.readline().strip() != "ready":
        raise SystemExit("the attacker did not start")
    prober = subprocess.Popen(
        [sys.executable, __file__, "--probe", json.dumps(ports), "--duration", str(args.duration)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    oldest_each: list[float] = []  # the oldest input at each sample
    started = time.monotonic()
    while time.monotonic() - started < args.duration:
        oldest_each.append(max(input_ages(gw), default=0.0))
        time.sleep(0.05)
    oldest, samples = max(oldest_each, default=0.0), len(oldest_each)
    ordered = sorted(oldest_each)
    median = ordered[len(ordered) // 2] if ordered else 0.0
    p90 = ordered[len(ordered) * 9 // 10] if ordered else 0.0
    checked = oldest if args.age_check == "oldest" else median
    rss_after, log_after = resident_bytes(me) or 0, log_path.stat().st_size
    probed_out, _ = prober.communicate(timeout=120)
    probed = json.loads(probed_out.strip().splitlines()[-1])
    out, _ = attacker.communicate("", timeout=60)
    counts = json.loads(out.strip().splitlines()[-1])
    children = gw.children()
    limit = 2 * POLL_MS / 1000
    checks = [
        (checked <= limit and samples > 0,
         f"RS-485 points in the fieldbus process: oldest {oldest * 1000:.0f} ms over {samples} "
         f"samples (median of the oldest {median * 1000:.0f} ms, 90th percentile "
         f"{p90 * 1000:.0f} ms), limit on the {args.age_check}: 2 poll periods = "
         f"{limit * 1000:.0f} ms"),
        (probed["modbus_ok"] >= 9, f"fresh Modbus TCP client served {probed['modbus_ok']}/{TRIES}"),
        (probed["opcua_ok"] >= 9, f"fresh OPC UA client served {probed['opcua_ok']}/{TRIES}"),
        ((log_after - log_before) < 20e6,
         f"log grew {(log_after - log_before) / 1e6:.2f} MB (limit 20 MB)"),
        (rss_after <= rss_before * 1.05,
         f"fieldbus process RSS {rss_before / 2**20:.1f} -> {rss_after / 2**20:.1f} MB"),
    ]  # fmt: skip
    print(f"north campaign: {args.duration:.0f} s, every attack at once")
    print(f"  attack counts: {dict(sorted(counts.items()))}")
    print(
        f"  the status page's view: oldest point {probed['http_oldest'] * 1000:.0f} ms "
        f"({probed['http_failed']} reads failed)"
    )
    for name, c in children.items():
        print(
            f"  child {name}: rss {c.get('rss_mb')} MB (peak {c.get('peak_rss_mb')}), cpu "
            f"{c.get('cpu_s')} s, kills {c.get('kills')}, resyncs {c.get('resyncs')}"
        )
    for ok, text in checks:
        print(f"  {'ok  ' if ok else 'FAIL'} {text}")
    passed = all(ok for ok, _ in checks)
    print(f"verdict: {'PASS' if passed else 'FAIL'}")
    return 0 if passed else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--warmup-s", type=float, default=5.0)
    parser.add_argument(
        "--age-check",
        choices=("oldest", "median"),
        default="oldest",
        help="which input age must stay within 2 poll periods: the oldest seen (the issue's "
        "figure) or the median of the samples (CI on a shared host, where another job can take "
        "the CPU for longer than a poll period; a stall such as issue 29's 24.8 s moves it too)",
    )
    parser.add_argument(
        "--fieldbus-nice",
        type=int,
        default=None,
        help="niceness the fieldbus process asks for (the unit's Nice=-5; below 0 needs root)",
    )
    parser.add_argument("--attack", help=argparse.SUPPRESS)
    parser.add_argument("--probe", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.attack:
        attack(json.loads(args.attack))
        return 0
    if args.probe:
        probe(json.loads(args.probe), args.duration)
        return 0
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
