"""Northbound fronts side by side: OPC UA, Modbus TCP and Sparkplug B on one gateway, one run.

Run:  .venv/bin/python bench/northbound.py                 (100 points, 200 changes/s, 3 x 15 s)
      .venv/bin/python bench/northbound.py --phase-s 5 --rate 100

The gateway is its own process, built as ``fieldgate run --simulate`` builds it: a Modbus RTU
back polling one simulated module with --points input registers every --poll-ms (20) over a
pseudo-terminal at 115200 baud, and three fronts on the same process image: ``opcua``,
``modbus-tcp`` and ``sparkplug`` (to a Mosquitto from the distribution on a loopback port). A
driver in that process gives --rate simulated inputs a new value every second (a hundredth of
them every 10 ms, so changes fall evenly across polls and publishing intervals; each value
unique per channel), and logs every change of the process image
with the wall-clock time it happened (the acquisition: the poll that read it).

Clients, in this process: an MQTT subscriber decoding the Sparkplug DDATA (all phases); an
asyncua subscription (publishing interval 100 ms, every point; phase "opcua"); a Modbus TCP
client reading all input registers in one FC4 request every --modbus-poll-ms (10; phase
"modbus"). Three phases of --phase-s seconds: "base" (only the MQTT subscriber), "opcua" (+ the
OPC UA client), "modbus" (the Modbus client instead).

Reported per front: value changes delivered, latency from the acquisition to the client
(p50/p99; a Modbus TCP client sees a change only at its next read, so its figure includes up to
one --modbus-poll-ms), and the gateway's CPU per delivered change: for OPC UA and Modbus TCP the
extra CPU of their phase over the base phase, divided by the changes their client received
(Modbus TCP also per request); for Sparkplug, the whole gateway's CPU in the base phase per
change (polling, image and Sparkplug together: an upper bound).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests.sparkplug.broker starts Mosquitto
sys.path.insert(0, str(ROOT / "bench"))
from opcua_libs import cpu_seconds, free_port  # noqa: E402  # the same /proc reading and ports


def tree_cpu_seconds(pid: int) -> float:
    """CPU of the gateway process and of its children (each north-facing front runs in one)."""
    total, pids = 0.0, [pid]
    while pids:
        current = pids.pop()
        total += cpu_seconds(current)
        try:
            with open(f"/proc/{current}/task/{current}/children") as f:
                pids += [int(p) for p in f.read().split()]
        except OSError:
            pass
    return total


GROUP = "bench"


def topology(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "gateway": {"name": "nb", "state_dir": args.state_dir},
        "fronts": [
            {"name": "ua", "type": "opcua", "listen": f"127.0.0.1:{args.ua_port}"},
            {"name": "mb", "type": "modbus-tcp", "listen": f"127.0.0.1:{args.mb_port}"},
            {
                "name": "spb",
                "type": "sparkplug",
                "group_id": GROUP,
                "brokers": [{"host": "127.0.0.1", "port": args.mqtt_port}],
                "data_qos": 0,
            },
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",  # a pseudo-terminal (simulate)
                "baudrate": 115200,
                "poll_ms": args.poll_ms,
                "timeout_ms": 500,
                "fail_threshold": 10,
                "modules": [
                    {
                        "address": 1,
                        "channels": [
                            {
                                "kind": "ai",
                                "table": "input_registers",
                                "address": 0,
                                "count": args.points,
                            }
                        ],
                    }
                ],
            }
        ],
    }


# -- the gateway (child process) --------------------------------------------------------------
async def run_gateway(args: argparse.Namespace) -> None:
    from fieldgate.image import Quality
    from fieldgate.runtime import Gateway

    gw = Gateway.load(topology(args), simulate=True)
    stop = asyncio.Event()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    out = sys.stdout
    async with gw:

        def changed(ch: Any) -> None:
            if ch.quality is Quality.GOOD and ch.value_changed:
                out.write(f'{{"c":"{ch.channel.id}","v":{ch.value},"t":{time.time():.6f}}}\n')

        gw.image.subscribe(changed)
        sim = gw.bench.simulator("rs485")
        ids = [f"rs485/m1/ai{i}" for i in range(args.points)]
        print("running", flush=True)
        per_tick = max(1, args.rate // 100)  # every 10 ms: spread over the polls and publishes
        cursor = 0
        value = 0
        next_at = time.monotonic()
        while not stop.is_set():
            value += 1
            for _ in range(per_tick):
                sim.set_input(ids[cursor], value % 32768)
                cursor = (cursor + 1) % len(ids)
            out.flush()
            next_at += 0.01
            try:
                await asyncio.wait_for(stop.wait(), max(0.0, next_at - time.monotonic()))
            except TimeoutError:
                pass


# -- clients (this process) ---------------------------------------------------------------------
class Received:
    def __init__(self) -> None:
        self.items: list[tuple[str, int, float]] = []  # (channel, value, arrival)
        self.lock = threading.Lock()

    def add(self, cid: str, value: int, when: float) -> None:
        with self.lock:
            self.items.append((cid, value, when))

    def between(self, start: float, end: float) -> list[tuple[str, int, float]]:
        with self.lock:
            return [i for i in self.items if start <= i[2] < end]


def sparkplug_subscriber(port: int, got: Received) -> Any:
    import paho.mqtt.client as mqtt
    from paho.mqtt.enums import CallbackAPIVersion

    from fieldgate.plugins.sparkplug import sparkplug_b_pb2 as pb

    names: dict[int, str] = {}

    def on_message(client: Any, userdata: Any, msg: Any) -> None:
        now = time.time()
        kind = msg.topic.split("/")[2]
        payload = pb.Payload.FromString(msg.payload)
        if kind == "DBIRTH":
            names.update({m.alias: m.name for m in payload.metrics})
        elif kind == "DDATA":
            for m in payload.metrics:
                value = m.int_value - 0x1_0000_0000 if m.int_value & 0x8000_0000 else m.int_value
                got.add(f"rs485/m1/{names[m.alias]}", value, now)

    client = mqtt.Client(CallbackAPIVersion.VERSION2)
    client.on_connect = lambda c, *_: c.subscribe(f"spBv1.0/{GROUP}/#", qos=0)
    client.on_message = on_message
    client.connect("127.0.0.1", port)
    client.loop_start()
    return client


async def opcua_phase(port: int, points: int, got: Received, seconds: float) -> None:
    import logging

    from asyncua import Client, ua

    logging.getLogger("asyncua").setLevel(logging.ERROR)

    class Handler:
        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            got.add(node.nodeid.Identifier, int(val), time.time())

    client = Client(f"opc.tcp://127.0.0.1:{port}/")
    await client.connect()
    idx = await client.get_namespace_index("urn:fieldgate:nb")
    sub = await client.create_subscription(100, Handler())
    await sub.subscribe_data_change(
        [client.get_node(ua.NodeId(f"rs485/m1/ai{i}", idx)) for i in range(points)], queuesize=10
    )
    await asyncio.sleep(seconds)
    await client.disconnect()


async def modbus_phase(port: int, points: int, got: Received, seconds: float, period: float) -> int:
    from pymodbus.client import AsyncModbusTcpClient

    client = AsyncModbusTcpClient("127.0.0.1", port=port)
    await client.connect()
    last: list[int] | None = None
    requests = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        answer = await client.read_input_registers(0, count=points, device_id=1)
        now = time.time()
        requests += 1
        regs = [r - 0x10000 if r & 0x8000 else r for r in answer.registers]
        if last is not None:
            for i, (a, b) in enumerate(zip(last, regs, strict=True)):
                if a != b:
                    got.add(f"rs485/m1/ai{i}", b, now)
        last = regs
        await asyncio.sleep(period)
    client.close()
    return requests


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


WARM_UP_S = 1.0  # a client's first second: initial values of its subscription or first read


def steady(
    got: list[tuple[str, int, float]], acquired: dict[tuple[str, int], float], start: float
) -> list[tuple[str, int, float]]:
    """What a client received of the changes acquired after its first second."""
    return [g for g in got if acquired.get((g[0], g[1]), 0.0) >= start + WARM_UP_S]


def latencies(
    got: list[tuple[str, int, float]], acquired: dict[tuple[str, int], float]
) -> list[float]:
    return [(when - acquired[(cid, value)]) * 1000 for cid, value, when in got]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--role", default="driver", choices=["driver", "gateway"])
    ap.add_argument("--points", type=int, default=100)
    ap.add_argument("--rate", type=int, default=200, help="value changes per second at the module")
    ap.add_argument("--poll-ms", type=int, default=20)
    ap.add_argument("--modbus-poll-ms", type=int, default=10)
    ap.add_argument("--phase-s", type=float, default=15.0)
    ap.add_argument("--ua-port", type=int, default=0)
    ap.add_argument("--mb-port", type=int, default=0)
    ap.add_argument("--mqtt-port", type=int, default=0)
    ap.add_argument("--state-dir", default="")
    ap.add_argument("--json", help="write the results here too")
    args = ap.parse_args()
    if args.role == "gateway":
        asyncio.run(run_gateway(args))
        return 0

    from tests.sparkplug.broker import Mosquitto, mosquitto_path

    binary = mosquitto_path()
    if binary is None:
        print("mosquitto is not installed: .ci/mosquitto/install", file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix="northbound-"))
    broker = Mosquitto(binary, work)
    broker.start()
    spb = Received()
    mqtt = sparkplug_subscriber(broker.port, spb)  # before the gateway: it sees the births
    ports = [
        "--ua-port",
        str(free_port()),
        "--mb-port",
        str(free_port()),
        "--mqtt-port",
        str(broker.port),
    ]
    child = subprocess.Popen(
        [
            sys.executable,
            __file__,
            "--role",
            "gateway",
            "--points",
            str(args.points),
            "--rate",
            str(args.rate),
            "--poll-ms",
            str(args.poll_ms),
            "--state-dir",
            str(work / "state"),
            *ports,
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    acquired: dict[tuple[str, int], float] = {}
    assert child.stdout is not None
    if child.stdout.readline().strip() != "running":
        raise SystemExit("the gateway did not start")

    def read_log() -> None:
        assert child.stdout is not None
        for line in child.stdout:
            entry = json.loads(line)
            acquired[(entry["c"], entry["v"])] = entry["t"]

    threading.Thread(target=read_log, daemon=True).start()
    results: dict[str, dict[str, float]] = {}
    try:
        time.sleep(3.0)  # births, steady state
        phases: dict[str, tuple[float, float, float]] = {}  # name -> (start, end, cpu seconds)

        def phase(name: str, work: Any) -> Any:
            cpu0, t0 = tree_cpu_seconds(child.pid), time.time()
            result = asyncio.run(work) if work is not None else time.sleep(args.phase_s)
            cpu1, t1 = tree_cpu_seconds(child.pid), time.time()
            phases[name] = (t0, t1, cpu1 - cpu0)
            return result

        ua_got, mb_got = Received(), Received()
        phase("base", None)
        phase("opcua", opcua_phase(int(ports[1]), args.points, ua_got, args.phase_s))
        requests = phase(
            "modbus",
            modbus_phase(
                int(ports[3]), args.points, mb_got, args.phase_s, args.modbus_poll_ms / 1000
            ),
        )
        time.sleep(0.5)
    finally:
        mqtt.loop_stop()
        child.send_signal(signal.SIGTERM)
        try:
            child.wait(20)
        except subprocess.TimeoutExpired:
            child.kill()
        broker.stop()

    base_start, base_end, base_cpu = phases["base"]
    base_rate = base_cpu / (base_end - base_start)
    spb_base = spb.between(base_start, base_end)
    rows = []
    for name, got, (start, end, cpu) in (
        ("sparkplug", spb_base, phases["base"]),
        ("opcua", ua_got.between(*phases["opcua"][:2]), phases["opcua"]),
        ("modbus-tcp", mb_got.between(*phases["modbus"][:2]), phases["modbus"]),
    ):
        got = steady(got, acquired, start)
        wall = end - start - WARM_UP_S
        cpu *= wall / (end - start)
        lat = latencies(got, acquired)
        extra = cpu - base_rate * wall if name != "sparkplug" else cpu
        per_change = extra / len(got) * 1e6 if got else float("nan")
        results[name] = {
            "delivered_per_s": len(got) / wall,
            "p50_ms": percentile(lat, 0.5),
            "p99_ms": percentile(lat, 0.99),
            "gateway_cpu_share": cpu / wall,
            "cpu_us_per_change": per_change,
            "matched": len(lat),
        }
        rows.append((name, results[name]))
    results["modbus-tcp"]["cpu_us_per_request"] = (
        (phases["modbus"][2] - base_rate * (phases["modbus"][1] - phases["modbus"][0]))
        / max(requests, 1)
        * 1e6
    )
    offered = len([1 for (_c, _v), t in acquired.items() if base_start <= t < base_end]) / (
        base_end - base_start
    )
    print(
        f"{args.points} points, {args.rate} changes/s at the module, poll {args.poll_ms} ms, phases of {args.phase_s:g} s; "
        f"{offered:.0f} changes/s reached the process image; load average {os.getloadavg()[0]:.2f}"
    )
    print(
        f"{'front':<11} {'delivered/s':>11} {'acq->client p50':>16} {'p99':>9} {'gateway CPU':>12} {'us/change':>10}"
    )
    for name, r in rows:
        print(
            f"{name:<11} {r['delivered_per_s']:>11.0f} {r['p50_ms']:>13.1f} ms {r['p99_ms']:>6.1f} ms "
            f"{r['gateway_cpu_share'] * 100:>11.1f}% {r['cpu_us_per_change']:>10.1f}"
        )
    print(
        f"opcua and modbus-tcp: extra CPU over the base phase ({base_rate * 100:.1f}% of a core: polling, image, Sparkplug); "
        f"sparkplug: the whole base phase. modbus-tcp: {results['modbus-tcp']['cpu_us_per_request']:.0f} us per FC4 request of {args.points} registers "
        f"({requests} requests), latency includes up to {args.modbus_poll_ms} ms of the client's own poll"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
