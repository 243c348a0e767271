"""No client of a north-facing server slows the fieldbus side: SDO and poll cycle, quiet and
under attack, in the same run (issue 29).

Run:  .venv/bin/python bench/isolation.py [--phase-s S] [--rounds R] [--attacks LIST]
      [--attackers-nice N] [--fieldbus-nice N] [--fieldbus-cpus LIST] [--loop auto|uvloop|asyncio]
      (about (1 + attacks) x R x S seconds; default 2 rounds of 8 s, 6 attacks: about 2 minutes)

One gateway (examples/plant-northbound.yaml: CANopen on python-can's in-process ``virtual``
bus, OPC UA, Modbus TCP, Sparkplug (a real Mosquitto when installed) and the HTTP status
server, its Modbus modules simulated on pseudo-terminals and animated, the line polled as
fast as it goes: ``poll_ms: 0``) runs on its own event loop in a thread of this process, as
``fieldgate run`` would; its north-facing parts run in their child processes.

Conditions alternate in each round, ``quiet`` first, all measured the same way:

* ``d1``: 4 OPC UA sessions, each a subscription at publishing interval 0 with 10,000
  monitored items at sampling 0, whose client then stops sending Publish requests: the
  subscriptions expire while their clients stay connected (issue 29, D1)
* ``d2``: 4 connections sending a Hello and then an OPC UA MSG chunk that announces
  0x7FFFFFFF bytes, in 1 MB blocks, reconnecting whenever closed (D2)
* ``idle``: 500 idle TCP connections to each server (OPC UA, Modbus TCP, HTTP), reopened
  whenever closed (D3, D4)
* ``items``: one OPC UA session with 10,000 monitored items at sampling 0, reading its
  notifications
* ``kill``: the OPC UA and Modbus TCP children are SIGKILLed every 2 s while a Modbus TCP
  client writes a holding register as fast as it is answered: every write it saw
  acknowledged must be in the fieldbus process's image (0 acknowledged writes lost)
* ``all``: d1, d2, idle and items at once, the kill loop too

The attackers run in separate processes at ``--attackers-nice`` (default 19: they stand for
machines elsewhere on the plant network; 0 makes them compete for this host's 2 cores as
equals). Meanwhile this thread measures SDO expedited uploads (0x6401:1, answered on the
event loop, and 0x1000:0, answered on the CAN receive thread), one in flight, and every
completed poll cycle of the Modbus line.

Printed: per condition p50/p99 of both and the ratios attack/quiet of the p99s (target: at
most 1.2), the fieldbus process's RSS and CPU, each child's RSS, CPU and kills, and the
attackers' own CPU, so that an attack that did not load anything shows.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import os
import resource
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout too
sys.path.insert(0, str(ROOT / "bench"))
sys.path.append(str(ROOT / "tests"))
from netkit import free_port  # noqa: E402  (tests/netkit.py: one helper for tests, benches and scripts)

TARGET = 1.2
NODE_ID = 4  # examples/plant-northbound.yaml's node-ID
ATTACKS = ("d1", "d2", "idle", "items", "kill", "all")


def cpu_of(pid: int) -> float:
    from fieldgate.procstat import cpu_seconds

    return cpu_seconds(pid) or 0.0


def rss_of(pid: int) -> int:
    from fieldgate.procstat import resident_bytes

    return resident_bytes(pid) or 0


# == the attackers (separate processes) ===================================================
ATTACKER_ADDRESSES = [f"127.0.0.{i}" for i in range(2, 12)]
"""Where the attackers' connections come from: other loopback addresses than the plant's
own clients (127.0.0.1), as hostile or clumsy machines elsewhere on the plant network; the
servers' per-address budgets see them as the 10 machines they stand for."""


def from_other_addresses(loop: asyncio.AbstractEventLoop) -> None:
    """Every connection this loop opens (asyncio's streams, asyncua's client, pymodbus's)
    gets its source address from ATTACKER_ADDRESSES in turn."""
    original = loop.create_connection
    sources = itertools.cycle(ATTACKER_ADDRESSES)

    async def create_connection(*args: Any, **kwargs: Any) -> Any:
        kwargs.setdefault("local_addr", (next(sources), 0))
        return await original(*args, **kwargs)

    loop.create_connection = create_connection  # type: ignore[method-assign]


