"""CPU per SYNC cycle and per Modbus poll reply: this tree against the code before the batched write.

Run:  .venv/bin/python bench/cycle_cost.py                  (about 2 min; --quick: about 15 s)
      .venv/bin/python bench/cycle_cost.py --loop asyncio   (asyncio's loop instead of uvloop)
      .venv/bin/python bench/cycle_cost.py --profile sync|poll [--profile-baseline]   (cProfile)

Two scenarios, each a real gateway's components (``load_topology``, ``GatewayContext``,
the registry's factories, ``start()``, as ``Gateway.start`` does without its supervision
tasks), driven in process on the event loop ``fieldgate run`` uses (``--loop``):

* **SYNC cycle** (issue 13's 1 kHz phase, bench/can_load.py): a ``canopen`` front
  (node-ID 5, python-can ``virtual`` bus) and the ``loopback`` test back (8 DO wired to
  8 DI). RPDO1 (0x6200:1, 8 DO bits) is set synchronous; one cycle is the RPDO frame and
  the SYNC frame handed to the node as the adapter hands them (``node.receive``): at the
  SYNC the 8 outputs are applied, the back echoes them to the 8 inputs, and the
  event-driven TPDO1 (0x6000:1) carries them out in the same call. Each cycle writes the
  complement of the last value, so all 8 bits change; the bench checks TPDO1 carries it.
* **Modbus poll reply, 16 DI**: a ``modbus`` back with one module of 16 discrete inputs
  and the same ``canopen`` front, Operational, serving them in TPDO1 (2 bytes). The
  serial link is replaced by one that returns the reply's 16 bits (the wire, the pty and
  pymodbus' framing are not in the figure: this work does not change them;
  bench/modbus_overhead.py measures them), and the line scheduler's clock moves one poll
  period per reply so the module is due at every step. One reply is core's
  ``LineScheduler.step()`` polling the module (accounting, the module's decoding, the
  image update, health) and everything until the front has handed TPDO1 to the bus (its
  wake-up in the next loop turn, or a timer of the adapter's). Each reply inverts all
  16 bits; the bench checks the image holds the reply and one TPDO1 leaves per reply.

**Today's code path, same run.** ``--baseline REV`` (default :data:`BEFORE_BATCH`, the
main commit this work started from, the last with per-channel image writes) is
extracted with ``git archive`` into a temporary directory. The same scenario code (this
file) runs in two worker processes: one imports ``fieldgate`` (``core/``, ``plugins/``,
``conformance/``) and the ``loopback`` test plugin from this checkout, the other from the
extracted tree (an import finder placed ahead of the editable install's: the equivalent of
PYTHONPATH for this package layout; each worker checks and prints where its modules came
from). Both workers are pinned to one CPU (``--cpu``). The parent alternates them
repetition by repetition (A B, B A, ...), so the machine's load falls on both; each
repetition is ``--cycles`` cycles timed with ``time.process_time()`` (the worker's CPU,
user + system, all threads), after a warm-up. Printed: the median and range per side, the
ratio of the medians (baseline / this tree: above 1, this tree is cheaper) with its range
over the repetition pairs, and whether it reaches ``--target`` (exit status 1 if not).
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.abc
import importlib.machinery
import importlib.util
import io
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
BEFORE_BATCH = "6f66c95951dff4807ff980ce4828d04be402d3ed"  # main before the batched image write
NODE = 5
SCENARIOS = ("sync", "poll")


# -- worker side: import fieldgate from a given tree --------------------------------------
class _TreeFinder(importlib.abc.MetaPathFinder):
    """Maps the package roots of pyproject.toml's ``package-dir`` to one source tree."""

    def __init__(self, root: Path):
        self.roots = {
            "fieldgate": root / "core",
            "fieldgate.plugins": root / "plugins",
            "fieldgate.conformance": root / "conformance",
            "fieldgate_loopback": root / "tests" / "plugin_pkg" / "fieldgate_loopback",
        }

    def find_spec(
        self, fullname: str, path: Any = None, target: Any = None
    ) -> importlib.machinery.ModuleSpec | None:
        folder = self.roots.get(fullname)
        if folder is None:
            return None
        return importlib.util.spec_from_file_location(
            fullname, folder / "__init__.py", submodule_search_locations=[str(folder)]
        )


