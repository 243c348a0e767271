"""Modbus back: software overhead per transaction and cycle time, against the wire time.

Run:  .venv/bin/python bench/modbus_overhead.py   (about 10 s)

1. Software overhead per transaction: our adapter over pymodbus and the simulator on an
   unpaced pty pair (no baud rate, no inter-frame silence), so every microsecond is
   software: master + simulator + the pty relay. Measured with the simulator in this
   process (one CPU does everything) and in a child process (``fieldgate simulate
   modbus --pty``). Compared with the theoretical wire time of the same transaction at
   9600 and 115200 baud: request and reply bits (8N1: 10 bits a character) plus two
   3.5-character silences (1.75 ms each above 19200 baud). Target: overhead < 10 % of
   the wire time at 115200 baud.
2. Cycle time of the i7232d-style line (modules 1, 3, 4, 5 as in seed-000 §4) through
   the real ModbusBack and core's LineScheduler: unpaced (pure software), then on a pty
   paced at 115200 and 9600 baud with the inter-frame silence enforced, against the
   theoretical wire time of one cycle.
"""

from __future__ import annotations

import asyncio
import os
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout too

from fieldgate.plugin import GatewayContext  # noqa: E402
from fieldgate.plugins.modbus.back import ModbusBack  # noqa: E402
from fieldgate.plugins.modbus.client import ModbusLink, inter_frame_gap  # noqa: E402
from fieldgate.plugins.modbus.config import ModbusBackConfig  # noqa: E402
from fieldgate.plugins.modbus.simulator import ModbusSimulator  # noqa: E402
from fieldgate.serial_link import PtyPair, char_time  # noqa: E402
from fieldgate.topology import GatewaySection, Topology  # noqa: E402

I7232D = [
    {"address": 1, "model": "M-7052D"},
    {"address": 3, "model": "M-7055D", "counts": {"di": 0}},
    {"address": 4, "model": "M-7024", "counts": {"ao": 1}},
    {"address": 5, "model": "M-7017R", "counts": {"ai": 1}},
]
BITS_PER_CHAR = 10  # 8N1
BAUDS = (9600, 115200)

# (name, request bytes, reply bytes, call) -- the transactions of the i7232d line
TRANSACTIONS = [
    ("FC2 read 8 DI", 8, 6, lambda link: link.read_bits(1, 2, 32, 8)),
    ("FC1 read 8 coils", 8, 6, lambda link: link.read_bits(3, 1, 0, 8)),
    ("FC4 read 1 AI", 8, 7, lambda link: link.read_registers(5, 4, 0, 1)),
    ("FC3 read 1 AO", 8, 7, lambda link: link.read_registers(4, 3, 0, 1)),
    ("FC15 write 8 DO", 10, 8, lambda link: link.write(3, 15, 0, [True, False] * 4)),
    ("FC6 write 1 AO", 8, 8, lambda link: link.write(4, 6, 0, [1234])),
]
CYCLE = TRANSACTIONS[:4]  # one poll of each module


def wire_time(request: int, reply: int, baud: int) -> float:
    return (request + reply) * char_time(baud, BITS_PER_CHAR) + 2 * inter_frame_gap(baud)


def config(port: str = "unused", baud: int = 115200, **extra) -> ModbusBackConfig:
    return ModbusBackConfig(
        name="rs485",
        type="modbus",
        port=port,
        baudrate=baud,
        timeout_ms=500,
        poll_ms=0,
        modules=I7232D,
        **extra,
    )


async def per_transaction(link: ModbusLink, call, n: int) -> float:
    for _ in range(20):  # warm up
        await call(link)
    started = time.perf_counter()
    for _ in range(n):
        await call(link)
    return (time.perf_counter() - started) / n


async def overhead_in_process(n: int) -> dict[str, float]:
    with PtyPair() as pair:
        sim = ModbusSimulator(config(), pair.b)
        await sim.start()
        link = ModbusLink(pair.a, baudrate=115200, timeout=0.5, inter_frame=0)
        await link.open()
        try:
            return {name: await per_transaction(link, call, n) for name, _, _, call in TRANSACTIONS}
        finally:
            link.close()
            await sim.stop()