RECONNECT_S = 1.0  # an idle connection the server closed is opened again after this long


async def hold_idle(host: str, port: int, count: int, counts: dict[str, int]) -> None:
    """``count`` connections that never send a byte, each opened again RECONNECT_S after the
    server closes it (as a client's retry would: the servers evict idle connections to make
    room, so holding more than they admit is a stream of new connections)."""

    async def one() -> None:
        while True:
            try:
                reader, writer = await asyncio.open_connection(host, port)
            except OSError:
                counts["refused"] += 1
                await asyncio.sleep(0.5)
                continue
            counts["opened"] += 1
            await reader.read()  # until the server closes it
            writer.close()
            counts["closed_by_server"] += 1
            await asyncio.sleep(RECONNECT_S)

    await asyncio.gather(*(one() for _ in range(count)))


def ua_hello(url: str, size: int = 65535) -> bytes:
    body = struct.pack("<IIIII", 0, size, size, 0, 0)
    raw = url.encode()
    body += struct.pack("<i", len(raw)) + raw
    return b"HELF" + struct.pack("<I", 8 + len(body)) + body


async def chunk_flood(host: str, port: int, counts: dict[str, int]) -> None:
    """A Hello, then a MSG chunk announcing 0x7FFFFFFF bytes, sent in 1 MB blocks."""
    block = b"\x00" * (1 << 20)
    while True:
        try:
            reader, writer = await asyncio.open_connection(host, port)
        except OSError:
            counts["refused"] += 1
            await asyncio.sleep(0.2)
            continue
        counts["connections"] += 1
        try:
            writer.write(ua_hello(f"opc.tcp://{host}:{port}/"))
            writer.write(b"MSGF" + struct.pack("<I", 0x7FFFFFFF))
            while True:
                writer.write(block)
                await writer.drain()
                counts["mb_sent"] += 1
        except (OSError, ConnectionError):
            counts["closed_by_server"] += 1
        writer.close()
        await asyncio.sleep(0.05)


async def monitored(url: str, items: int, expire: bool, counts: dict[str, int]) -> None:
    """One OPC UA session with ``items`` monitored items at sampling 0; ``expire``: at
    publishing interval 0, and then no more Publish requests (D1), keeping the session."""
    from asyncua import Client, ua

    client = Client(url, timeout=30)
    await client.connect()
    counts["sessions"] += 1

    class Handler:
        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            counts["notifications"] += 1

    params = ua.CreateSubscriptionParameters(
        RequestedPublishingInterval=0 if expire else 100,
        RequestedLifetimeCount=3000,
        RequestedMaxKeepAliveCount=10,
        MaxNotificationsPerPublish=0,
        PublishingEnabled=True,
        Priority=0,
    )
    sub = await client.create_subscription(params, Handler())
    objects = await client.nodes.objects.get_children()
    variables: list[Any] = []
    stack = list(objects)
    while stack and len(variables) < 200:
        node = stack.pop()
        try:
            cls = await node.read_node_class()
        except Exception:
            continue
        if cls == ua.NodeClass.Variable:
            variables.append(node)
        elif cls == ua.NodeClass.Object:
            stack += await node.get_children()
    nodes = [variables[i % len(variables)] for i in range(items)]
    made = 0
    for start in range(0, items, 1000):
        try:
            handles = await sub.subscribe_data_change(
                nodes[start : start + 1000], sampling_interval=0
            )
            made += len(handles) if isinstance(handles, list) else 1
        except Exception:
            counts["refused_items"] += 1000
    counts["items"] += made
    if expire:
        task = client.uaclient._publish_task
        if task is not None:
            task.cancel()  # the subscription expires while the session stays
    while True:
        await asyncio.sleep(1)
        try:
            await client.check_connection()
        except Exception:
            counts["sessions_lost"] += 1
            return