def _use_tree(root: Path) -> None:
    sys.meta_path.insert(0, _TreeFinder(root))


async def _start(topology: dict[str, Any], clock: Callable[[], float] | None = None) -> Any:
    """Build and start every component as ``Gateway.start`` does, without supervision tasks
    (nothing runs behind the bench's back)."""
    from fieldgate.plugin import GatewayContext, load_registry
    from fieldgate.topology import load_topology

    registry = load_registry()
    topo = load_topology(topology, registry)
    context = GatewayContext.build(topo, clock)
    components: dict[str, Any] = {}
    for cfg in topo.backs:
        comp = registry.lookup("back", cfg.type).factory(cfg, context)  # type: ignore[union-attr]
        context.backs[cfg.name] = comp
        components[cfg.name] = comp
    for cfg in topo.fronts:
        context.masters.register(cfg.name)
        components[cfg.name] = registry.lookup("front", cfg.type).factory(cfg, context)  # type: ignore[union-attr]
    for comp in components.values():
        await comp.start()
    return context, components


def _front(channel: str) -> dict[str, Any]:
    return {
        "name": "can",
        "type": "canopen",
        "interface": "virtual",
        "channel": channel,
        "node_id": NODE,
    }


class SyncScenario:
    """RPDO1 (8 DO, synchronous) + SYNC -> outputs applied, looped back, TPDO1 out."""

    def __init__(self) -> None:
        self.components: dict[str, Any] = {}
        self.value = 0x55

    async def setup(self, state_dir: str) -> None:
        from fieldgate.can.frame import Frame

        self.Frame = Frame
        topology = {
            "gateway": {"name": "cycle-cost", "state_dir": state_dir},
            "fronts": [_front(f"cycle-cost-sync-{os.getpid()}")],
            "backs": [
                {"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}
            ],
        }
        self.context, self.components = await _start(topology)
        self.node = node = self.components["can"].node
        now = time.monotonic()
        answer = node.receive(Frame(0x600 + NODE, bytes([0x2F, 0, 0x14, 2, 1, 0, 0, 0])), now)
        assert answer and answer[0].data[0] == 0x60, answer  # 0x1400:2 = 1: RPDO1 synchronous
        node.receive(Frame(0x000, bytes([0x01, NODE])), now)  # Operational
        node.flush()
        self.rpdo, self.sync = 0x200 + NODE, Frame(0x080, b"")
        self.tpdo = 0x180 + NODE
        self.run(4)  # warm up; checks the loop

    def run(self, cycles: int) -> None:
        node, Frame, rpdo, sync, tpdo = self.node, self.Frame, self.rpdo, self.sync, self.tpdo
        clock = time.monotonic
        value = self.value
        for _ in range(cycles):
            value ^= 0xFF
            node.receive(Frame(rpdo, bytes([value])), clock())
            out = node.receive(sync, clock()) + node.flush()
            if not out or out[-1].can_id != tpdo or out[-1].data[0] != value:
                raise AssertionError(f"TPDO1 did not follow RPDO1 {value:02X}: {out}")
        self.value = value

    async def close(self) -> None:
        for comp in reversed(list(self.components.values())):
            await comp.stop()


class _ReplyLink:
    """The serial line replaced by the module's reply: 16 discrete inputs, inverted per read."""

    def __init__(self) -> None:
        self.bits = [bool(i & 1) for i in range(16)]

    async def read_bits(self, unit: int, function: int, address: int, count: int) -> list[bool]:
        self.bits = [not b for b in self.bits]
        return self.bits[:count]

    def close(self) -> None:
        pass


class LineClock:
    """The line scheduler's clock: moved one poll period per reply, so the module is due at
    every step without waiting (the rest of the gateway keeps the real clock)."""

    def __init__(self) -> None:
        self.t = time.monotonic()

    def __call__(self) -> float:
        return self.t


class PollScenario:
    """One Modbus reply of 16 DI through the line scheduler, the image and the CANopen front."""

    POLL_S = 0.02

    def __init__(self) -> None:
        self.components: dict[str, Any] = {}

    async def setup(self, state_dir: str) -> None:
        from fieldgate.can.frame import Frame
        from fieldgate.plugins.modbus.back import ModbusBack

        self.link = link = _ReplyLink()

        async def open_link(back: Any) -> _ReplyLink:
            return link

        async def close_link(back: Any) -> None:
            pass

        ModbusBack.open_link = open_link  # type: ignore[method-assign]
        ModbusBack.close_link = close_link  # type: ignore[method-assign]
        topology = {
            "gateway": {"name": "cycle-cost", "state_dir": state_dir},
            "fronts": [_front(f"cycle-cost-poll-{os.getpid()}")],
            "backs": [
                {
                    "name": "rs485",
                    "type": "modbus",
                    "port": "/dev/null",
                    "poll_ms": int(self.POLL_S * 1000),
                    "modules": [
                        {
                            "address": 1,
                            "channels": [
                                {
                                    "kind": "di",
                                    "table": "discrete_inputs",
                                    "address": 0,
                                    "count": 16,
                                }
                            ],
                        }
                    ],
                }
            ],
        }
        self.context, self.components = await _start(topology)
        front = self.components["can"]
        self.node = node = front.node
        self.adapter = front.adapter
        self.scheduler = self.components["rs485"].scheduler
        self.clock = self.scheduler.clock = LineClock()
        self.tpdo_sent = asyncio.Event()
        bus, send = self.adapter.bus, self.adapter.bus.send

        def sending(msg: Any, timeout: float | None = None) -> None:
            send(msg, timeout)
            if msg.arbitration_id == 0x180 + NODE:
                self.tpdo_sent.set()

        bus.send = sending
        node.receive(Frame(0x000, bytes([0x01, NODE])), self.adapter.now)  # Operational
        node.flush()
        await self.run(4)

    async def run(self, replies: int) -> None:
        scheduler, clock, sent = self.scheduler, self.clock, self.tpdo_sent
        for _ in range(replies):
            clock.t += self.POLL_S
            deadline = await scheduler.step()
            if deadline is not None:
                raise AssertionError("the module was not polled")
            await asyncio.sleep(0)  # the loop turn in which the front's wake-up sends TPDO1
            if not sent.is_set():  # not yet: the adapter sends it from a timer
                async with asyncio.timeout(2.0):
                    await sent.wait()
            sent.clear()
        expected = sum(1 << i for i, b in enumerate(self.link.bits) if b)
        value = self.node.service("io").profile.read_di(0) | (
            self.node.service("io").profile.read_di(1) << 8
        )
        if value != expected:
            raise AssertionError(f"the image holds {value:04X}, the reply was {expected:04X}")

    async def close(self) -> None:
        for comp in reversed(list(self.components.values())):
            await comp.stop()


def _worker(root: Path, loop: str) -> None:
    """Serve 'SCENARIO CYCLES' lines on stdin with one JSON line each: the CPU seconds."""
    _use_tree(root)
    import fieldgate.image
    import fieldgate_loopback  # type: ignore[import-not-found]

    origin = Path(fieldgate.image.__file__).resolve()
    for module in (fieldgate.image, fieldgate_loopback):
        if not Path(module.__file__).resolve().is_relative_to(root.resolve()):
            raise SystemExit(f"{module.__name__} came from {module.__file__}, not from {root}")

    async def serve() -> None:
        with tempfile.TemporaryDirectory() as state:
            scenarios: dict[str, Any] = {"sync": SyncScenario(), "poll": PollScenario()}
            for name, scenario in scenarios.items():
                await scenario.setup(os.path.join(state, name))
            print(json.dumps({"ready": str(origin)}), flush=True)
            for line in sys.stdin:
                name, count = line.split()
                scenario = scenarios[name]
                started = time.process_time()
                if name == "sync":
                    scenario.run(int(count))
                else:
                    await scenario.run(int(count))
                spent = time.process_time() - started
                print(json.dumps({"cpu": spent}), flush=True)
            for scenario in scenarios.values():
                await scenario.close()

    from fieldgate.cli import loop_factory

    with asyncio.Runner(loop_factory=loop_factory(loop)) as runner:
        print(json.dumps({"loop": type(runner.get_loop()).__module__}), flush=True)
        runner.run(serve())


# -- parent side ----------------------------------------------------------------------------
def _git(*args: str) -> str:
    return subprocess.run(
        ["git", "-C", str(ROOT), *args], check=True, capture_output=True, text=True
    ).stdout.strip()


def _extract(rev: str, into: Path) -> str:
    """The tree of ``rev`` in ``into`` (git archive: no worktree to clean up); its full hash."""
    commit = _git("rev-parse", "--verify", f"{rev}^{{commit}}")
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", commit],
        check=True,
        capture_output=True,
    ).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(into, filter="data")
    return commit