async def overhead_child_process(n: int) -> dict[str, float]:
    args = [
        sys.executable,
        "-m",
        "fieldgate",
        "simulate",
        "modbus",
        "--pty",
        "--baudrate",
        "115200",
        "--duration",
        "120",
    ]
    for m in I7232D:
        args += ["--module", f"{m['address']}:{m['model']}"]
    proc = await asyncio.create_subprocess_exec(
        *args,
        stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        banner = (await asyncio.wait_for(proc.stdout.readline(), 20)).decode()
        port = re.search(r"point the gateway at (\S+)", banner).group(1)
        link = ModbusLink(port, baudrate=115200, timeout=0.5, inter_frame=0)
        await link.open()
        try:
            return {name: await per_transaction(link, call, n) for name, _, _, call in TRANSACTIONS}
        finally:
            link.close()
    finally:
        proc.kill()
        await proc.wait()


async def cycle_time(baud: int | None, cycles: int) -> float:
    """Seconds per poll cycle of the i7232d line through ModbusBack + LineScheduler."""
    with PtyPair(baudrate=baud) as pair:
        cfg = config(pair.a, baud or 115200, **({} if baud else {"inter_frame_ms": 0}))
        sim = ModbusSimulator(cfg, pair.b)
        await sim.start()
        topology = Topology(
            GatewaySection(name="bench"), [], [cfg], channel_specs=cfg.channel_specs()
        )
        back = ModbusBack(cfg, GatewayContext.build(topology))
        await back.start()
        task = asyncio.create_task(back.run())
        try:
            stats = back.scheduler.stats
            while stats.cycles < 3:
                await asyncio.sleep(0.001)
            first, started = stats.cycles, time.perf_counter()
            while stats.cycles < first + cycles:
                await asyncio.sleep(0.001)
            elapsed = time.perf_counter() - started
            assert not any(stats.errors.values()), f"errors during the bench: {dict(stats.errors)}"
            return elapsed / (stats.cycles - first)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await back.stop()
            await sim.stop()


def ms(seconds: float) -> str:
    return f"{seconds * 1000:8.3f} ms"


async def main() -> None:
    n = 400
    print(
        f"Modbus RTU back: software overhead per transaction (unpaced pty, {n} transactions each)\n"
    )
    own = await overhead_in_process(n)
    child = await overhead_child_process(n)
    print(
        f"{'transaction':<18} {'in-process':>11} {'sim in child':>12} {'wire 9600':>11} {'wire 115200':>11} {'ratio@115200':>12}"
    )
    worst = 0.0
    for name, request, reply, _ in TRANSACTIONS:
        wires = [wire_time(request, reply, b) for b in BAUDS]
        ratio = child[name] / wires[1]
        worst = max(worst, ratio)
        print(
            f"{name:<18} {ms(own[name])} {ms(child[name]):>12} {ms(wires[0])} {ms(wires[1])} {ratio:11.1%}"
        )
    print(
        f"\nworst overhead / wire time at 115200 baud: {worst:.1%} (target < 10%) -> {'OK' if worst < 0.10 else 'MISSED'}"
    )
    print(
        "(ratio: the child column, i.e. the master's view; the in-process column also pays for the simulator on the same CPU)\n"
    )

    wire_cycle = {b: sum(wire_time(rq, rp, b) for _, rq, rp, _ in CYCLE) for b in BAUDS}
    unpaced = await cycle_time(None, 300)
    print(
        "Cycle of the i7232d-style line (modules 1, 3, 4, 5; 4 transactions), ModbusBack + LineScheduler:"
    )
    print(
        f"  unpaced pty (software only): {ms(unpaced)}  = {unpaced / wire_cycle[115200]:.1%} of the 115200 wire cycle, {unpaced / wire_cycle[9600]:.1%} of the 9600 one"
    )
    for baud, cycles in ((115200, 60), (9600, 15)):
        paced = await cycle_time(baud, cycles)
        print(
            f"  pty paced at {baud:>6} baud:   {ms(paced)}  wire time {ms(wire_cycle[baud])}  ratio {paced / wire_cycle[baud]:.2f}"
        )
    print(
        "  (paced: the master keeps t3.5 before each request; the simulator answers at once, so one of the two silences counted in the wire time is not spent)"
    )


if __name__ == "__main__":
    asyncio.run(main())
