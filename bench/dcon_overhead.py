"""DCON back: software overhead per transaction and poll-cycle time, against the wire time.

Run:  .venv/bin/python bench/dcon_overhead.py   (about 15 s)

1. Software overhead per transaction: DconLink (codec + asyncio serial) against the
   DCON simulator on an unpaced pty pair, so every microsecond is software: master +
   simulator + pty relay. The simulator runs in a child process (``fieldgate simulate
   dcon --pty``), as real modules are other hardware; the in-process column pays for
   the simulator on the same CPU too. The peer, measured in the same run, is the bare
   minimum a master can do: write the same bytes and wait for the CR with the same
   asyncio serial port, no codec, no checks. Compared with the theoretical wire time of
   the transaction (command and reply, 8N1 = 10 bits a character; DCON has no
   inter-frame silence) at 9600 and 115200 baud. Target: < 10 % at 115200.
2. Poll cycle of an i7231d-style line (I-7043, I-7053, I-7021, I-7012 as in the
   seed-001 PDO demo, plus an I-7017) through DconBack and core's LineScheduler:
   unpaced, then on a pty paced at 115200 and 9600 baud, against the cycle's wire time.
   The master's own share is measured directly: the turnaround from the arrival of a
   reply's CR at the port to the write of the next command (parse, process-image
   update, scheduling, next command), per transaction, against the mean wire time of a
   transaction. That is the poll-cycle overhead the DCON back adds to a real line.
"""

from __future__ import annotations

import asyncio
import os
import re
import statistics
import sys
import time
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout too
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the paced wire

from paced_wire import PacedWire  # noqa: E402

from fieldgate.plugin import GatewayContext  # noqa: E402
from fieldgate.plugins.dcon import codec  # noqa: E402
from fieldgate.plugins.dcon.back import DconBack  # noqa: E402
from fieldgate.plugins.dcon.config import DconBackConfig  # noqa: E402
from fieldgate.plugins.dcon.link import DconLink  # noqa: E402
from fieldgate.plugins.dcon.simulator import DconSimulator  # noqa: E402
from fieldgate.serial_link import AsyncSerial, PtyPair, char_time  # noqa: E402
from fieldgate.topology import GatewaySection, Topology  # noqa: E402

LINE = [(1, "I-7043"), (2, "I-7053"), (3, "I-7021"), (4, "I-7012"), (5, "I-7017")]
BITS_PER_CHAR = 10
BAUDS = (9600, 115200)

# (name, command text, reply length in characters incl. CR)
TRANSACTIONS = [
    ("#05 read 8 AI hex", "#05", 1 + 8 * 4 + 1),
    ("@02 read 16 DI", "@02", 6),
    ("@01 write 16 DO", "@01A55A", 2),
    ("@04DI read DI/DO", "@04DI", 9),
    ("#03 write AO", "#037FF", 2),
    ("$012 read config", "$012", 10),
]


def wire_time(command: str, reply_chars: int, baud: int) -> float:
    return (len(command) + 1 + reply_chars) * char_time(baud, BITS_PER_CHAR)


async def per_transaction(action, n: int) -> float:
    for _ in range(20):
        await action()
    started = time.perf_counter()
    for _ in range(n):
        await action()
    return (time.perf_counter() - started) / n


async def measure(port: str, n: int) -> tuple[dict[str, float], dict[str, float]]:
    """(DconLink with codec and reply checks, bare write + read-until-CR) per transaction."""
    serial = await AsyncSerial.open(port, 115200)
    link = DconLink(serial, False, 0.5)
    ours, bare = {}, {}
    try:
        for name, text, _ in TRANSACTIONS:
            check = (
                codec.write_ack
                if text[0] in "#@" and len(text) > 3 and not text.endswith("DI")
                else (lambda reply: reply)
            )
            ours[name] = await per_transaction(partial(_checked, link, text, check), n)
            raw = codec.frame(text, False)
            bare[name] = await per_transaction(partial(_bare, serial, raw), n)
    finally:
        await serial.close()
    return ours, bare


async def _checked(link: DconLink, text: str, check) -> None:
    check(await link.transact(text))


