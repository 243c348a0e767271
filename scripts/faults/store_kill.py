#!/usr/bin/env python3
"""Store under power loss: SIGKILL a gateway process at random moments while it stores.

A child process builds the CANopen and DeviceNet fronts of a topology exactly as
``fieldgate run`` does (plugin ``build()``: the real stores, the real persist code) and
then, as an in-process master, drives their engines with frames in an endless loop:

* CANopen: SDO download of 0x1017 (heartbeat) and 0x100C (guard time), then 0x1010 sub 1
  "save" (written to ``<front>.canopen.json``);
* LSS: switch global to configuration, configure node-ID, store configuration
  (``<front>.lss.json``);
* DeviceNet: allocate the explicit connection, Set_Attribute_Single DeviceNet object MAC ID
  (``<front>.devicenet.json``), let the device restart and finish its duplicate MAC check.

After each confirmed answer (the SDO 0x60, the LSS store answer, the CIP 0x90) the child
reports the generation on a pipe. The parent kills the child with SIGKILL after a random
delay, then builds the fronts again from the state folder (what the next gateway start
does) and checks, per store: the file parses, the front loads it without a problem, and
the value it loads is the last confirmed one or the one being written, never a default
once something was confirmed. The state folder is kept across kills: every child starts
from what the previous one left.

The child is forked from the parent after the imports (a real process, killed with a real
SIGKILL; forking spares 1,000 interpreter starts).

    .venv/bin/python scripts/faults/store_kill.py --kills 1000 --seed 1
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import random
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fieldgate import Gateway, load_registry
from fieldgate.can.frame import Frame
from fieldgate.persist import CorruptStore, read_json, temp_files
from fieldgate.plugins.canopen.plugin import CanopenFront
from fieldgate.plugins.devicenet.plugin import DeviceNetFront

CO, DN = "plc", "dnet"
CO_NODE_ID, DN_MAC, MASTER_MAC = 5, 9, 0x0A
KINDS = ("co", "lss", "dn")
FILES = {"co": f"{CO}.canopen.json", "lss": f"{CO}.lss.json", "dn": f"{DN}.devicenet.json"}
DN_MACS = [m for m in range(64) if m not in (MASTER_MAC, DN_MAC)]  # never the default


def topology(state_dir: Path) -> dict[str, Any]:
    return {
        "gateway": {"name": "store-kill", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": CO,
                "type": "canopen",
                "interface": "virtual",
                "node_id": CO_NODE_ID,
                "heartbeat_ms": 0,  # 0x1017 is among the settings stored (icpdas: guarding only)
            },
            {
                "name": DN,
                "type": "devicenet",
                "interface": "virtual",
                "mac_id": DN_MAC,
                "dup_mac_timeout_ms": 50,
                "expose": ["rs485/*/di*"],  # inputs only: the CANopen front writes the outputs
            },
        ],
        # never started: the fronts need channels, the stores do not need a running back
        "backs": [
            {
                "name": "rs485",
                "type": "dcon",
                "port": "/dev/null",
                "modules": [{"address": 1, "model": "I-7055"}],
            }
        ],
    }


def value(kind: str, generation: int) -> int:
    """What generation ``generation`` stores for ``kind`` (consecutive generations differ)."""
    if kind == "co":
        return generation % 60000 + 1  # 0x1017 heartbeat ms (0 is the default)
    if kind == "lss":
        return generation % 126 + 1 if generation % 126 + 1 != CO_NODE_ID else 127
    return DN_MACS[generation % len(DN_MACS)]


@dataclass
class Loaded:
    values: dict[str, int | None]
    problems: list[str] = field(default_factory=list)


def build(state_dir: Path) -> tuple[Any, Any]:
    """The CANopen node and DeviceNet slave as a gateway start builds them (stores loaded)."""
    gateway = Gateway.load(topology(state_dir), registry=load_registry())
    fronts = gateway.topology.fronts
    node = CanopenFront(fronts[0], gateway.context).build()
    slave = DeviceNetFront(fronts[1], gateway.context).build()
    return node, slave


def load(state_dir: Path) -> Loaded:
    """What the next start loads, with every sign of a corrupt or ignored file."""
    problems = []
    for kind, name in FILES.items():
        try:
            read_json(state_dir / name)
        except CorruptStore as exc:
            problems.append(f"{kind}: corrupt file: {exc}")
    node, slave = build(state_dir)
    store = node.service("store")
    if store.problem is not None:
        problems.append(f"co: store problem {store.problem[0]:04X}")
    node.boot(0.0)
    stored_hb = node.od.get(0x1017)
    if node.od.get(0x100C) != stored_hb:
        problems.append(f"co: 0x100C {node.od.get(0x100C)} != 0x1017 {stored_hb} (mixed save)")
    return Loaded(
        {
            "co": stored_hb or None,
            "lss": None if node.node_id == CO_NODE_ID else node.node_id,
            "dn": None if slave.mac_id == DN_MAC else slave.mac_id,
        },
        problems,
    )


# -- the child: an in-process master storing in a loop ----------------------------------------
class Driver:
    def __init__(self, state_dir: Path, report: int):
        self.node, self.slave = build(state_dir)
        self.report = report
        self.now = 0.0
        self.node.boot(self.now)
        self.slave.boot(self.now)
        self.dn_mac = self.slave.mac_id
        self._settle_devicenet()

    def _tell(self, kind: str, generation: int) -> None:
        os.write(self.report, f"{kind} {generation}\n".encode())

    def _co(self, data: str) -> bytes:
        out = self.node.receive(Frame(0x600 + self.node.node_id, bytes.fromhex(data)), self.now)
        (answer,) = out
        if answer.data[0] != 0x60:
            raise RuntimeError(f"SDO {data}: {answer.data.hex()}")
        answered: bytes = answer.data
        return answered

    def _lss(self, data: str) -> list[Frame]:
        out: list[Frame] = self.node.receive(
            Frame(0x7E5, bytes.fromhex(data).ljust(8, b"\0")), self.now
        )
        return out

    def _dn(self, message: int, data: bytes) -> list[Frame]:
        can_id = 0x400 | self.dn_mac << 3 | message
        out: list[Frame] = self.slave.receive(Frame(can_id, data), self.now)
        return out

    def _settle_devicenet(self) -> None:
        """Run the slave's clock until its duplicate MAC check is over."""
        for _ in range(100):
            self.now += 0.05
            self.slave.tick(self.now)
            if self.slave.state == "online":
                return
        raise RuntimeError(f"DeviceNet slave stuck in {self.slave.state}")

    def store(self, generation: int) -> None:
        hb = value("co", generation).to_bytes(2, "little").hex()
        self._co(f"2B 17 10 00 {hb} 00 00")
        self._co(f"2B 0C 10 00 {hb} 00 00")
        self._co("23 10 10 01 73 61 76 65")  # "save"
        self._tell("co", generation)

        self._lss("04 01")
        (configured,) = self._lss(f"11 {value('lss', generation):02X}")
        (stored,) = self._lss("17")
        if configured.data[1] or stored.data[1]:
            raise RuntimeError(f"LSS refused: {configured.data.hex()} {stored.data.hex()}")
        self._lss("04 00")
        self._tell("lss", generation)

        self._dn(6, bytes([MASTER_MAC, 0x4B, 0x03, 0x01, 0x01, MASTER_MAC]))
        mac = value("dn", generation)
        answers = self._dn(4, bytes([MASTER_MAC, 0x10, 0x03, 0x01, 0x01, mac]))
        if not answers or answers[0].data[1] != 0x90:
            raise RuntimeError(f"DeviceNet Set MAC refused: {[a.data.hex() for a in answers]}")
        self._tell("dn", generation)
        self.now += 0.01
        self.slave.tick(self.now)  # the restart: shutdown, then the check at the new MAC
        self.dn_mac = mac
        self._settle_devicenet()