async def ack_writer(host: str, port: int, acked: list[int]) -> None:
    """A Modbus TCP client writing holding register 1 (rs485/m4/ao1) with 1, 2, 3, ...: each
    value it sees acknowledged is recorded; a connection the server loses is reopened."""
    from pymodbus.client import AsyncModbusTcpClient

    value = 0
    while True:
        client = AsyncModbusTcpClient(host, port=port, timeout=2, retries=0)
        try:
            await client.connect()
            while client.connected:
                value = value % 30000 + 1
                reply = await client.write_register(1, value, device_id=1)
                if not reply.isError():
                    acked.append(value)
        except Exception:
            pass
        finally:
            client.close()
        await asyncio.sleep(0.05)


def attack(name: str, ports: dict[str, int]) -> None:
    """Run one attack until stdin closes; print what it did (JSON)."""
    resource.setrlimit(resource.RLIMIT_NOFILE, (resource.getrlimit(resource.RLIMIT_NOFILE)[1],) * 2)
    counts: dict[str, Any] = {
        "opened": 0,
        "closed_by_server": 0,
        "refused": 0,
        "connections": 0,
        "mb_sent": 0,
        "sessions": 0,
        "notifications": 0,
        "items": 0,
        "refused_items": 0,
        "sessions_lost": 0,
    }
    acked: list[int] = []
    host = "127.0.0.1"
    ua_url = f"opc.tcp://{host}:{ports['opcua']}/"

    async def main() -> None:
        if name != "writer":  # the plant's own client (the acknowledged writes) stays on .1
            from_other_addresses(asyncio.get_running_loop())
        jobs: list[Any] = []
        if name in ("d1", "all"):
            jobs += [monitored(ua_url, 10_000, True, counts) for _ in range(4)]
        if name in ("d2", "all"):
            jobs += [chunk_flood(host, ports["opcua"], counts) for _ in range(4)]
        if name in ("idle", "all"):
            jobs += [hold_idle(host, ports[p], 500, counts) for p in ("opcua", "modbus", "http")]
        if name in ("items", "all"):
            jobs.append(monitored(ua_url, 10_000, False, counts))
        if name == "writer":
            jobs.append(ack_writer(host, ports["modbus"], acked))
        tasks = [asyncio.ensure_future(_quiet(j)) for j in jobs]
        print("ready", flush=True)
        await asyncio.to_thread(sys.stdin.read)
        for t in tasks:
            t.cancel()

    asyncio.run(main())
    counts["acked"] = acked
    print(json.dumps(counts), flush=True)


async def _quiet(job: Any) -> None:
    try:
        await job
    except asyncio.CancelledError:
        raise
    except Exception as exc:  # an attack that fails is reported by its counts, not a traceback
        print(f"attack job ended: {type(exc).__name__}: {exc}", file=sys.stderr)


class Attacker:
    def __init__(self, name: str, ports: dict[str, int], nice: int, cpus: set[int] | None = None):
        self.name = name

        def lower() -> None:
            os.nice(nice)
            if cpus:  # other machines on the plant network: their work off the gateway's CPUs
                os.sched_setaffinity(0, cpus)

        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--attack", name, "--ports", json.dumps(ports)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            preexec_fn=lower,  # noqa: PLW1509  (no threads in this process yet)
        )
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != "ready":
            raise SystemExit(f"attacker {name} did not start")

    def stop(self) -> tuple[dict[str, Any], float]:
        cpu = cpu_of(self.proc.pid)
        out, _ = self.proc.communicate("", timeout=60)
        lines = out.strip().splitlines()
        return (json.loads(lines[-1]) if lines else {}), cpu


