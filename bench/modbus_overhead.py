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

import serial

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout too
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the paced wire

from paced_wire import PacedWire  # noqa: E402

from fieldgate.plugin import GatewayContext  # noqa: E402
from fieldgate.plugins.modbus.back import ModbusBack  # noqa: E402
from fieldgate.plugins.modbus.client import ModbusLink, inter_frame_gap  # noqa: E402
from fieldgate.plugins.modbus.codec import response_length  # noqa: E402
from fieldgate.plugins.modbus.config import ModbusBackConfig  # noqa: E402
from fieldgate.plugins.modbus.simulator import ModbusSimulator  # noqa: E402
from fieldgate.serial_link import AsyncSerial, PtyPair, char_time  # noqa: E402
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
    proc = await simulator_process(["--pty", "--baudrate", "115200"])
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


async def simulator_process(wire: list[str]) -> asyncio.subprocess.Process:
    """``fieldgate simulate modbus WIRE`` with the i7232d line's modules, in a process of its own."""
    args = [sys.executable, "-m", "fieldgate", "simulate", "modbus", *wire, "--duration", "120"]
    for m in I7232D:
        args += ["--module", f"{m['address']}:{m['model']}"]
    return await asyncio.create_subprocess_exec(
        *args,
        stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


async def child_simulator(port: str, baud: int) -> asyncio.subprocess.Process:
    """``fieldgate simulate modbus --port PORT``: the modules in a process of their own, as
    real modules are other hardware (their answers never wait for the master's loop)."""
    proc = await simulator_process(["--port", port, "--baudrate", str(baud)])
    while "simulating back" not in (await asyncio.wait_for(proc.stdout.readline(), 20)).decode():
        pass
    return proc


async def cycle_time(baud: int | None, cycles: int) -> tuple[float, float | None]:
    """Seconds per poll cycle of the i7232d line through ModbusBack + LineScheduler, and
    (paced) of the bare peer on the same wire and simulator right after it.

    Paced: the tests' wire (tests/paced_wire.py: byte by byte at the baud rate, in a process
    of its own, as a UART is other hardware) and the simulator in a child process; unpaced:
    a PtyPair and the simulator in this process (software only)."""
    sent: list[bytes] = []
    write = AsyncSerial.write

    async def recording(port: AsyncSerial, data: bytes) -> None:
        sent.append(bytes(data))
        await write(port, data)

    with PacedWire(baud) if baud else PtyPair() as pair:
        cfg = config(pair.a, baud or 115200, **({} if baud else {"inter_frame_ms": 0}))
        sim, child = None, None
        if baud:
            child = await child_simulator(pair.b, baud)
        else:
            sim = ModbusSimulator(cfg, pair.b)
            await sim.start()
        topology = Topology(
            GatewaySection(name="bench"), [], [cfg], channel_specs=cfg.channel_specs()
        )
        back = ModbusBack(cfg, GatewayContext.build(topology))
        AsyncSerial.write = recording  # type: ignore[method-assign]
        try:
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
                assert not any(stats.errors.values()), f"errors: {dict(stats.errors)}"
                ours = elapsed / (stats.cycles - first)
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
                await back.stop()
            # the peer on the same wire and modules: the bare minimum a master does
            bare = bare_cycle(pair.a, baud, sent[-len(CYCLE) :], cycles) if baud else None
            return ours, bare
        finally:
            AsyncSerial.write = write  # type: ignore[method-assign]
            if sim is not None:
                await sim.stop()
            if child is not None:
                child.kill()
                await child.wait()


def bare_cycle(port: str, baud: int, requests: list[bytes], cycles: int) -> float:
    """The same cycle's requests from plain blocking pyserial: t3.5 of silence, the request,
    the reply read to its length (no loop, no codec, no checks, no process image)."""
    gap = inter_frame_gap(baud)
    with serial.Serial(port, baud, timeout=0.5) as line:

        def one_cycle() -> None:
            for request in requests:
                time.sleep(gap)
                line.write(request)
                head = line.read(3)
                length = response_length(request[1], head) or 5
                rest = line.read(length - len(head))
                assert len(head) + len(rest) == length, "the peer got no full reply"

        for _ in range(3):
            one_cycle()
        started = time.perf_counter()
        for _ in range(cycles):
            one_cycle()
        return (time.perf_counter() - started) / cycles


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
    unpaced, _ = await cycle_time(None, 300)
    print(
        "Cycle of the i7232d-style line (modules 1, 3, 4, 5; 4 transactions), ModbusBack + LineScheduler:"
    )
    print(
        f"  unpaced pty (software only): {ms(unpaced)}  = {unpaced / wire_cycle[115200]:.1%} of the 115200 wire cycle, {unpaced / wire_cycle[9600]:.1%} of the 9600 one"
    )
    worst_paced = 0.0
    for baud, cycles in ((115200, 60), (9600, 15)):
        paced, bare = await cycle_time(baud, cycles)
        assert bare is not None
        over = (paced - bare) / bare
        worst_paced = max(worst_paced, over)
        print(
            f"  wire paced at {baud:>6} baud: {ms(paced)}  bare peer {ms(bare)}  overhead {over:6.1%}"
            f"  (theoretical wire time {ms(wire_cycle[baud])}, ratio {paced / wire_cycle[baud]:.2f})"
        )
    print(
        "  (paced: tests/paced_wire.py, byte by byte in a process of its own, the modules in a child; the bare peer:"
        " blocking pyserial, t3.5 then the request, the reply read to its length, on the same wire and modules right after;"
        " the simulator answers at once, so one of the two silences of the theoretical wire time is not spent)"
    )
    print(
        f"\npoll-cycle overhead of the Modbus back over the bare peer on a paced wire: {worst_paced:.1%} at worst (target <= 2%) -> {'OK' if worst_paced <= 0.02 else 'MISSED'}"
    )


if __name__ == "__main__":
    # on the loop `fieldgate run` uses (uvloop where installed; BENCH_LOOP=asyncio for the other)
    from fieldgate.cli import loop_factory  # noqa: E402

    with asyncio.Runner(loop_factory=loop_factory(os.environ.get("BENCH_LOOP", "auto"))) as runner:
        print(f"event loop: {type(runner.get_loop()).__module__.split('.')[0]}")
        runner.run(main())
