#!/usr/bin/env python3
"""Serial port faults on a running gateway: the port is pulled and plugged back, returns
garbage, or echoes what the back sends (a 2-wire RS-485 adapter that hears itself).

A real gateway (``Gateway.start``: CANopen front on python-can's virtual bus, DeviceNet
front, one Modbus or DCON back) polls the back's simulator over pseudo-terminals. The
back's port is a symlink (:class:`fieldgate.serial_link.PluggablePty`), the way
``/dev/serial/by-id/...`` names a USB adapter: "unplug" removes the link and hangs up the
pty (the open port reads EIO), "plug" makes a new pty under the same path.

Per fault and cycle it measures: detection (fault to every module offline), the EMCY
``00 FF 81 0B <address>`` per module on the CAN bus, the DeviceNet module-fault bit, and
recovery (fault removed to every module online with GOOD inputs), with no component
restart. Figures go to docs/reliability.md.

    .venv/bin/python scripts/faults/port_faults.py --cycles 20
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import random
import statistics
import sys
import tempfile
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from fieldgate import Gateway, Quality, load_registry
from fieldgate.plugin import Registry
from fieldgate.serial_link import PluggablePty

NODE_ID = 5
ECHO_S = 1.5  # how long an echo must last before a line that still serves is accepted as such
FAULTS = ("unplug", "garbage", "echo")
BACKS: dict[str, dict[str, Any]] = {
    "modbus": {
        "type": "modbus",
        "modules": [
            {"address": 1, "model": "M-7052D"},
            {"address": 3, "model": "M-7055D"},
            {"address": 5, "model": "M-7017R", "counts": {"ai": 2}},
        ],
    },
    "dcon": {
        "type": "dcon",
        "modules": [
            {"address": 1, "model": "I-7052"},
            {"address": 2, "model": "I-7017"},
            {"address": 7, "model": "I-7055"},
        ],
    },
}


def topology(
    back: str, port: str, state_dir: Path, co_channel: str, dn_channel: str
) -> dict[str, Any]:
    return {
        "gateway": {"name": f"port-faults-{back}", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "plc",
                "type": "canopen",
                "interface": "virtual",
                "channel": co_channel,
                "node_id": NODE_ID,
            },
            {
                "name": "dnet",
                "type": "devicenet",
                "interface": "virtual",
                "channel": dn_channel,
                "mac_id": 9,
                # inputs only: the CANopen front writes the outputs (one writing front each)
                "expose": ["rs485/*/di*", "rs485/*/ai*"],
            },
        ],
        "backs": [
            {
                "name": "rs485",
                "port": port,
                "baudrate": 115200,
                "poll_ms": 20,
                "timeout_ms": 60,
                "offline_probe_ms": 1000,
                **BACKS[back],
            }
        ],
    }


@dataclass
class Cycle:
    fault: str
    detect_s: float | None  # None: the line kept serving through the fault (went not offline)
    recover_s: float
    failures_counted: dict[int, int]  # per module, during the fault
    emcy_modules: list[int]  # module addresses with an EMCY FF81 on the bus
    devicenet_fault_seen: bool
    devicenet_fault_cleared: bool
    port_losses: int


@dataclass
class Rig:
    gateway: Gateway
    pty: PluggablePty
    bus: can.BusABC
    simulator: Any
    addresses: list[int]
    emcy: list[bytes] = field(default_factory=list)

    @property
    def health(self) -> list[Any]:
        return [self.gateway.health.get("rs485", a) for a in self.addresses]

    def inputs_good(self) -> bool:
        return all(
            c.quality is Quality.GOOD
            for c in self.gateway.image.channels(back="rs485")
            if not c.spec.kind.is_output
        )

    def drain_emcy(self) -> None:
        while (msg := self.bus.recv(0)) is not None:
            if msg.arbitration_id == 0x80 + NODE_ID:
                self.emcy.append(bytes(msg.data))


async def wait_until(condition: Callable[[], bool], timeout: float, what: str) -> float:
    """Seconds until ``condition`` held (polled every 5 ms); AssertionError after ``timeout``."""
    loop = asyncio.get_running_loop()
    start = loop.time()
    while not condition():
        if loop.time() - start > timeout:
            raise AssertionError(f"not within {timeout} s: {what}")
        await asyncio.sleep(0.005)
    return loop.time() - start


async def start_rig(back: str, work_dir: Path, registry: Registry) -> Rig:
    co, dn = f"pf-co-{uuid.uuid4().hex[:8]}", f"pf-dn-{uuid.uuid4().hex[:8]}"
    pty = PluggablePty(work_dir / "ttyUSB0")
    gateway = Gateway.load(topology(back, pty.a, work_dir, co, dn), registry=registry)
    back_cfg = gateway.topology.backs[0]
    simulator = registry.simulators[back_cfg.type](back_cfg, pty.b, False)
    await simulator.start()
    bus = can.Bus(interface="virtual", channel=co, receive_own_messages=False)
    await gateway.start()
    rig = Rig(gateway, pty, bus, simulator, [m.address for m in back_cfg.modules])
    await wait_until(lambda: all(h.online for h in rig.health) and rig.inputs_good(), 10, "start")
    return rig


async def stop_rig(rig: Rig) -> None:
    await rig.gateway.stop()
    await rig.simulator.stop()
    rig.bus.shutdown()
    rig.pty.close()


def _inject(rig: Rig, fault: str, rng: random.Random) -> Callable[[], None]:
    """Start ``fault``; returns what ends it."""
    if fault == "unplug":
        rig.pty.unplug()
        plug: Callable[[], None] = rig.pty.plug
        return plug
    if fault == "garbage":
        rig.pty.fault = lambda data: bytes(rng.randrange(256) for _ in data)

        def clean() -> None:
            rig.pty.fault = None

        return clean
    rig.pty.echo = True

    def quiet() -> None:
        rig.pty.echo = False

    return quiet


async def cycle(rig: Rig, fault: str, rng: random.Random, outage_s: float = 0.3) -> Cycle:
    dnet = rig.gateway.component("dnet")
    rig.drain_emcy()
    rig.emcy.clear()
    errors_before = {h.address: sum(h.errors.values()) for h in rig.health}
    losses_before = rig.gateway.component("rs485").status()["port"]["losses"]
    end_fault = _inject(rig, fault, rng)
    try:
        detect: float | None = await wait_until(
            lambda: not any(h.online for h in rig.health),
            ECHO_S if fault == "echo" else 15,
            f"{fault}: offline",
        )
    except AssertionError:
        if fault != "echo":
            raise
        detect = None  # echo: auto: the link drops the echo and reads the reply behind it
    devicenet_fault_seen = bool(dnet.slave.module_fault)
    await asyncio.sleep(outage_s)  # the port stays away / keeps failing a while
    failures = {h.address: sum(h.errors.values()) - errors_before[h.address] for h in rig.health}
    end_fault()
    recover = await wait_until(
        lambda: all(h.online for h in rig.health) and rig.inputs_good(), 30, f"{fault}: recovery"
    )
    rig.drain_emcy()
    return Cycle(
        fault=fault,
        detect_s=None if detect is None else round(detect, 3),
        recover_s=round(recover, 3),
        failures_counted=failures,
        emcy_modules=sorted({d[4] for d in rig.emcy if d[:4] == bytes.fromhex("00 FF 81 0B")}),
        devicenet_fault_seen=devicenet_fault_seen,
        devicenet_fault_cleared=not dnet.slave.module_fault,
        port_losses=rig.gateway.component("rs485").status()["port"]["losses"] - losses_before,
    )


async def campaign(
    back: str, faults: list[str], cycles: int, seed: int, registry: Registry | None = None
) -> dict[str, Any]:
    registry = registry or load_registry()
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory(prefix="port-faults-") as tmp:
        rig = await start_rig(back, Path(tmp), registry)
        try:
            results = [await cycle(rig, fault, rng) for _ in range(cycles) for fault in faults]
            restarts = rig.gateway.status()["backs"]["rs485"]["restarts"]
        finally:
            await stop_rig(rig)
    return {"back": back, "cycles": [r.__dict__ for r in results], "restarts": restarts}


def summary(report: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {"back": report["back"], "restarts": report["restarts"]}
    for fault in FAULTS:
        rows = [c for c in report["cycles"] if c["fault"] == fault]
        if not rows:
            continue
        detect = [c["detect_s"] for c in rows if c["detect_s"] is not None]
        recover = [c["recover_s"] for c in rows]
        out[fault] = {
            "cycles": len(rows),
            "went_offline": len(detect),
            "detect_s_median": round(statistics.median(detect), 3) if detect else None,
            "detect_s_max": max(detect, default=None),
            "recover_s_median": round(statistics.median(recover), 3),
            "recover_s_max": max(recover),
            "failures_per_module_max": max(max(c["failures_counted"].values()) for c in rows),
            "all_modules_emcy": all(
                len(c["emcy_modules"]) == 3 for c in rows if c["detect_s"] is not None
            ),
            "devicenet_fault_bit": all(
                c["devicenet_fault_seen"] and c["devicenet_fault_cleared"]
                for c in rows
                if c["detect_s"] is not None
            ),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--back", choices=[*BACKS, "both"], default="both")
    parser.add_argument("--fault", choices=[*FAULTS, "all"], default="all")
    parser.add_argument("--cycles", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    backs = list(BACKS) if args.back == "both" else [args.back]
    faults = list(FAULTS) if args.fault == "all" else [args.fault]
    for back in backs:
        report = asyncio.run(campaign(back, faults, args.cycles, args.seed))
        print(json.dumps(summary(report), indent=1), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