# == the gateway (a thread with its own loop) ==============================================
class GatewayThread:
    """examples/plant-northbound.yaml on its own loop in a thread of this process (the
    fieldbus process), its listeners on ``ports``; ``fast``: the line polled as fast as it goes."""

    def __init__(
        self,
        loop_choice: str,
        state_dir: str,
        ports: dict[str, int],
        fast: bool = True,
        fieldbus_nice: int | None = None,
        fieldbus_cpus: set[int] | None = None,
    ):
        from fieldgate.cli import loop_factory
        from fieldgate.runtime import Gateway

        self.channel = f"fieldgate-iso-bench-{uuid.uuid4().hex[:8]}"
        overrides: dict[str, Any] = {
            "gateway.state_dir": state_dir,
            "gateway.http.listen": f"127.0.0.1:{ports['http']}",
            "fronts.can.channel": self.channel,
            "fronts.opcua.listen": f"127.0.0.1:{ports['opcua']}",
            "fronts.modbus.listen": f"127.0.0.1:{ports['modbus']}",
            "fronts.plant.brokers.0.port": ports["mqtt"],
        }
        if fast:
            overrides["backs.rs485.poll_ms"] = 0
        if fieldbus_nice is not None:  # as the systemd unit's Nice= would (docs/deploy.md)
            overrides["gateway.isolation.fieldbus_nice"] = fieldbus_nice
        if fieldbus_cpus:  # the children on the other CPUs (docs/architecture.md)
            overrides["gateway.isolation.fieldbus_cpus"] = sorted(fieldbus_cpus)
        self.gateway = Gateway.load(
            ROOT / "examples" / "plant-northbound.yaml",
            overrides=overrides,
            simulate=True,
            animate=True,
        )
        self.loop = loop_factory(loop_choice)()
        self.cycles: list[float] = []
        self.recording = False
        self.applied: set[int] = set()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)

    def start(self) -> None:
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self.gateway.start(), self.loop).result(120)
        back = self.gateway.component("rs485")
        stats = back.scheduler.stats
        count = back.scheduler._count_cycle  # bench instrumentation: every completed cycle

        def counting(st: Any) -> None:
            before = stats.cycles
            count(st)
            if self.recording and stats.cycles != before:
                self.cycles.append(stats.last_cycle_time)

        back.scheduler._count_cycle = counting

        def written(changes: list[Any]) -> None:
            for c in changes:
                if c.origin == "modbus":
                    self.applied.add(c.value)

        self.call(lambda: self.gateway.image.subscribe_batch(written, ids=["rs485/m4/ao1"]))

    def call(self, fn: Any) -> Any:
        async def run() -> Any:
            return fn()

        return asyncio.run_coroutine_threadsafe(run(), self.loop).result(30)

    def children(self) -> dict[str, Any]:
        return self.call(self.gateway.children_status)  # type: ignore[no-any-return]

    def child_pids(self, names: tuple[str, ...]) -> list[int]:
        return [c["pid"] for n, c in self.children().items() if n in names and c["pid"]]

    def stop(self) -> None:
        asyncio.run_coroutine_threadsafe(self.gateway.stop(), self.loop).result(60)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(10)


class KillLoop(threading.Thread):
    """SIGKILLs the OPC UA and Modbus TCP children every ``period`` seconds."""

    def __init__(self, gw: GatewayThread, period: float = 2.0):
        super().__init__(daemon=True)
        self.gw, self.period, self.kills = gw, period, 0
        self.halt = threading.Event()

    def run(self) -> None:
        while not self.halt.wait(self.period):
            for pid in self.gw.child_pids(("opcua", "modbus")):
                try:
                    os.kill(pid, signal.SIGKILL)
                    self.kills += 1
                except ProcessLookupError:
                    pass