async def _bare(serial: AsyncSerial, raw: bytes) -> None:
    serial.reset_input()
    await serial.write(raw)
    await serial.read_until(b"\r", 0.5)


async def in_process(n: int):
    with PtyPair() as pair:
        sim = DconSimulator.from_modules(pair.b, LINE)
        await sim.start()
        try:
            return await measure(pair.a, n)
        finally:
            await sim.stop()


async def child_process(n: int):
    proc, port = await start_child_simulator(["--pty"])
    try:
        return await measure(port, n)
    finally:
        proc.kill()
        await proc.wait()


class Turnaround:
    """Times from a reply's CR arriving at the master's port to its next command write."""

    def __init__(self) -> None:
        self.samples: list[float] = []
        self._last_cr: float | None = None
        self._readable, self._write = AsyncSerial._readable, AsyncSerial.write

    def __enter__(self) -> Turnaround:
        probe = self

        def readable(port: AsyncSerial) -> None:
            before = len(port._buffer)
            probe._readable(port)
            if b"\r" in port._buffer[before:]:
                probe._last_cr = time.perf_counter()

        async def write(port: AsyncSerial, data: bytes) -> None:
            if probe._last_cr is not None:
                probe.samples.append(time.perf_counter() - probe._last_cr)
                probe._last_cr = None
            await probe._write(port, data)

        AsyncSerial._readable, AsyncSerial.write = readable, write
        return self

    def __exit__(self, *exc) -> None:
        AsyncSerial._readable, AsyncSerial.write = self._readable, self._write


def line_config(port: str, baud: int) -> DconBackConfig:
    modules = [{"address": a, "model": m} for a, m in LINE]
    return DconBackConfig(
        name="rs485",
        type="dcon",
        port=port,
        baudrate=baud,
        timeout_ms=500,
        poll_ms=0,
        modules=modules,
    )


async def start_child_simulator(port_args: list[str]):
    args = [sys.executable, "-m", "fieldgate", "simulate", "dcon", *port_args, "--duration", "120"]
    for address, model in LINE:
        args += ["--module", f"{address}:{model}"]
    proc = await asyncio.create_subprocess_exec(
        *args, stdout=asyncio.subprocess.PIPE, env={**os.environ, "PYTHONUNBUFFERED": "1"}
    )
    while True:
        line = (await asyncio.wait_for(proc.stdout.readline(), 20)).decode()
        if not line:
            raise RuntimeError("the simulator exited")
        if line.startswith("simulating back "):  # the banner: the gateway's end of a --pty pair
            match = re.search(r"point the gateway at (\S+)", line)
            return proc, match.group(1) if match else None


async def cycle_time(baud: int | None, cycles: int) -> tuple[float, float, list[float]]:
    """(seconds per poll cycle, transactions per cycle, master turnarounds) through DconBack +
    LineScheduler, the simulator in a child process serving the far end of a (paced) pty pair."""
    # paced: the tests' wire (tests/paced_wire.py), byte by byte in a process of its own as
    # a UART is other hardware (PtyPair relays whole chunks from threads of this process)
    with PacedWire(baud) if baud else PtyPair() as pair, Turnaround() as turnaround:
        proc, _ = await start_child_simulator(["--port", pair.b])
        cfg = line_config(pair.a, baud or 115200)
        topology = Topology(
            GatewaySection(name="bench"), [], [cfg], channel_specs=cfg.channel_specs()
        )
        back = DconBack(cfg, GatewayContext.build(topology))
        await back.start()
        task = asyncio.create_task(back.run())
        try:
            stats = back.scheduler.stats
            while stats.cycles < 3:
                await asyncio.sleep(0.001)
            first, transactions, started = stats.cycles, back.dcon.transactions, time.perf_counter()
            turnaround.samples.clear()
            while stats.cycles < first + cycles:
                await asyncio.sleep(0.001)
            elapsed = time.perf_counter() - started
            assert not any(stats.errors.values()), f"errors during the bench: {dict(stats.errors)}"
            done = stats.cycles - first
            return (
                elapsed / done,
                (back.dcon.transactions - transactions) / done,
                list(turnaround.samples),
            )
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await back.stop()
            proc.kill()
            await proc.wait()


