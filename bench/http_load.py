"""HTTP observers never slow the gateway: SDO round trip and poll cycle with and without them.

Run:  .venv/bin/python bench/http_load.py [--phase-s S] [--rounds R] [--loop auto|uvloop|asyncio]
      (about 2 x R x S seconds; default 4 rounds of 6 s: under a minute)

One gateway (examples/i7232d-style.yaml: the CANopen front on python-can's in-process
``virtual`` bus, Modbus modules simulated on pseudo-terminals, animated so that points
change all the time, the line polled as fast as it goes: ``poll_ms: 0``) runs on its own
event loop in a thread, as ``fieldgate run`` would, with its HTTP server on 127.0.0.1.

Phases alternate, ``quiet`` then ``observed``, R times each, in the same run:

* observed: a separate process (its own interpreter and loop, like a real Prometheus and
  browsers) scrapes ``/metrics`` 10 times a second and keeps two ``/api/v1/events`` streams
  open, reading every point batch; quiet: that process is not running.
* meanwhile this thread measures SDO expedited uploads, one in flight (as SDO allows),
  alternating 0x6401:1 (an analog input: answered on the event loop, the path that shares
  the loop with HTTP) and 0x1000:0 (answered on the CAN receive thread), and records every
  completed poll cycle of the Modbus line (``LineStats.last_cycle_time``).

Printed: per condition p50/p99 of both, the ratio observed/quiet of the p99s (target:
at most 1.05, i.e. <= 5 % change), and what the observers got (scrapes, SSE batches), so
that a run where they got nothing cannot pass silently.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout too

import can  # noqa: E402

from fieldgate.cli import loop_factory, loop_name  # noqa: E402
from fieldgate.runtime import Gateway  # noqa: E402

NODE_ID = 2  # examples/i7232d-style.yaml's node-ID
SCRAPES_PER_S = 10
SSE_CLIENTS = 2
TARGET = 1.05
OBJECTS = {"0x6401:1 (event loop)": (0x6401, 1), "0x1000:0 (receive thread)": (0x1000, 0)}


# -- the observers (a separate process) --------------------------------------------------
def observers(url: str) -> None:
    """10 scrapes/s of /metrics and two SSE clients, until stdin closes; prints counts."""

    async def scrape(counts: dict) -> None:
        host, port = url.split("//")[1].rstrip("/").split(":")
        period, next_at = 1 / SCRAPES_PER_S, time.monotonic()
        while True:
            reader, writer = await asyncio.open_connection(host, int(port))
            writer.write(b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
            data = await reader.read()
            writer.close()
            if data.startswith(b"HTTP/1.1 200") and b"fieldgate_module_up" in data:
                counts["scrapes"] += 1
            next_at += period
            await asyncio.sleep(max(0.0, next_at - time.monotonic()))

    async def stream(counts: dict) -> None:
        host, port = url.split("//")[1].rstrip("/").split(":")
        reader, writer = await asyncio.open_connection(host, int(port))
        writer.write(b"GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        while True:
            block = await reader.readuntil(b"\n\n")
            if b"event: points" in block:  # the stream is chunked (HTTP/1.1): size lines between
                counts["sse_batches"] += 1

    async def main() -> None:
        counts = {"scrapes": 0, "sse_batches": 0}
        tasks = [asyncio.create_task(scrape(counts))]
        tasks += [asyncio.create_task(stream(counts)) for _ in range(SSE_CLIENTS)]
        print("ready", flush=True)
        await asyncio.to_thread(sys.stdin.read)  # until the parent closes our stdin
        for t in tasks:
            t.cancel()
        print(json.dumps(counts), flush=True)

    asyncio.run(main())


# -- the gateway (a thread with its own loop) --------------------------------------------
class GatewayThread:
    def __init__(self, loop_choice: str, state_dir: str):
        self.channel = f"fieldgate-http-bench-{uuid.uuid4().hex[:8]}"
        self.gateway = Gateway.load(
            ROOT / "examples" / "i7232d-style.yaml",
            overrides={
                "gateway.state_dir": state_dir,
                "gateway.http.listen": "127.0.0.1:0",
                "fronts.can.channel": self.channel,
                "backs.rs485.poll_ms": 0,
            },
            simulate=True,
            animate=True,
        )
        self.loop = loop_factory(loop_choice)()
        self.cycles: list[float] = []
        self.recording = False
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)

    def start(self) -> None:
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self.gateway.start(), self.loop).result(30)
        back = self.gateway.component("rs485")
        stats = back.scheduler.stats
        count = back.scheduler._count_cycle  # bench instrumentation: every completed cycle

        def counting(st) -> None:
            before = stats.cycles
            count(st)
            if self.recording and stats.cycles != before:
                self.cycles.append(stats.last_cycle_time)

        back.scheduler._count_cycle = counting

    @property
    def url(self) -> str:
        return self.gateway.http.url

    def stop(self) -> None:
        asyncio.run_coroutine_threadsafe(self.gateway.stop(), self.loop).result(30)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(10)


# -- the measurement ----------------------------------------------------------------------
def sdo_round_trips(
    bus: can.BusABC, seconds: float, node_id: int = NODE_ID
) -> dict[str, list[float]]:
    times: dict[str, list[float]] = {name: [] for name in OBJECTS}
    end = time.monotonic() + seconds
    requests = [
        (name, bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]))
        for name, (index, sub) in OBJECTS.items()
    ]
    i = 0
    while time.monotonic() < end:
        name, data = requests[i % 2]
        i += 1
        started = time.perf_counter()
        bus.send(can.Message(arbitration_id=0x600 + node_id, data=data, is_extended_id=False))
        while True:
            msg = bus.recv(1.0)
            if msg is None:
                raise SystemExit(f"no SDO answer to {name}")
            if msg.arbitration_id == 0x580 + node_id:
                break
        times[name].append(time.perf_counter() - started)
        if msg.data[0] != 0x43 and msg.data[0] != 0x4B and msg.data[0] != 0x4F:
            raise SystemExit(f"SDO {name} answered {bytes(msg.data).hex()}")
        time.sleep(0.001)  # a master's pace, not a flood
    return times


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def run(phase_s: float, rounds: int, loop_choice: str) -> int:
    with tempfile.TemporaryDirectory() as state_dir:
        gw = GatewayThread(loop_choice, state_dir)
        gw.start()
        bus = can.Bus(interface="virtual", channel=gw.channel, receive_own_messages=False)
        results: dict[str, dict[str, list[float]]] = {
            c: {**{n: [] for n in OBJECTS}, "cycle": []} for c in ("quiet", "observed")
        }
        per_round: dict[str, dict[str, list[float]]] = {
            c: {**{n: [] for n in OBJECTS}, "cycle": []} for c in ("quiet", "observed")
        }
        observed_counts = {"scrapes": 0, "sse_batches": 0}
        try:
            print(
                f"fieldgate HTTP load bench: event loop {loop_name(gw.loop)}, {rounds} rounds of "
                f"{phase_s:.0f} s per condition, observers: {SCRAPES_PER_S} scrapes/s of /metrics "
                f"+ {SSE_CLIENTS} event streams (another process)",
                flush=True,
            )
            sdo_round_trips(bus, 1.0)  # warm-up
            for r in range(rounds):
                for condition in ("quiet", "observed"):
                    proc = None
                    if condition == "observed":
                        proc = subprocess.Popen(
                            [sys.executable, __file__, "--observers", gw.url],
                            stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE,
                            text=True,
                        )
                        assert proc.stdout is not None and proc.stdin is not None
                        if proc.stdout.readline().strip() != "ready":
                            raise SystemExit("the observer process did not start")
                        time.sleep(0.5)  # its connections are open and scraping
                    gw.cycles.clear()
                    gw.recording = True
                    times = sdo_round_trips(bus, phase_s)
                    gw.recording = False
                    for name, values in times.items():
                        results[condition][name] += values
                        per_round[condition][name].append(pct(values, 0.99))
                    results[condition]["cycle"] += gw.cycles
                    per_round[condition]["cycle"].append(pct(gw.cycles, 0.99))
                    if proc is not None:
                        out, _ = proc.communicate("", timeout=30)
                        for key, value in json.loads(out.strip().splitlines()[-1]).items():
                            observed_counts[key] += value
                print(f"  round {r + 1}/{rounds} done", flush=True)
            status = json.loads(urllib.request.urlopen(gw.url + "api/v1/status", timeout=5).read())
        finally:
            bus.shutdown()
            gw.stop()
    return report(results, per_round, observed_counts, phase_s * rounds, status)


def report(results: dict, per_round: dict, counts: dict, seconds: float, status: dict) -> int:
    print()
    print(
        f"{'measure':34} {'quiet p50':>10} {'p99':>9} {'observed p50':>13} {'p99':>9}"
        f" {'p50 ratio':>10} {'p99 ratio':>10}"
    )
    worst = 0.0
    for name in [*OBJECTS, "cycle"]:
        quiet, observed = results["quiet"][name], results["observed"][name]
        label = f"SDO {name}" if name != "cycle" else "poll cycle (4 modules, poll_ms 0)"
        q50, q99, o50, o99 = (
            pct(quiet, 0.5),
            pct(quiet, 0.99),
            pct(observed, 0.5),
            pct(observed, 0.99),
        )
        ratio = o99 / q99
        worst = max(worst, ratio)
        print(
            f"{label:34} {q50 * 1e3:8.3f}ms {q99 * 1e3:7.3f}ms {o50 * 1e3:11.3f}ms {o99 * 1e3:7.3f}ms"
            f" {o50 / q50:10.3f} {ratio:10.3f}   (n={len(quiet)}/{len(observed)})"
        )
    print()
    print("p99 of each round (ms), quiet | observed: the machine's own noise between rounds")
    for name in [*OBJECTS, "cycle"]:
        q = " ".join(f"{v * 1e3:.2f}" for v in per_round["quiet"][name])
        o = " ".join(f"{v * 1e3:.2f}" for v in per_round["observed"][name])
        print(f"  {name:32} {q} | {o}")
    http = status.get("children", {}).get("http", {})
    print()
    print(
        f"the status server runs in a child process of its own (pid {http.get('pid')}, "
        f"{http.get('cpu_s')} s of CPU, {http.get('rss_mb')} MB): the observers take nothing "
        "from the fieldbus loop but the feed of image changes (docs/architecture.md)"
    )
    scrapes_per_s = counts["scrapes"] / seconds
    print()
    print(
        f"observers got {counts['scrapes']} scrapes ({scrapes_per_s:.1f}/s) and {counts['sse_batches']} "
        f"event-stream batches; gateway answered {status['http']['responses']}, "
        f"events dropped {status['http']['events_dropped']}"
    )
    if counts["scrapes"] < 0.8 * SCRAPES_PER_S * seconds or counts["sse_batches"] == 0:
        print("verdict: INVALID (the observers did not get their load through)")
        return 2
    verdict = "PASS" if worst <= TARGET else "ABOVE TARGET"
    print(f"verdict: {verdict}: worst p99 ratio observed/quiet {worst:.3f} (target <= {TARGET})")
    return 0 if worst <= TARGET else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--phase-s", type=float, default=6.0, help="seconds per phase (default 6)")
    parser.add_argument("--rounds", type=int, default=4, help="quiet/observed rounds (default 4)")
    parser.add_argument("--loop", choices=("auto", "uvloop", "asyncio"), default="auto")
    parser.add_argument("--observers", metavar="URL", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.observers:
        observers(args.observers)
        return 0
    return run(args.phase_s, args.rounds, args.loop)


if __name__ == "__main__":
    sys.exit(main())