# == the measurement ============================================================================
def run(args: argparse.Namespace) -> int:
    import can
    from http_load import OBJECTS, pct, sdo_round_trips

    from fieldgate.cli import loop_name

    attacks = [a for a in args.attacks.split(",") if a]
    ports = {"opcua": free_port(), "modbus": free_port(), "http": free_port(), "mqtt": free_port()}
    broker = None
    with tempfile.TemporaryDirectory() as state_dir:
        try:
            from tests.sparkplug.broker import Mosquitto, mosquitto_path

            binary = mosquitto_path()
            if binary is not None:
                broker = Mosquitto(binary, Path(state_dir), port=ports["mqtt"])
                broker.start()
        except ImportError:
            pass
        if args.fieldbus_cpus and not args.attackers_cpus:  # else they inherit the pinned mask
            args.attackers_cpus = (set(os.sched_getaffinity(0)) - args.fieldbus_cpus) or None
        gw = GatewayThread(
            args.loop,
            state_dir,
            ports,
            fieldbus_nice=args.fieldbus_nice,
            fieldbus_cpus=args.fieldbus_cpus,
        )
        gw.start()
        time.sleep(2.0)  # every child has reported once
        bus = can.Bus(interface="virtual", channel=gw.channel, receive_own_messages=False)
        conditions = ["quiet", *attacks]
        results = {c: {**{n: [] for n in OBJECTS}, "cycle": []} for c in conditions}
        per_round = {c: {**{n: [] for n in OBJECTS}, "cycle": []} for c in conditions}
        side: dict[str, dict[str, Any]] = {c: {} for c in conditions}
        acked: list[int] = []
        me = os.getpid()
        print(
            f"fieldgate isolation bench: event loop {loop_name(gw.loop)}, {args.rounds} round(s) of "
            f"{args.phase_s:.0f} s per condition ({', '.join(conditions)}), attackers at nice "
            f"{args.attackers_nice}, fieldbus process at nice {os.nice(0) if args.fieldbus_nice is None else args.fieldbus_nice}, "
            f"fieldbus CPUs {','.join(map(str, sorted(os.sched_getaffinity(0))))}, "
            f"attackers' CPUs {','.join(map(str, sorted(args.attackers_cpus or os.sched_getaffinity(0))))}, "
            f"broker {'Mosquitto' if broker else 'none'}",
            flush=True,
        )
        try:
            sdo_round_trips(bus, 1.0, NODE_ID)  # warm-up
            for r in range(args.rounds):
                for condition in conditions:
                    attackers: list[Attacker] = []
                    kill = None
                    if condition not in ("quiet", "kill"):
                        attackers.append(
                            Attacker(condition, ports, args.attackers_nice, args.attackers_cpus)
                        )
                    if condition in ("kill", "all"):
                        attackers.append(
                            Attacker("writer", ports, args.attackers_nice, args.attackers_cpus)
                        )
                        kill = KillLoop(gw)
                        kill.start()
                    if attackers:
                        time.sleep(args.settle_s)  # the attack is on before we measure
                    cpu0, children0 = cpu_of(me), gw.children()
                    gw.cycles.clear()
                    gw.recording = True
                    times = sdo_round_trips(bus, args.phase_s, NODE_ID)
                    gw.recording = False
                    cpu1, children1 = cpu_of(me), gw.children()
                    if kill is not None:
                        kill.halt.set()
                        kill.join()
                    for name, values in times.items():
                        results[condition][name] += values
                        per_round[condition][name].append(pct(values, 0.99))
                    results[condition]["cycle"] += gw.cycles
                    per_round[condition]["cycle"].append(pct(gw.cycles, 0.99) if gw.cycles else 0)
                    info = side[condition]
                    info["fieldbus_cpu"] = info.get("fieldbus_cpu", 0.0) + cpu1 - cpu0
                    info["fieldbus_rss"] = max(info.get("fieldbus_rss", 0), rss_of(me))
                    info["seconds"] = info.get("seconds", 0.0) + args.phase_s
                    for name, c in children1.items():
                        before = children0.get(name, {}).get("cpu_s", 0.0)
                        used = c["cpu_s"] - before if c["cpu_s"] >= before else c["cpu_s"]
                        entry = info.setdefault("children", {}).setdefault(
                            name, {"cpu": 0.0, "rss": 0.0, "kills": {}}
                        )
                        entry["cpu"] += used
                        entry["rss"] = max(entry["rss"], c["peak_rss_mb"])
                        entry["kills"] = c["kills"]
                    if kill is not None:
                        info["sigkills"] = info.get("sigkills", 0) + kill.kills
                    for a in attackers:
                        counts, cpu = a.stop()
                        if a.name == "writer":
                            acked += counts.pop("acked", [])
                            info["writes_acked"] = info.get("writes_acked", 0) + len(acked)
                        else:
                            counts.pop("acked", None)
                        info["attacker_cpu"] = info.get("attacker_cpu", 0.0) + cpu
                        info.setdefault("counts", {}).update({k: v for k, v in counts.items() if v})
                print(f"  round {r + 1}/{args.rounds} done", flush=True)
            time.sleep(1.0)  # the last writes' changes have reached the subscription
            applied = set(gw.call(lambda: set(gw.applied)))
        finally:
            bus.shutdown()
            gw.stop()
            if broker is not None:
                broker.stop()
    lost = [v for v in acked if v not in applied]
    return report(results, per_round, side, len(acked), lost)