def ms(seconds: float) -> str:
    return f"{seconds * 1000:8.3f} ms"


async def main() -> None:
    n = 400
    print(f"DCON back: software overhead per transaction (unpaced pty, {n} transactions each)\n")
    own, _ = await in_process(n)
    child, bare = await child_process(n)
    print(
        f"{'transaction':<20} {'in-process':>11} {'sim in child':>12} {'bare peer':>11} {'wire 9600':>11} {'wire 115200':>11} {'ratio@9600':>10} {'ratio@115200':>12}"
    )
    worst = 0.0
    for name, text, reply in TRANSACTIONS:
        wires = [wire_time(text, reply, b) for b in BAUDS]
        ratio = child[name] / wires[1]
        worst = max(worst, ratio)
        print(
            f"{name:<20} {ms(own[name])} {ms(child[name]):>12} {ms(bare[name])} {ms(wires[0])} {ms(wires[1])} {child[name] / wires[0]:9.2%} {ratio:11.1%}"
        )
    print(
        f"\nworst overhead / wire time at 115200 baud: {worst:.1%} (target < 10%) -> {'OK' if worst < 0.10 else 'MISSED'}"
    )
    mean_ours = sum(child.values()) / len(child)
    mean_bare = sum(bare.values()) / len(bare)
    print(
        f"codec and reply checks cost {ms(mean_ours - mean_bare)} a transaction over the bare peer ({mean_ours / mean_bare:.2f}x)\n"
    )

    print(
        "Poll cycle of the i7231d-style line (I-7043, I-7053, I-7021, I-7012, I-7017), DconBack + LineScheduler,"
    )
    print("simulator in a child process:")
    unpaced, per_cycle, _ = await cycle_time(None, 300)
    print(
        f"  unpaced pty (software only): {ms(unpaced)} a cycle of {per_cycle:.0f} transactions = {ms(unpaced / per_cycle)} each"
    )
    verdict = None
    for baud, cycles in ((115200, 100), (9600, 10)):
        paced, per_cycle, turns = await cycle_time(baud, cycles)
        wire = _cycle_wire(baud)
        per_transaction_wire = wire / per_cycle
        extra = (paced - wire) / per_cycle
        turn = statistics.median(turns)
        print(
            f"  pty paced at {baud:>6} baud: cycle {ms(paced)}, wire time {ms(wire)} ({per_cycle:.0f} transactions)"
        )
        print(
            f"      everything beyond the wire (bench included): {ms(extra)} a transaction = {extra / per_transaction_wire:.1%} of its mean wire time"
        )
        print(
            f"      master turnaround (reply CR in -> next command out), median of {len(turns)}: {ms(turn)}"
            f" = {turn / per_transaction_wire:.1%} of the mean wire time (95th percentile {ms(sorted(turns)[int(len(turns) * 0.95)])})"
        )
        if baud == 115200:
            verdict = turn / per_transaction_wire
    floor = sum(bare.values()) / len(bare)
    print(
        f"  (the bare peer above, {ms(floor)} a transaction, is the floor of the pty relay and the simulator themselves)"
    )
    print(
        f"\npoll-cycle overhead of the DCON back at 115200 baud: {verdict:.1%} of the wire time per transaction (target < 10%) -> {'OK' if verdict < 0.10 else 'MISSED'}"
    )


def _cycle_wire(baud: int) -> float:
    # one poll of each module: @01 (DO read-back), @02, ~03 0 (AO status), @04DI + #04, #05
    polls = [("@01", 6), ("@02", 6), ("~030", 6), ("@04DI", 9), ("#04", 9), ("#05", 34)]
    return sum(wire_time(text, reply, baud) for text, reply in polls)


if __name__ == "__main__":
    # on the loop `fieldgate run` uses (uvloop where installed; BENCH_LOOP=asyncio for the other)
    from fieldgate.cli import loop_factory  # noqa: E402

    with asyncio.Runner(loop_factory=loop_factory(os.environ.get("BENCH_LOOP", "auto"))) as runner:
        print(f"event loop: {type(runner.get_loop()).__module__.split('.')[0]}")
        runner.run(main())