class Worker:
    def __init__(self, label: str, root: Path, cpu: int | None, loop: str):
        self.label = label
        pin = [] if cpu is None else ["--pin", str(cpu)]
        self.proc = subprocess.Popen(
            [
                sys.executable,
                str(Path(__file__).resolve()),
                "--worker",
                str(root),
                "--loop",
                loop,
                *pin,
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
        )
        self.loop = self._read()["loop"]
        self.origin = self._read()["ready"]

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"the {self.label} worker ended early (its error is above)")
        result: dict[str, Any] = json.loads(line)
        return result

    def cpu_us(self, scenario: str, cycles: int) -> float:
        """CPU microseconds per cycle over ``cycles`` cycles."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{scenario} {cycles}\n")
        self.proc.stdin.flush()
        return float(self._read()["cpu"]) / cycles * 1e6

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=30)


def _spread(values: list[float]) -> str:
    return f"{min(values):.1f}-{max(values):.1f}"


def compare(args: argparse.Namespace) -> int:
    head = _git("rev-parse", "--short", "HEAD")
    dirty = (
        " + uncommitted changes" if _git("status", "--porcelain", "--", "core", "plugins") else ""
    )
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="cycle-cost-baseline-") as tmp:
        base_commit = _extract(args.baseline, Path(tmp))
        print(
            f"cycle cost: CPU per cycle (time.process_time of the worker), {args.cycles} cycles "
            f"x {args.repeats} repetitions per side, alternating; Python {sys.version.split()[0]}, "
            f"{os.cpu_count()} CPUs, load average {load_before[0]:.2f}, workers "
            + ("not pinned" if args.cpu is None else f"pinned to CPU {args.cpu}"),
            flush=True,
        )
        workers = {
            "baseline": Worker("baseline", Path(tmp), args.cpu, args.loop),
            "this tree": Worker("this tree", ROOT, args.cpu, args.loop),
        }
        try:
            print(
                f"  baseline:  {base_commit[:12]} ({args.baseline}), {workers['baseline'].origin}"
            )
            print(f"  this tree: {head}{dirty}, {workers['this tree'].origin}")
            print(f"  event loop: {workers['this tree'].loop} (--loop {args.loop})", flush=True)
            results: dict[str, dict[str, list[float]]] = {
                s: {w: [] for w in workers} for s in SCENARIOS
            }
            for worker in workers.values():  # warm-up, not counted
                for scenario in SCENARIOS:
                    worker.cpu_us(scenario, max(1, args.cycles // 4))
            for rep in range(args.repeats):
                order = list(workers) if rep % 2 == 0 else list(reversed(workers))
                for scenario in SCENARIOS:
                    for name in order:
                        results[scenario][name].append(workers[name].cpu_us(scenario, args.cycles))
        finally:
            for worker in workers.values():
                worker.close()
    load_after = os.getloadavg()
    met = True
    labels = {
        "sync": "SYNC cycle (RPDO1 8 DO + SYNC -> loopback -> TPDO1)",
        "poll": "Modbus poll reply (16 DI -> image -> TPDO1)",
    }
    print()
    for scenario in SCENARIOS:
        base, new = results[scenario]["baseline"], results[scenario]["this tree"]
        ratio = statistics.median(base) / statistics.median(new)
        pairs = [b / n for b, n in zip(base, new, strict=True)]
        met = met and ratio >= args.target
        print(f"{labels[scenario]}:")
        print(
            f"  baseline  median {statistics.median(base):7.1f} us  (repetitions {_spread(base)})"
        )
        print(f"  this tree median {statistics.median(new):7.1f} us  (repetitions {_spread(new)})")
        print(
            f"  ratio baseline / this tree {ratio:.2f}x (per repetition pair {min(pairs):.2f}-"
            f"{max(pairs):.2f}x); target >= {args.target:g}x: {'met' if ratio >= args.target else 'NOT met'}"
        )
    print(f"\nload average {load_before[0]:.2f} before, {load_after[0]:.2f} after")
    return 0 if met else 1


def profile(scenario_name: str, cycles: int, loop: str, root: Path) -> None:
    """cProfile of one scenario in one tree, in process."""
    import cProfile
    import pstats

    _use_tree(root)
    from fieldgate.cli import loop_factory

    async def run() -> None:
        with tempfile.TemporaryDirectory() as state:
            scenario: Any = SyncScenario() if scenario_name == "sync" else PollScenario()
            await scenario.setup(state)
            profiler = cProfile.Profile()
            profiler.enable()
            if scenario_name == "sync":
                scenario.run(cycles)
            else:
                await scenario.run(cycles)
            profiler.disable()
            await scenario.close()
            stats = pstats.Stats(profiler)
            stats.sort_stats("tottime").print_stats(20)
            stats.sort_stats("cumulative").print_stats(30)

    with asyncio.Runner(loop_factory=loop_factory(loop)) as runner:
        runner.run(run())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument(
        "--baseline",
        default=BEFORE_BATCH,
        help="the revision to compare with (default: main before the batched write)",
    )
    parser.add_argument("--cycles", type=int, default=2000, help="cycles per repetition")
    parser.add_argument("--repeats", type=int, default=15, help="repetitions per side")
    parser.add_argument("--target", type=float, default=2.0, help="the ratio to reach")
    parser.add_argument("--quick", action="store_true", help="500 cycles x 5 repetitions")
    parser.add_argument(
        "--loop",
        choices=("auto", "uvloop", "asyncio"),
        default="auto",
        help="the workers' event loop (auto: what `fieldgate run` uses, uvloop where installed)",
    )
    parser.add_argument("--profile", choices=SCENARIOS, help="cProfile this tree's scenario")
    parser.add_argument(
        "--profile-baseline", action="store_true", help="--profile the baseline's code instead"
    )
    parser.add_argument(
        "--cpu",
        type=int,
        default=(os.cpu_count() or 1) - 1,
        help="the CPU both workers are pinned to (default: the last; -1: not pinned)",
    )
    parser.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--pin", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker is not None:
        if args.pin is not None and hasattr(os, "sched_setaffinity"):
            os.sched_setaffinity(0, {args.pin})
        _worker(args.worker, args.loop)
        return 0
    if args.cpu < 0 or not hasattr(os, "sched_setaffinity"):
        args.cpu = None
    if args.profile:
        if not args.profile_baseline:
            profile(args.profile, args.cycles, args.loop, ROOT)
            return 0
        with tempfile.TemporaryDirectory(prefix="cycle-cost-baseline-") as tmp:
            print(f"baseline {_extract(args.baseline, Path(tmp))[:12]} ({args.baseline})")
            profile(args.profile, args.cycles, args.loop, Path(tmp))
        return 0
    if args.quick:
        args.cycles, args.repeats = 500, 5
    return compare(args)


if __name__ == "__main__":
    sys.exit(main())
