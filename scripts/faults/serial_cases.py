"""The serial cases of the bug report as a probe, on pseudo-terminals paced byte by byte at
the baud rate (tests/paced_wire.py, the tests' own pacer): figures per case.

Run:  .venv/bin/python scripts/faults/serial_cases.py [--seconds 10]   (about 40 s)

1. **long reply**: Modbus at 9600 baud, ``timeout_ms: 200``, one module answering 125
   registers (255 bytes, 266 ms on the wire) and an M-7052D, polled as fast as the line
   goes: polls, failures, offline events, the measured round trip of the long read;
2. **echo**: the same line with an adapter that echoes every byte back (``echo: auto``),
   FC6 writes to a module that exists and to one that does not: writes acknowledged,
   writes to the dead module (must fail: its echo is not an answer), failures;
3. **DCON watchdog clear**: an I-7060 with a 300 ms host watchdog, the master lost
   (``~**`` paused) until the module times out, then the master back and the clear
   requested in the same moment: the flag after the next poll and 2 s later, ``~**``
   sent before ``~AA1``.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))  # the tests' pacer: independent of the code under test

from paced_wire import PacedWire, SimulatorProcess  # noqa: E402

from fieldgate import Gateway, load_registry  # noqa: E402
from fieldgate.plugins.modbus.client import ModbusLink  # noqa: E402
from fieldgate.polling import CommError  # noqa: E402

BIG = {
    "address": 1,
    "channels": [{"kind": "ai", "table": "input_registers", "address": 0, "count": 125}],
}
SMALL = {"address": 2, "model": "M-7052D"}


def modbus_topology(port: str, modules: list[dict] | None = None) -> dict:
    return {
        "gateway": {"name": "probe"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": port,
                "baudrate": 9600,
                "timeout_ms": 200,
                "poll_ms": 0,
                "modules": modules or [BIG, SMALL],
            }
        ],
    }


async def long_reply(seconds: float) -> bool:
    registry = load_registry()
    with (
        tempfile.TemporaryDirectory() as folder,
        PacedWire(9600) as wire,
        SimulatorProcess.modbus(modbus_topology(wire.b), wire.b, folder),
    ):
        gateway = Gateway.load(modbus_topology(wire.a), registry=registry)
        offline = []
        gateway.context.events.subscribe(
            lambda e: offline.append(e) if "offline" in str(e.kind) else None
        )
        await gateway.start()
        try:
            await asyncio.sleep(seconds)
            big, small = gateway.health.get("rs485", 1), gateway.health.get("rs485", 2)
            rtt = big.last_rtt or 0.0
            print(
                f"  long reply: {seconds:.0f} s at 9600 baud, timeout_ms 200: module 1 (255-byte "
                f"reply) {big.requests} polls, {big.error_counter} failures, round trip "
                f"{rtt * 1000:.0f} ms; module 2 {small.requests} polls, {small.error_counter} "
                f"failures; offline events {len(offline)}; both online: {big.online and small.online}"
            )
            return big.error_counter == small.error_counter == 0 and big.online and small.online
        finally:
            await gateway.stop()


async def echo(writes: int) -> bool:
    modules = [SMALL, {"address": 4, "model": "M-7024"}]
    with (
        tempfile.TemporaryDirectory() as folder,
        PacedWire(9600, echo=True) as wire,
        SimulatorProcess.modbus(modbus_topology(wire.b, modules), wire.b, folder),
    ):
        link = ModbusLink(wire.a, baudrate=9600, timeout=0.2, echo="auto")
        await link.open()
        acked = dead_failed = 0
        started = time.monotonic()
        try:
            await link.read_bits(2, 2, 32, 8)  # auto decides here
            for i in range(writes):
                await link.write(4, 6, 0, [i])
                acked += await link.read_registers(4, 3, 0, 1) == [i]
                try:
                    await link.write(9, 6, 0, [i])  # nobody at 9: only the echo comes back
                except CommError:
                    dead_failed += 1
        finally:
            link.close()
        print(
            f"  echo: adapter echoes every byte, echo: auto -> {link.echo.describe()}; "
            f"{acked}/{writes} FC6 writes acknowledged and read back, {dead_failed}/{writes} "
            f"writes to a missing module failed (the echo was not taken for its answer); "
            f"{time.monotonic() - started:.1f} s"
        )
        return acked == writes and dead_failed == writes


async def watchdog_clear() -> bool:
    registry = load_registry()
    topology = {
        "gateway": {"name": "probe-wd"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "rs485",
                "type": "dcon",
                "port": "simulated",
                "timeout_ms": 150,
                "poll_ms": 10,
                "modules": [
                    {
                        "address": 1,
                        "model": "I-7060",
                        "watchdog": {"enabled": True, "timeout_ms": 300},
                    }
                ],
            }
        ],
    }
    gateway = Gateway.load(topology, registry=registry, simulate=True)
    await gateway.start()
    try:
        sim, back = gateway.bench.simulator("rs485"), gateway.component("rs485")
        while not sim.module(1).watchdog_enabled:
            await asyncio.sleep(0.01)
        gateway.context.masters.lost("plc", "probe")
        lost_at = time.monotonic()
        while not back.watchdog_status(1):
            await asyncio.sleep(0.01)
        seen = time.monotonic() - lost_at
        gateway.context.masters.ok("plc")
        sent_before = back.host_ok_sent
        started = time.monotonic()
        await asyncio.wait_for(back.request_clear_watchdog(1), 3)
        cleared = time.monotonic() - started
        after_poll = back.watchdog_status(1)
        await asyncio.sleep(2.0)
        later = back.watchdog_status(1) or sim.module(1).timed_out
        status = next(m for m in back.status()["dcon_modules"] if m["address"] == 1)
        print(
            f"  DCON watchdog clear: timeout seen {seen * 1000:.0f} ms after the master loss; "
            f"clear (with ~** first: {back.host_ok_sent > sent_before}) done in "
            f"{cleared * 1000:.0f} ms; flag at the next poll {int(after_poll)}, 2 s later "
            f"{int(later)}; status '{status['watchdog']['last_clear']}'"
        )
        return not after_poll and not later
    finally:
        await gateway.stop()


async def main(seconds: float) -> int:
    print("serial cases on pseudo-terminals paced byte by byte (tests/paced_wire.py)")
    results = [await long_reply(seconds), await echo(20), await watchdog_clear()]
    print("verdict:", "PASS" if all(results) else "FAIL")
    return 0 if all(results) else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="long-reply run (default 10)")
    sys.exit(asyncio.run(main(parser.parse_args().seconds)))
