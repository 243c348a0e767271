#!/usr/bin/env python3
"""A dead device and the others' polls, on the modbus-tcp-client back (about 40 s).

Four meters on loopback (simulated hosts, real sockets), each polled every 100 ms, timeout
500 ms, fail_threshold 3, offline_probe_ms 2000. One phase per case, each ``--seconds`` long;
what a healthy meter sees is measured at its host (the time between two of its requests):

* base: every meter answers;
* dead host: one meter's host refuses connections (its own host: the others are elsewhere);
* dead unit, shared host, pipeline 1: one of two units behind one TCP/RTU gateway is silent;
* dead unit, shared host, pipeline 2: the same, with two lanes on the connection.

Prints the healthy meter's interval p50 / p99 / max per case, against the base case of the
same run. Run: .venv/bin/python bench/modbus_tcp_client.py [--seconds 8]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics

from fieldgate import load_registry
from fieldgate.plugin import GatewayContext
from fieldgate.plugins.modbus import Fault, ModbusTcpClientBack, ModbusTcpSimulator
from fieldgate.topology import load_topology

AI = {"kind": "ai", "table": "input_registers", "address": 0, "count": 4}


def topology(hosts: list[str], pipeline: int) -> dict:
    return {
        "gateway": {"name": "bench"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "net",
                "type": "modbus-tcp-client",
                "poll_ms": 100,
                "timeout_ms": 500,
                "offline_probe_ms": 2000,
                "pipeline": pipeline,
                "modules": [
                    {"address": i + 1, "host": host, "channels": [AI]}
                    for i, host in enumerate(hosts)
                ],
            }
        ],
    }


async def phase(name: str, topo: dict, broken: str | None, seconds: float) -> list[float]:
    loaded = load_topology(topo, load_registry())
    config = loaded.back("net")
    sim = ModbusTcpSimulator(config)
    await sim.start()
    if broken == "host":
        await sim.kill_host(4)
    elif broken == "unit":
        sim.inject(2, Fault("no_answer"))
    back = ModbusTcpClientBack(config, GatewayContext.build(loaded))
    await back.start()
    task = asyncio.ensure_future(back.run())
    await asyncio.sleep(seconds)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    await back.stop()
    times = [s.at for s in sim.requests(1) if s.unit == 1]
    await sim.stop()
    skip = max(1, len(times) // 10)  # the first connects and the offline transition out
    return [b - a for a, b in zip(times[skip:], times[skip + 1 :], strict=False)]


def summary(intervals: list[float]) -> tuple[float, float, float]:
    ordered = sorted(intervals)
    p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    return statistics.median(ordered) * 1000, p99 * 1000, ordered[-1] * 1000


async def main(seconds: float) -> None:
    own = ["10.9.0.1", "10.9.0.2", "10.9.0.3", "10.9.0.4"]  # one host each
    gateway = ["10.9.0.1", "10.9.0.1", "10.9.0.3", "10.9.0.4"]  # units 1 and 2 share a host
    cases = [
        ("base (every meter answers)", topology(own, 1), None),
        ("dead host (meter 4 refuses)", topology(own, 1), "host"),
        ("dead unit on the shared host, pipeline 1", topology(gateway, 1), "unit"),
        ("dead unit on the shared host, pipeline 2", topology(gateway, 2), "unit"),
    ]
    rows = []
    for name, topo, broken in cases:
        rows.append((name, summary(await phase(name, topo, broken, seconds))))
    base = rows[0][1][0]
    print(f"healthy meter's poll interval (poll_ms 100, timeout 500 ms), {seconds:.0f} s a case")
    print(f"{'case':<44} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'p50/base':>9}")
    for name, (p50, p99, worst) in rows:
        print(f"{name:<44} {p50:8.1f} {p99:8.1f} {worst:8.1f} {p50 / base:9.2f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0)
    asyncio.run(main(parser.parse_args().seconds))
