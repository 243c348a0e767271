"""A fleet of Sparkplug gateways on one host: one Mosquitto, one checking subscriber.

Run:  .venv/bin/python bench/fleet.py                       (50 gateways, 60 s: the issue's run)
      .venv/bin/python bench/fleet.py --gateways 3 --duration 10   (the CI version, a test)

Each gateway is its own process (``fieldgate.runtime.Gateway``, as ``fieldgate run
--simulate`` builds it): a Modbus RTU back polling one simulated module with --points input
registers every --poll-ms (100) over a pseudo-terminal at 115200 baud, and the Sparkplug front.
A driver in the process sets every simulated input to a new value --rate times a second
(the "module change"). The checker is the primary host application: it publishes its STATE
(the gateways publish only while it is online) and records every message with its arrival
time. In the middle of the run the broker is restarted on the same port after --outage
seconds (--restart: SIGTERM with persistence, or SIGKILL).

Reported: messages and samples per second, latency from the module change (the driver set
the input) and from the acquisition (the metric's timestamp: the poll that read it) to
arrival at the subscriber, p50/p99 of live samples outside the restart window; CPU (share of
one core) and RSS of each gateway; and per channel, against what each gateway saw in its own
process image: samples lost, duplicated, or out of order (live samples must arrive in
increasing order, historical ones too, and sorted by timestamp they are the image's order).
Decoding uses the protobuf module (``sparkplug_b_pb2``): the tests use an independent
decoder; here volume needs protobuf's C decoder.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout too; tests.sparkplug.broker starts Mosquitto

GROUP = "fleet"
HOST_ID = "checker"


# -- one gateway (child process) ------------------------------------------------------------
def gateway_topology(
    index: int, port: int, points: int, state_dir: str, poll_ms: int = 100, data_qos: int = 0
) -> dict[str, Any]:
    return {
        "gateway": {"name": f"gw{index:03d}", "state_dir": state_dir},
        "fronts": [
            {
                "name": "north",
                "type": "sparkplug",
                "group_id": GROUP,
                "primary_host_id": HOST_ID,
                "brokers": [{"host": "127.0.0.1", "port": port}],
                "reconnect_min_s": 0.2,
                "reconnect_max_s": 1.0,
                "replay_messages_per_s": 50,
                "data_qos": data_qos,
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",  # replaced by a pseudo-terminal (simulate)
                "baudrate": 115200,
                "poll_ms": poll_ms,
                # generous for a host running 50 of these: a starved process must not mark
                # its simulated module offline (that would be a test of the CPU, not of Sparkplug)
                "timeout_ms": 1000,
                "fail_threshold": 10,
                "modules": [
                    {
                        "address": 1,
                        "name": "sim",
                        "channels": [
                            {
                                "kind": "ai",
                                "table": "input_registers",
                                "address": 0,
                                "count": points,
                            }
                        ],
                    }
                ],
            }
        ],
    }


async def run_gateway(args: argparse.Namespace) -> None:
    from fieldgate.image import Quality
    from fieldgate.runtime import Gateway

    gw = Gateway.load(
        gateway_topology(
            args.index, args.port, args.points, args.state_dir, args.poll_ms, args.data_qos
        ),
        simulate=True,
    )
    seen: dict[str, list[int]] = {}  # good values each channel took in the process image
    set_times: list[float] = []
    stop = asyncio.Event()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    cpu0 = resource.getrusage(resource.RUSAGE_SELF)
    wall0 = time.monotonic()
    async with gw:
        # the sparkplug front runs in a child process of its own: its CPU and memory count too
        child0 = gw.component("north").child.process_status()
        gw.image.subscribe(
            lambda ch: (
                ch.quality is Quality.GOOD
                and ch.value_changed
                and seen.setdefault(ch.channel.id, []).append(ch.value)
            )
        )
        sim = gw.bench.simulator("rs485")
        ids = [f"rs485/m1/ai{i}" for i in range(args.points)]
        print("running", flush=True)
        period = 1.0 / args.rate
        next_at = time.monotonic()
        value = 0
        while not stop.is_set():
            value += 1
            for cid in ids:
                sim.set_input(cid, value % 32768)
            set_times.append(time.time())
            next_at += period
            try:
                await asyncio.wait_for(stop.wait(), max(0.0, next_at - time.monotonic()))
            except TimeoutError:
                pass
        front = gw.component("north")
        await asyncio.sleep(0.5)  # the last values set reach the image (next poll) and go out
        end = time.monotonic() + 30
        while time.monotonic() < end:
            status = front.status()
            if not status.get("backlog_messages") and not status.get("inflight"):
                break
            await asyncio.sleep(0.1)
        status = front.status()
        cpu1 = resource.getrusage(resource.RUSAGE_SELF)
        wall = time.monotonic() - wall0
        rss_kb = int(Path("/proc/self/status").read_text().split("VmRSS:")[1].split()[0])
        child1 = front.child.process_status()
    child_cpu = child1["cpu_s"] - child0["cpu_s"]
    report = {
        "seen": seen,
        "set_times": set_times,
        "cpu": (cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime + child_cpu) / wall,
        "rss_mb": rss_kb / 1024 + child1["rss_mb"],
        "max_rss_mb": cpu1.ru_maxrss / 1024 + child1["peak_rss_mb"],
        "dropped": status.get("dropped_messages"),
        "poll_errors": sum(sum(m.errors.values()) for m in gw.health.modules()),
        "backlog": status.get("backlog_messages"),
    }
    Path(args.report).write_text(json.dumps(report))


# -- the checker ---------------------------------------------------------------------------
class Checker:
    def __init__(self, port: int):
        import paho.mqtt.client as mqtt
        from paho.mqtt.enums import CallbackAPIVersion

        self.raw: list[tuple[str, bytes, float]] = []
        self.lock = threading.Lock()
        # a persistent session: what the broker queued for the checker survives a broker
        # restart that saves it (--restart term with persistence)
        self.client = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=HOST_ID, clean_session=False
        )
        self.client.reconnect_delay_set(0.05, 0.2)
        self.client.will_set(
            f"spBv1.0/STATE/{HOST_ID}",
            json.dumps({"online": False, "timestamp": int(time.time() * 1000)}),
            qos=1,
            retain=True,
        )
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.port = port

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        client.subscribe(f"spBv1.0/{GROUP}/#", qos=1)
        client.publish(
            f"spBv1.0/STATE/{HOST_ID}",
            json.dumps({"online": True, "timestamp": int(time.time() * 1000)}),
            qos=1,
            retain=True,
        )

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        now = time.time()
        with self.lock:
            self.raw.append((msg.topic, bytes(msg.payload), now))

    def start(self) -> None:
        self.client.connect("127.0.0.1", self.port, keepalive=5)
        self.client.loop_start()

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (from /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def int16(raw: int) -> int:
    raw &= 0xFFFF
    return raw - 0x10000 if raw & 0x8000 else raw


def percentile(values: list[float], p: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(p / 100 * (len(ordered) - 1))))]


def analyse(
    raw: list[tuple[str, bytes, float]],
    reports: dict[str, dict[str, Any]],
    window: tuple[float, float],
    restart_at: float = float("inf"),
) -> dict[str, Any]:
    from fieldgate.plugins.sparkplug import sparkplug_b_pb2 as pb
    from tests.sparkplug.broker import in_flight_repeats

    names: dict[tuple[str, str, int], str] = {}
    # (edge, channel) -> DDATA samples (timestamp, value, good, historical, arrival)
    got: dict[tuple[str, str], list[tuple[int, int, bool, bool, float]]] = {}
    births: dict[tuple[str, str], set[int]] = {}  # good values a DBIRTH delivered
    ddata = 0
    first = last = None

    def good(m: Any) -> bool:
        for key, value in zip(m.properties.keys, m.properties.values, strict=True):
            if key == "Quality":
                return bool(value.int_value == 192)
        return True  # DATA without the property: GOOD

    for topic, payload, received in raw:
        parts = topic.split("/")
        if len(parts) < 5:
            continue
        kind, edge, device = parts[2], parts[3], parts[4]
        msg = pb.Payload.FromString(payload)
        if kind == "DBIRTH":
            for m in msg.metrics:
                names[(edge, device, m.alias)] = m.name
                if good(m) and not m.is_null:
                    births.setdefault((edge, f"rs485/m1/{m.name}"), set()).add(int16(m.int_value))
        elif kind == "DDATA":
            ddata += 1
            first = received if first is None else first
            last = received
            for m in msg.metrics:
                cid = f"rs485/m1/{names[(edge, device, m.alias)]}"
                got.setdefault((edge, cid), []).append(
                    (m.timestamp, int16(m.int_value), good(m), m.is_historical, received)
                )
    payload_bytes = sum(len(payload) for _, payload, _ in raw)
    lost = dup = redelivered = 0
    disorder = {"live": 0, "historical": 0, "values": 0}
    examples: list[str] = []
    acq_latency: list[float] = []
    change_latency: list[float] = []
    for edge, report in reports.items():
        set_times = report["set_times"]
        for cid, values in report["seen"].items():
            samples = got.get((edge, cid), [])
            delivered = {v for _, v, ok, _, _ in samples if ok} | births.get((edge, cid), set())
            missing = set(values) - delivered
            lost += len(missing)
            if missing and len(examples) < 10:
                examples.append(f"{edge} {cid} lost values {sorted(missing)[:5]} of {len(values)}")
            keys = [(ts, v, ok) for ts, v, ok, _, _ in samples]
            dup += len(keys) - len(set(keys))
            copies = (((ts, v, ok), arrived, hist) for ts, v, ok, hist, arrived in samples)
            redelivered += in_flight_repeats(copies, restart_at)
            # arrival order of live samples, of historical ones, and the values along time
            live = [ts for ts, _, _, hist, _ in samples if not hist]
            hist = [ts for ts, _, _, hist, _ in samples if hist]
            along = [v for _, v, ok, _, _ in sorted(samples) if ok]
            for name, seq in (("live", live), ("historical", hist), ("values", along)):
                bad = [(a, b) for a, b in zip(seq, seq[1:], strict=False) if b < a]
                disorder[name] += len(bad)
                if bad and len(examples) < 10:
                    examples.append(f"{edge} {cid} {name}: {bad[:3]}")
            for ts, value, ok, historical, arrived in samples:
                if historical or not ok or window[0] <= arrived <= window[1]:
                    continue
                acq_latency.append(arrived - ts / 1000)
                if 1 <= value <= len(set_times):
                    change_latency.append(arrived - set_times[value - 1])
    duration = (last - first) if first is not None and last is not None else float("nan")
    samples_total = sum(len(v) for v in got.values())
    return {
        "ddata_messages": ddata,
        "messages_per_s": ddata / duration if duration else float("nan"),
        "payload_bytes_per_s": payload_bytes / duration if duration else float("nan"),
        "samples_per_s": samples_total / duration if duration else float("nan"),
        "acquisition_latency_ms": {
            "p50": 1000 * percentile(acq_latency, 50),
            "p99": 1000 * percentile(acq_latency, 99),
        },
        "change_latency_ms": {
            "p50": 1000 * percentile(change_latency, 50),
            "p99": 1000 * percentile(change_latency, 99),
        },
        "lost": lost,
        "duplicated": dup,
        # of those, repeats of a sample first seen before the restart and again as historical
        # after it: a DDATA the broker had read (and passed on) when it was killed, whose sync
        # had not come back, replayed from the journal (at-least-once; docs/sparkplug.md)
        "duplicated_in_flight": redelivered,
        "out_of_order": sum(disorder.values()),
        "out_of_order_by_check": disorder,
        "examples": examples,
    }


def run_fleet(args: argparse.Namespace) -> dict[str, Any]:
    from tests.sparkplug.broker import Mosquitto, mosquitto_path

    binary = mosquitto_path()
    if binary is None:
        raise SystemExit("mosquitto is not installed (.ci/mosquitto/install)")
    work = Path(tempfile.mkdtemp(prefix="fieldgate-fleet-"))
    broker = Mosquitto(binary, work, persistence=True)
    broker.start()
    checker = Checker(broker.port)
    checker.start()
    procs: dict[str, subprocess.Popen[str]] = {}
    reports: dict[str, Path] = {}
    started = time.time()
    try:
        for i in range(args.gateways):
            edge = f"gw{i:03d}"
            reports[edge] = work / f"{edge}.json"
            procs[edge] = subprocess.Popen(
                [
                    sys.executable,
                    __file__,
                    "--child",
                    "--index",
                    str(i),
                    "--port",
                    str(broker.port),
                    "--points",
                    str(args.points),
                    "--rate",
                    str(args.rate),
                    "--poll-ms",
                    str(args.poll_ms),
                    "--data-qos",
                    str(args.data_qos),
                    "--state-dir",
                    str(work / edge),
                    "--report",
                    str(reports[edge]),
                ],
                stdout=subprocess.PIPE,
                stderr=(work / f"{edge}.log").open("w"),
                text=True,
            )
        for edge, proc in procs.items():
            assert proc.stdout is not None
            if proc.stdout.readline().strip() != "running":
                raise SystemExit(f"gateway {edge} did not start")
        print(f"{args.gateways} gateways running; {args.duration:.0f} s", file=sys.stderr)
        run_start = time.time()
        time.sleep(args.duration / 2)
        broker_cpu = cpu_seconds(broker.proc.pid) if broker.proc else 0.0
        broker_cpu_span = time.time() - run_start
        kill_at = time.time()
        if args.restart == "kill":
            broker.kill()
        else:
            broker.stop()
        time.sleep(args.outage)
        broker.start()
        restart_at = time.time()
        print(f"broker restarted after {restart_at - kill_at:.1f} s", file=sys.stderr)
        time.sleep(max(0.0, run_start + args.duration - time.time()))
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in procs.values():
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
        time.sleep(0.5)
        checker.stop()
        broker.stop()
    loaded = {edge: json.loads(path.read_text()) for edge, path in reports.items() if path.exists()}
    # the restart window: samples acquired or arriving in it are not counted for latency
    result = analyse(checker.raw, loaded, (kill_at - 0.2, restart_at + 3.0), restart_at)
    result.update(
        broker_cpu=broker_cpu / broker_cpu_span,  # share of one core, first half of the run
        gateways=args.gateways,
        data_qos=args.data_qos,
        restart=args.restart,
        gateways_reporting=len(loaded),
        points=args.points,
        rate_hz=args.rate,
        duration_s=round(time.time() - started, 1),
        outage_s=round(restart_at - kill_at, 2),
        cpu_per_gateway={
            "mean": statistics.mean(r["cpu"] for r in loaded.values()),
            "max": max(r["cpu"] for r in loaded.values()),
        },
        rss_mb_per_gateway={
            "mean": statistics.mean(r["rss_mb"] for r in loaded.values()),
            "max": max(max(r["max_rss_mb"], r["rss_mb"]) for r in loaded.values()),
        },
        journal_dropped=sum(r["dropped"] or 0 for r in loaded.values()),
        poll_errors=sum(r["poll_errors"] for r in loaded.values()),
        backlog_left=sum(r["backlog"] or 0 for r in loaded.values()),
    )
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    parser.add_argument("--gateways", type=int, default=50)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds")
    parser.add_argument("--points", type=int, default=100, help="inputs per gateway")
    parser.add_argument("--rate", type=float, default=10.0, help="changes per second of each input")
    parser.add_argument(
        "--poll-ms",
        type=int,
        default=100,
        help="poll period of each gateway's module: a change waits up to one period to be read",
    )
    parser.add_argument(
        "--restart",
        choices=("term", "kill"),
        default="term",
        help="how the broker goes down in the middle: term (SIGTERM: it saves its sessions and "
        "queued messages and loads them again) or kill (SIGKILL: what it had acknowledged but "
        "not yet delivered to the checker dies with it)",
    )
    parser.add_argument("--outage", type=float, default=1.0, help="seconds the broker stays down")
    parser.add_argument(
        "--data-qos",
        type=int,
        choices=(0, 1),
        default=0,
        help="the front's data_qos: 0 (its default, Sparkplug 3.0) or 1 (at-least-once)",
    )
    parser.add_argument("--json", help="also write the results to this file")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--index", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--state-dir", help=argparse.SUPPRESS)
    parser.add_argument("--report", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        asyncio.run(run_gateway(args))
        return
    result = run_fleet(args)
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text)
    print(
        f"\n{result['gateways']} gateways x {result['points']} points at {result['rate_hz']:g} Hz, "
        f"data_qos {result['data_qos']}, broker {result['restart']}: "
        f"{result['messages_per_s']:.0f} msg/s, {result['samples_per_s']:.0f} samples/s; "
        f"latency change->subscriber p50 {result['change_latency_ms']['p50']:.1f} ms "
        f"p99 {result['change_latency_ms']['p99']:.1f} ms, acquisition->subscriber p50 "
        f"{result['acquisition_latency_ms']['p50']:.1f} ms p99 "
        f"{result['acquisition_latency_ms']['p99']:.1f} ms (outside the restart); "
        f"per gateway CPU {100 * result['cpu_per_gateway']['mean']:.1f} % of a core, "
        f"RSS {result['rss_mb_per_gateway']['mean']:.0f} MB (max {result['rss_mb_per_gateway']['max']:.0f}); "
        f"lost {result['lost']}, duplicated {result['duplicated']} "
        f"({result['duplicated_in_flight']} in flight at the restart), out of order {result['out_of_order']}",
        file=sys.stderr,
    )


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    main()
