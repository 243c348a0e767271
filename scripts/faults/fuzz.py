#!/usr/bin/env python3
"""Fuzz every wire: one target per protocol (scripts/faults/fuzz_targets.py), each input fed
through Hypothesis and checked by the target's invariant.

Each target is a Hypothesis property (``@given(st.binary())``: run the input, then check the
engine still answers a valid request). The campaign drives it through Hypothesis's fuzzing
entry point, ``fuzz_one_input``, with buffers from a seeded generator: the same property a
developer runs with plain ``@given``, at several times the rate of Hypothesis's own search
loop (about 8x for the binary strategy on the build machine). An input that takes longer
than --hang-s is a hang (SIGALRM). Every failure prints its input (hex); the target's state
depends on the inputs before it, so the way to reproduce one is the same seed and count.

    .venv/bin/python scripts/faults/fuzz.py                      # the full campaign
    .venv/bin/python scripts/faults/fuzz.py --target sdo,pdo --inputs 100000 --seed 3
"""

from __future__ import annotations

import argparse
import json
import logging
import random
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from fuzz_targets import FULL_INPUTS, TARGETS, InvariantBroken, Target

__all__ = ["InvariantBroken", "Report", "fuzz"]
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


class Hang(Exception):
    pass


@dataclass
class Report:
    target: str
    inputs: int = 0
    crashes: int = 0
    hangs: int = 0
    invariant_failures: int = 0
    seconds: float = 0.0
    slowest_ms: float = 0.0
    examples: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not (self.crashes or self.hangs or self.invariant_failures)

    def as_dict(self) -> dict[str, Any]:
        rate = self.inputs / self.seconds if self.seconds else 0.0
        return {**self.__dict__, "inputs_per_s": round(rate)}


def _alarm(signum: int, frame: FrameType | None) -> None:
    raise Hang


def fuzz(
    target: Target,
    inputs: int,
    seed: int,
    hang_s: float = 2.0,
    progress: bool = False,
) -> Report:
    """Run ``inputs`` executed inputs through ``target``; failures are counted, not raised."""
    report = Report(target.name)
    rng = random.Random(seed)
    slowest = 0.0

    @settings(database=None, deadline=None, suppress_health_check=list(HealthCheck))
    @given(st.binary(min_size=1, max_size=target.max_len))
    def prop(data: bytes) -> None:
        nonlocal slowest
        report.inputs += 1
        started = time.perf_counter()
        target.run(data)
        target.check()
        slowest = max(slowest, time.perf_counter() - started)

    fuzz_one = prop.hypothesis.fuzz_one_input  # type: ignore[attr-defined]
    previous = signal.signal(signal.SIGALRM, _alarm)
    logging.disable(logging.CRITICAL)  # a counted internal error logs its traceback
    started = time.monotonic()
    next_progress = started + 30
    try:
        while report.inputs < inputs:
            buffer = rng.randbytes(rng.randint(8, 4 * target.max_len))
            signal.setitimer(signal.ITIMER_REAL, hang_s)
            try:
                fuzz_one(buffer)
            except Hang:
                report.hangs += 1
                _note(report, "hang", buffer)
                target.setup()
            except InvariantBroken as exc:
                report.invariant_failures += 1
                _note(report, f"invariant: {exc}", buffer)
                target.setup()
            except Exception as exc:
                report.crashes += 1
                _note(report, f"crash: {type(exc).__name__}: {exc}", buffer)
                target.setup()
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            if progress and time.monotonic() >= next_progress:
                next_progress += 30
                rate = report.inputs / (time.monotonic() - started)
                print(
                    f"  {target.name}: {report.inputs:,}/{inputs:,} inputs, {rate:,.0f}/s, "
                    f"{report.crashes} crashes, {report.hangs} hangs, "
                    f"{report.invariant_failures} invariant failures",
                    file=sys.stderr,
                    flush=True,
                )
    finally:
        signal.signal(signal.SIGALRM, previous)
        logging.disable(logging.NOTSET)
    report.seconds = round(time.monotonic() - started, 1)
    report.slowest_ms = round(slowest * 1000, 2)
    return report


def _note(report: Report, what: str, buffer: bytes) -> None:
    if len(report.examples) < 5:
        report.examples.append(f"input {report.inputs}: {what[:300]} [{buffer.hex()}]")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--target", default="all", help=f"all, or some of {', '.join(TARGETS)} (comma-separated)"
    )
    parser.add_argument(
        "--inputs",
        type=int,
        help="per target (default: 10^6 per wire, 20,000 YAML files, 10^5 over a socket)",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--hang-s", type=float, default=2.0)
    args = parser.parse_args(argv)
    names = list(TARGETS) if args.target == "all" else args.target.split(",")
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        parser.error(f"unknown target(s) {', '.join(unknown)}; known: {', '.join(TARGETS)}")
    reports = []
    with tempfile.TemporaryDirectory(prefix="fuzz-", dir=_fast_dir()) as tmp:
        for name in names:
            work = Path(tmp) / name
            work.mkdir()
            target = TARGETS[name](work)
            inputs = args.inputs or FULL_INPUTS[name]
            print(f"{name}: {inputs:,} inputs, seed {args.seed}", file=sys.stderr, flush=True)
            try:
                report = fuzz(target, inputs, args.seed, args.hang_s, progress=True)
            finally:
                target.close()
            print(json.dumps(report.as_dict()), flush=True)
            reports.append(report)
    return 0 if all(r.ok for r in reports) else 1


def _fast_dir() -> str | None:
    """State files the targets write (0x1010 save, DeviceNet MAC) go to RAM when it exists."""
    shm = Path("/dev/shm")
    return str(shm) if shm.is_dir() else None


if __name__ == "__main__":
    sys.exit(main())
