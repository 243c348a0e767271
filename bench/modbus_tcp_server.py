"""The modbus-tcp front's server: this tree (our MBAP engine on asyncio) against pymodbus's.

Run:  .venv/bin/python bench/modbus_tcp_server.py              (about 40 s)
      .venv/bin/python bench/modbus_tcp_server.py --requests 500 --repeats 3
      .venv/bin/python bench/modbus_tcp_server.py --baseline REV --loop asyncio

Two server processes, each the ``modbus-tcp`` front alone on a process image (a ``modbus``
back's channels, not polled: one module of --points input registers, one of 4 holding
registers the client may write), built as the gateway builds it (``load_topology``,
``GatewayContext``, the registry's factory, ``start()``) on the event loop ``fieldgate run``
uses (``--loop``): one imports ``fieldgate`` from this checkout, the other from --baseline
(default :data:`PYMODBUS_FRONT`: the front on pymodbus 3.16.1's server, with the map of this
tree, so the difference is the server),
extracted with ``git archive`` (bench/cycle_cost.py's tree finder). The client, in this
process, is a blocking socket writing MBAP frames by hand, one request at a time, as a
SCADA polls: FC3 of 1 register, FC4 of --points registers, FC16 of 4 registers (a write:
answered once applied). The sides alternate request type by request type and repetition by
repetition (A B, B A, ...), so the machine's load falls on both.

Printed per request type and side: the server's CPU per request (``time.process_time()`` of
the server process, asked over its stdin before and after --requests requests that follow
a warm-up; median and range over --repeats), the client's
round trip p50 / p99 (all repetitions), and the ratio of the CPU medians (baseline / this
tree: above 1, this tree is cheaper).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
from cycle_cost import _extract, _git, _use_tree  # noqa: E402  # the baseline tree, imported
from opcua_libs import free_port  # noqa: E402

PYMODBUS_FRONT = "7b8f4d051dc9f561a8b232084dbc094edb4d1580"  # the front on pymodbus's ModbusTcpServer, with this tree's map


def topology(port: int, points: int) -> dict[str, Any]:
    return {
        "gateway": {"name": "bench"},
        "fronts": [
            {
                "name": "mb",
                "type": "modbus-tcp",
                "listen": f"127.0.0.1:{port}",
                "expose": ["rs485/m2/*", "rs485/m1/*"],  # holding registers from address 0
                "writable": ["rs485/m2/ao*"],
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",  # never opened: the channels are what the front needs
                "modules": [
                    {
                        "address": 1,
                        "channels": [
                            {
                                "kind": "ai",
                                "table": "input_registers",
                                "address": 0,
                                "count": points,
                            }
                        ],
                    },
                    {"address": 2, "model": "M-7024"},
                ],
            }
        ],
    }


# -- the server (a worker process) -----------------------------------------------------------
def serve(root: Path, loop: str, points: int) -> None:
    _use_tree(root)
    from fieldgate.cli import loop_factory
    from fieldgate.plugin import GatewayContext, load_registry
    from fieldgate.topology import load_topology

    async def main() -> None:
        registry = load_registry()
        port = free_port()
        topo = load_topology(topology(port, points), registry)
        context = GatewayContext.build(topo)
        cfg = topo.fronts[0]
        front = registry.lookup("front", "modbus-tcp").factory(cfg, context)  # type: ignore[union-attr]
        await front.start()
        origin = sys.modules[type(front).__module__].__file__
        print(json.dumps({"port": port, "origin": origin}), flush=True)
        while await asyncio.to_thread(sys.stdin.readline):  # "cpu": the process's CPU time
            print(json.dumps({"cpu": time.process_time()}), flush=True)
        await front.stop()

    with asyncio.Runner(loop_factory=loop_factory(loop)) as runner:
        runner.run(main())


# -- the client (this process) ---------------------------------------------------------------
class Server:
    def __init__(self, label: str, root: Path, loop: str, points: int):
        self.label = label
        self.proc = subprocess.Popen(
            [
                sys.executable,
                __file__,
                "--serve",
                str(root),
                "--loop",
                loop,
                "--points",
                str(points),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"the {label} server ended early (its error is above)")
        info = json.loads(line)
        self.port, self.origin = info["port"], info["origin"]

    def cpu(self) -> float:
        """The server's CPU seconds so far (user + system, every thread)."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write("cpu\n")
        self.proc.stdin.flush()
        return float(json.loads(self.proc.stdout.readline())["cpu"])

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait(timeout=30)