def child(state_dir: Path, first_generation: int, report: int) -> None:
    logging.disable(logging.CRITICAL)
    driver = Driver(state_dir, report)
    os.write(report, b"ready\n")
    generation = first_generation
    while True:
        driver.store(generation)
        generation += 1


# -- the parent ---------------------------------------------------------------------------------
@dataclass
class Result:
    kills: int = 0
    stores_confirmed: int = 0
    kills_mid_write: int = 0  # a temporary file was left: the kill fell between create and rename
    loaded_new: int = 0  # a store loaded the value that was being written when the kill came
    failures: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {**self.__dict__, "failures": self.failures[:20]}


def campaign(
    kills: int, seed: int, state_dir: Path, max_delay: float = 0.2, progress: bool = False
) -> Result:
    rng = random.Random(seed)
    result = Result()
    committed: dict[str, int | None] = {k: None for k in KINDS}
    generation = 1
    started = time.monotonic()
    for n in range(kills):
        try:
            confirmed = _one_run(state_dir, generation, rng.uniform(0.0, max_delay))
        except ChildFailed as exc:
            result.failures.append(f"kill {n}: {exc}")
            break
        if confirmed is None:
            result.failures.append(f"kill {n}: the child died before it was ready")
            break
        result.kills += 1
        pending = {k: value(k, confirmed[k] + 1 if k in confirmed else generation) for k in KINDS}
        for k, g in confirmed.items():
            committed[k] = value(k, g)
            result.stores_confirmed += g - generation + 1
        result.kills_mid_write += any(temp_files(state_dir / f) for f in FILES.values())
        loaded = load(state_dir)
        result.failures += [f"kill {n}: {p}" for p in loaded.problems]
        for k in KINDS:
            got = loaded.values[k]
            if got == committed[k]:
                continue
            if got == pending[k]:
                result.loaded_new += 1
                committed[k] = got
                continue
            result.failures.append(
                f"kill {n}: {k} loaded {got}, expected {committed[k]} (old) or {pending[k]} (new)"
            )
        generation = max([generation, *confirmed.values()]) + 2
        if progress and (n + 1) % 50 == 0:
            print(
                f"{n + 1}/{kills} kills, {result.kills_mid_write} mid-write, "
                f"{len(result.failures)} failures, {time.monotonic() - started:.0f} s",
                file=sys.stderr,
                flush=True,
            )
    result.seconds = round(time.monotonic() - started, 1)
    return result


