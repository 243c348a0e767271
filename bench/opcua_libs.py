"""asyncua against o6 (open62541) as the OPC UA server of the ``opcua`` front: one run, same machine.

Run:  .venv/bin/python bench/opcua_libs.py                 (1, 5, 20 clients; ~4 min)
      .venv/bin/python bench/opcua_libs.py --clients 1 --window 5 --libs asyncua

Needs both libraries (``pip install asyncua o6``; o6 is not a fieldgate dependency: the
bench is how it was ruled out, docs/opcua.md). Each server runs in its own process with
--items Int32 variables (1,000) in one namespace, and changes --rate of them per second
(1,000: every item once a second, 100 items every 100 ms), on its asyncio loop, the way the
front writes the process image's changes. The clients, in one other process, are asyncua
clients (the same client code for both servers): each creates one subscription with a
100 ms publishing interval and a monitored item (sampling interval 100 ms, queue 1) on
every variable, and counts the data-change notifications it receives.

Reported per library and client count: server CPU (user + system, from /proc) per delivered
value change (notifications received by all clients in the measuring window), the server's
share of one core, delivered changes per second against offered (rate x clients), RSS after
the run and its peak, and start time (process start, interpreter and library import
included, until the address space is built and the endpoint listens; a session is then
opened to check it answers).
Both servers run on loopback with security None. o6 without a credential runs in its
"Script Mode" (the process exits after ten minutes): each server process here lives about a
minute.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.append(str(ROOT / "tests"))
from netkit import free_port  # noqa: E402  (tests/netkit.py: one helper for tests, benches and scripts)

URI = "urn:fieldgate:bench"
CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def rss_mb(pid: int) -> tuple[float, float]:
    rss = hwm = 0.0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) / 1024
        elif line.startswith("VmHWM:"):
            hwm = int(line.split()[1]) / 1024
    return rss, hwm


# -- servers (child process) ----------------------------------------------------------------
async def serve_asyncua(port: int, items: int, rate: int) -> None:
    import logging

    from asyncua import Server, ua

    logging.getLogger("asyncua").setLevel(logging.ERROR)
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{port}/")
    server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    idx = await server.register_namespace(URI)
    folder = await server.nodes.objects.add_folder(ua.NodeId("bench", idx), "bench")
    ids = []
    for i in range(items):
        node = await folder.add_variable(
            ua.NodeId(f"v{i}", idx), f"v{i}", ua.Variant(0, ua.VariantType.Int32)
        )
        ids.append(node.nodeid)
    await server.start()
    print("READY", flush=True)

    async def write(batch: list[tuple[int, int]]) -> None:
        for i, value in batch:
            await server.write_attribute_value(
                ids[i], ua.DataValue(ua.Variant(value, ua.VariantType.Int32))
            )

    await drive(write, items, rate)


async def serve_o6(port: int, items: int, rate: int) -> None:
    import o6

    server = o6.Server(port=port)
    parent = server.objectsNode
    names = [f"ns=1;s=v{i}" for i in range(items)]
    for i, nid in enumerate(names):
        await server.addVariable(f"v{i}", parent, o6.Int32(0), nodeId=nid)
    server.start()
    await server.waitReady()
    print("READY", flush=True)

    async def write(batch: list[tuple[int, int]]) -> None:
        await server.write({names[i]: o6.Int32(value) for i, value in batch})

    await drive(write, items, rate)


async def drive(write: object, items: int, rate: int) -> None:
    """Every 100 ms, the next rate/10 items get a new value (each item in turn)."""
    per_tick = max(1, rate // 10)
    cursor = 0
    value = 0
    next_tick = time.monotonic()
    while True:
        next_tick += 0.1
        value += 1
        batch = []
        for _ in range(per_tick):
            batch.append((cursor, value))
            cursor = (cursor + 1) % items
        await write(batch)  # type: ignore[operator]
        await asyncio.sleep(max(0.0, next_tick - time.monotonic()))


# -- clients (child process) ----------------------------------------------------------------
async def run_clients(url: str, n: int, items: int, ns_index_uri: str) -> None:
    import logging

    from asyncua import Client, ua

    logging.getLogger("asyncua").setLevel(logging.ERROR)
    counts = [0] * n

    class Handler:
        def __init__(self, k: int) -> None:
            self.k = k

        def datachange_notification(self, node: object, val: object, data: object) -> None:
            counts[self.k] += 1

    clients = []
    for k in range(n):
        client = Client(url, timeout=30)
        await client.connect()
        idx = (
            int(ns_index_uri)
            if ns_index_uri.isdigit()
            else await client.get_namespace_index(ns_index_uri)
        )
        nodes = [client.get_node(ua.NodeId(f"v{i}", idx)) for i in range(items)]
        sub = await client.create_subscription(100, Handler(k))
        await sub.subscribe_data_change(nodes, queuesize=1, sampling_interval=100)
        clients.append(client)
    print("SUBSCRIBED", flush=True)
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    while True:
        line = (await reader.readline()).decode().strip()
        if not line or line == "quit":
            break
        print(json.dumps({"t": time.monotonic(), "count": sum(counts)}), flush=True)
    for client in clients:
        await client.disconnect()


# -- driver ---------------------------------------------------------------------------------
def one_run(lib: str, clients: int, items: int, rate: int, window: float) -> dict[str, float]:
    port = free_port()
    me = [sys.executable, __file__]
    t0 = time.monotonic()
    server = subprocess.Popen(
        [
            *me,
            "--role",
            "server",
            "--libs",
            lib,
            "--port",
            str(port),
            "--items",
            str(items),
            "--rate",
            str(rate),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert server.stdout is not None
        for line in server.stdout:  # o6 prints a banner first
            if line.strip() == "READY":
                break
        else:
            raise RuntimeError(f"{lib} server did not start")
        started = time.monotonic() - t0  # address space built, listening
        ns_uri = URI if lib == "asyncua" else "1"  # o6: the server's namespace 1
        for _ in range(50):  # the endpoint answers a session
            probe = subprocess.run(
                [*me, "--role", "probe", "--port", str(port)], capture_output=True, text=True
            )
            if probe.returncode == 0:
                break
        else:
            raise RuntimeError(f"{lib} server accepts no session")
        cl = subprocess.Popen(
            [
                *me,
                "--role",
                "clients",
                "--port",
                str(port),
                "--n",
                str(clients),
                "--items",
                str(items),
                "--ns-uri",
                ns_uri,
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert cl.stdout is not None and cl.stdin is not None
        if cl.stdout.readline().strip() != "SUBSCRIBED":
            raise RuntimeError("clients did not subscribe")
        time.sleep(2.0)  # initial values delivered, steady state

        def sample() -> tuple[float, int, float]:
            cl.stdin.write("count\n")  # type: ignore[union-attr]
            cl.stdin.flush()  # type: ignore[union-attr]
            got = json.loads(cl.stdout.readline())  # type: ignore[union-attr]
            return got["t"], got["count"], cpu_seconds(server.pid)

        t_a, n_a, cpu_a = sample()
        time.sleep(window)
        t_b, n_b, cpu_b = sample()
        cl.stdin.write("quit\n")
        cl.stdin.flush()
        cl.wait(30)
        rss, hwm = rss_mb(server.pid)
        delivered = n_b - n_a
        cpu = cpu_b - cpu_a
        return {
            "start_s": started,
            "delivered_per_s": delivered / (t_b - t_a),
            "offered_per_s": rate * clients,
            "cpu_share": cpu / (t_b - t_a),
            "cpu_us_per_change": cpu / delivered * 1e6 if delivered else float("inf"),
            "rss_mb": rss,
            "peak_rss_mb": hwm,
        }
    finally:
        server.kill()
        server.wait()


async def probe(port: int) -> None:
    from asyncua import Client

    client = Client(f"opc.tcp://127.0.0.1:{port}/", timeout=2)
    await client.connect()
    await client.get_namespace_array()
    await client.disconnect()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--role", default="driver", choices=["driver", "server", "clients", "probe"])
    ap.add_argument("--libs", default="asyncua,o6")
    ap.add_argument("--clients", default="1,5,20", help="client counts, comma separated")
    ap.add_argument("--items", type=int, default=1000)
    ap.add_argument("--rate", type=int, default=1000, help="value changes per second at the server")
    ap.add_argument("--window", type=float, default=15.0, help="measuring window, seconds")
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--n", type=int, default=1)
    ap.add_argument("--ns-uri", default=URI, help="namespace URI of the variables, or an index")
    ap.add_argument("--json", help="write the results here too")
    args = ap.parse_args()
    if args.role == "server":
        serve = serve_asyncua if args.libs == "asyncua" else serve_o6
        asyncio.run(serve(args.port, args.items, args.rate))
        return 0
    if args.role == "clients":
        asyncio.run(
            run_clients(f"opc.tcp://127.0.0.1:{args.port}/", args.n, args.items, args.ns_uri)
        )
        return 0
    if args.role == "probe":
        try:
            asyncio.run(probe(args.port))
        except Exception:
            return 1
        return 0
    results = []
    print(
        f"{args.items} monitored items per client, publishing 100 ms, {args.rate} value changes/s "
        f"at the server, window {args.window:g} s; load average {os.getloadavg()[0]:.2f}"
    )
    print(
        f"{'library':<8} {'clients':>7} {'start s':>8} {'delivered/s':>12} {'offered/s':>10} "
        f"{'server CPU':>10} {'us/change':>10} {'RSS MB':>7} {'peak MB':>8}"
    )
    for n in [int(x) for x in args.clients.split(",")]:
        for lib in args.libs.split(","):
            r = one_run(lib, n, args.items, args.rate, args.window)
            results.append({"library": lib, "clients": n, **r})
            print(
                f"{lib:<8} {n:>7} {r['start_s']:>8.2f} {r['delivered_per_s']:>12.0f} "
                f"{r['offered_per_s']:>10.0f} {r['cpu_share'] * 100:>9.1f}% "
                f"{r['cpu_us_per_change']:>10.1f} {r['rss_mb']:>7.1f} {r['peak_rss_mb']:>8.1f}",
                flush=True,
            )
    by = {(r["library"], r["clients"]): r for r in results}
    for n in [int(x) for x in args.clients.split(",")]:
        a, o = by.get(("asyncua", n)), by.get(("o6", n))
        if a and o:
            print(
                f"{n:>2} client(s): asyncua/o6 CPU per delivered change {a['cpu_us_per_change'] / o['cpu_us_per_change']:.2f}, "
                f"delivered {a['delivered_per_s'] / max(o['delivered_per_s'], 1e-9):.2f}"
            )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