def requests_of(points: int) -> dict[str, bytes]:
    return {
        "FC3, 1 register": struct.pack(">BHH", 3, 0, 1),
        f"FC4, {points} registers": struct.pack(">BHH", 4, 0, points),
        "FC16, 4 registers (write)": struct.pack(">BHHBHHHH", 16, 0, 4, 8, 1, 2, 3, 4),
    }


def exactly(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise SystemExit("the server closed the connection")
        data += chunk
    return data


def run_phase(server: Server, pdu: bytes, n: int, warmup: int = 200) -> tuple[float, list[float]]:
    """(server CPU seconds per request, round trips in seconds) over ``n`` requests."""
    with socket.create_connection(("127.0.0.1", server.port)) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        frame = struct.pack(">HHHB", 1, 0, len(pdu) + 1, 1) + pdu
        for _ in range(warmup):
            sock.sendall(frame)
            head = exactly(sock, 7)
            exactly(sock, struct.unpack(">H", head[4:6])[0] - 1)
        trips = []
        cpu_before = server.cpu()
        for _ in range(n):
            started = time.perf_counter()
            sock.sendall(frame)
            head = exactly(sock, 7)
            body = exactly(sock, struct.unpack(">H", head[4:6])[0] - 1)
            trips.append(time.perf_counter() - started)
            if body[0] & 0x80:
                raise SystemExit(f"{server.label}: exception {body.hex()} to {pdu.hex()}")
        cpu = server.cpu() - cpu_before
    return cpu / n, trips


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def compare(args: argparse.Namespace) -> None:
    head = _git("rev-parse", "--short", "HEAD")
    dirty = " + uncommitted changes" if _git("status", "--porcelain", "--", "plugins") else ""
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="mbtcp-bench-baseline-") as tmp:
        base = _extract(args.baseline, Path(tmp))
        servers = {
            "baseline": Server("baseline", Path(tmp), args.loop, args.points),
            "this tree": Server("this tree", ROOT, args.loop, args.points),
        }
        try:
            print(
                f"modbus-tcp server: {args.requests} requests x {args.repeats} repetitions per "
                f"side and request type, alternating; Python {sys.version.split()[0]}, "
                f"{os.cpu_count()} CPUs, load average {load:.2f}, --loop {args.loop}"
            )
            print(f"  baseline:  {base[:12]} ({args.baseline}): {servers['baseline'].origin}")
            print(f"  this tree: {head}{dirty}: {servers['this tree'].origin}")
            cpu: dict[str, dict[str, list[float]]] = {}
            trips: dict[str, dict[str, list[float]]] = {}
            for name, pdu in requests_of(args.points).items():
                cpu[name] = {s: [] for s in servers}
                trips[name] = {s: [] for s in servers}
                for rep in range(args.repeats):
                    order = list(servers) if rep % 2 == 0 else list(servers)[::-1]
                    for side in order:
                        per_request, times = run_phase(servers[side], pdu, args.requests)
                        cpu[name][side].append(per_request * 1e6)
                        trips[name][side] += times
        finally:
            for server in servers.values():
                server.close()
    print(
        f"\n{'request':28} {'side':10} {'CPU us/request: median (range)':32} "
        f"{'round trip p50 / p99':22} baseline/this (CPU)"
    )
    for name in cpu:
        for side in cpu[name]:
            values = cpu[name][side]
            t = trips[name][side]
            ratio = ""
            if side == "this tree":
                ratios = [b / a for a, b in zip(values, cpu[name]["baseline"], strict=True)]
                ratio = (
                    f"{statistics.median(cpu[name]['baseline']) / statistics.median(values):.2f}x"
                    f" ({min(ratios):.2f}-{max(ratios):.2f})"
                )
            print(
                f"{name:28} {side:10} {statistics.median(values):7.1f} "
                f"({min(values):.1f}-{max(values):.1f}){'':14} "
                f"{pct(t, 0.5) * 1e3:6.3f} / {pct(t, 0.99) * 1e3:6.3f} ms   {ratio}"
            )
    print(f"load average after: {os.getloadavg()[0]:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--points", type=int, default=100)
    parser.add_argument("--baseline", default=PYMODBUS_FRONT)
    parser.add_argument("--loop", default="uvloop", choices=("uvloop", "asyncio"))
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(Path(args.serve), args.loop, args.points)
    else:
        compare(args)


if __name__ == "__main__":
    main()