def _one_run(state_dir: Path, generation: int, delay: float) -> dict[str, int] | None:
    """Fork a child storing from ``generation`` on, SIGKILL it ``delay`` s after it is ready;
    returns the last confirmed generation per kind (None if it never got ready)."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child never returns into the caller's code (pytest, the CLI)
        os.close(read_end)
        try:
            child(state_dir, generation, write_end)
        except BaseException as exc:
            os.write(write_end, f"\nerror {type(exc).__name__}: {exc}\n".encode())
        finally:
            os._exit(3)
    os.close(write_end)
    buffer = b""
    while b"\n" not in buffer:
        chunk = os.read(read_end, 4096)
        if not chunk:
            os.waitpid(pid, 0)
            os.close(read_end)
            return None
        buffer += chunk
    time.sleep(delay)  # the random moment of the power cut
    os.kill(pid, signal.SIGKILL)
    _, status = os.waitpid(pid, 0)
    while chunk := os.read(read_end, 65536):
        buffer += chunk
    os.close(read_end)
    lines = buffer.decode().splitlines()
    if not (os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL):
        raise ChildFailed(f"the child ended on its own (status {status}): {lines[-1]}")
    confirmed: dict[str, int] = {}
    for line in lines[1:]:
        kind, _, number = line.partition(" ")
        confirmed[kind] = int(number)
    return confirmed


class ChildFailed(Exception):
    """The storing child stopped before the kill (it found its own stored state unusable)."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--max-delay", type=float, default=0.2, help="seconds (uniform 0..max)")
    parser.add_argument("--state-dir", type=Path, help="default: a new temporary folder")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="store-kill-") as tmp:
        state_dir = args.state_dir or Path(tmp)
        result = campaign(args.kills, args.seed, state_dir, args.max_delay, progress=True)
    print(json.dumps(result.as_dict(), indent=1))
    return 0 if not result.failures and result.kills == args.kills else 1


if __name__ == "__main__":
    sys.exit(main())