def report(results: dict, per_round: dict, side: dict, acked: int, lost: list[int]) -> int:
    from http_load import OBJECTS, pct

    print()
    print(f"{'condition':10} {'measure':28} {'p50':>9} {'p99':>9} {'p99/quiet':>10}   n")
    worst = 0.0
    for condition, series in results.items():
        for name in [*OBJECTS, "cycle"]:
            values = series[name]
            if not values:
                continue
            quiet99 = pct(results["quiet"][name], 0.99)
            p99 = pct(values, 0.99)
            ratio = p99 / quiet99
            if condition != "quiet":
                worst = max(worst, ratio)
            label = f"SDO {name}" if name != "cycle" else "poll cycle (5 modules)"
            print(
                f"{condition:10} {label:28} {pct(values, 0.5) * 1e3:7.3f}ms {p99 * 1e3:7.3f}ms"
                f" {ratio:10.3f}   {len(values)}"
            )
    print()
    print("p99 of each round (ms), per condition: the machine's own noise between rounds")
    for condition, series in per_round.items():
        text = "; ".join(
            f"{name.split(' ')[0]} " + " ".join(f"{v * 1e3:.2f}" for v in series[name])
            for name in [*OBJECTS, "cycle"]
        )
        print(f"  {condition:10} {text}")
    print()
    print("processes per condition (CPU in % of one core over the measured phases; RSS peak):")
    for condition, info in side.items():
        seconds = info["seconds"]
        kids = ", ".join(
            f"{n} {c['cpu'] / seconds * 100:.0f}% {c['rss']:.0f}MB"
            + (f" kills {c['kills']}" if c["kills"] else "")
            for n, c in info.get("children", {}).items()
        )
        print(
            f"  {condition:10} fieldbus {info['fieldbus_cpu'] / seconds * 100:5.1f}% "
            f"{info['fieldbus_rss'] / 2**20:.0f}MB | attackers "
            f"{info.get('attacker_cpu', 0.0) / seconds * 100:5.1f}% | children: {kids}"
        )
        if info.get("counts"):
            print(f"  {'':10} attack counts {info['counts']}")
        if "sigkills" in info:
            print(f"  {'':10} SIGKILLs sent {info['sigkills']}")
    print()
    print(f"acknowledged Modbus TCP writes across SIGKILLs: {acked}, lost: {len(lost)}")
    verdict = worst <= TARGET and not lost and acked > 0
    print(
        f"verdict: {'PASS' if verdict else 'ABOVE TARGET'}: worst p99 ratio attack/quiet "
        f"{worst:.3f} (target <= {TARGET}), {len(lost)} acknowledged write(s) lost"
    )
    return 0 if verdict else 1


def cpu_list(text: str) -> set[int]:
    """``0,1`` -> {0, 1}: a set of CPUs on the command line."""
    return {int(c) for c in text.split(",")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--phase-s", type=float, default=8.0, help="seconds per condition (default 8)"
    )
    parser.add_argument("--rounds", type=int, default=2, help="rounds (default 2)")
    parser.add_argument("--settle-s", type=float, default=3.0, help="attack on before measuring")
    parser.add_argument(
        "--attacks", default=",".join(ATTACKS), help="comma-separated: " + ",".join(ATTACKS)
    )
    parser.add_argument("--attackers-nice", type=int, default=19)
    parser.add_argument(
        "--attackers-cpus",
        type=cpu_list,
        default=None,
        help="CPUs the attackers run on (e.g. 1): on a plant network they are other machines, "
        "here their own work and their side of the loopback traffic stay off the other CPUs",
    )
    parser.add_argument(
        "--fieldbus-nice",
        type=int,
        default=None,
        help="niceness the fieldbus process asks for (the unit's Nice=-5; below 0 needs root)",
    )
    parser.add_argument(
        "--fieldbus-cpus",
        type=cpu_list,
        default=None,
        help="gateway.isolation.fieldbus_cpus (e.g. 0): the fieldbus process (this one, with "
        "the SDO master that measures) on these CPUs, the children and attackers on the others",
    )
    parser.add_argument("--loop", choices=("auto", "uvloop", "asyncio"), default="auto")
    parser.add_argument("--attack", help=argparse.SUPPRESS)
    parser.add_argument("--ports", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.attack:
        attack(args.attack, json.loads(args.ports))
        return 0
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
