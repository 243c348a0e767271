"""Hostile topology files against ``fieldgate validate`` and ``fieldgate run``: each must end
with one error line (file:line:column where there is one) and exit 1, never a traceback or
a hang. Prints each case's wall time and the peak memory of the process.

Run:  .venv/bin/python scripts/faults/hostile_topology.py [--command validate|run] [--keep DIR]
      (about 20 s; goal per case: under 2 s and 200 MB)

The cases (the bug report's, as a new user met them): an alias bomb with a duplicate key in
the same mapping (2 KB; ruamel built its duplicate-key message with ``repr()`` of the whole
mapping: past 1 GB in 20 s), 400-deep nesting (a 2,750-line RecursionError traceback),
``/dev/zero`` (read until MemoryError), a FIFO (blocked forever), a 50 MB file (17 s and
260 MB), a recursive alias, and a plain duplicate key.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_S = 30.0

LEVELS = "abcdefghi"


def alias_bomb() -> str:
    """Nine levels of nine aliases each (9^9 = 387 million strings once expanded), with the
    last key given twice in the same mapping."""
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for prev, name in zip(LEVELS, LEVELS[1:], strict=False):
        lines.append(f"{name}: &{name} [{','.join(['*' + prev] * 9)}]")
    lines.append("i: 1")  # the duplicate key
    return "\n".join(lines) + "\n"


def _write(text: str) -> Callable[[Path], str]:
    def make(folder: Path) -> str:
        path = folder / "topology.yaml"
        path.write_text(text)
        return str(path)

    return make


def _fifo(folder: Path) -> str:
    path = folder / "fifo.yaml"
    os.mkfifo(path)
    return str(path)


def _big(folder: Path) -> str:
    path = folder / "big.yaml"
    with path.open("w") as f:
        f.write("gateway: {name: big}\n")
        block = ("# " + "x" * 60 + "\n") * 16384  # 1 MiB
        for _ in range(50):
            f.write(block)
    return str(path)


CASES: dict[str, tuple[Callable[[Path], str], str]] = {
    # name: (make the file, what the one error line must say)
    "alias bomb + duplicate key": (_write(alias_bomb()), "expands to more than"),
    "400-deep nesting": (_write("gateway: " + "[" * 400 + "]" * 400 + "\n"), "nested deeper than"),
    "/dev/zero": (lambda folder: "/dev/zero", "not a regular file (a character device)"),
    "FIFO": (_fifo, "not a regular file (a FIFO)"),
    "50 MB file": (_big, "is larger than the 2 MiB"),
    "recursive alias": (
        _write("gateway: &g {name: x, self: *g}\n"),
        "refers to a node that contains it",
    ),
    "duplicate key": (
        _write("gateway: {name: a}\ngateway: {name: b}\n"),
        'duplicate key "gateway"',
    ),
}


def run_case(command: str, path: str) -> tuple[int, str, float, float]:
    """(exit code, standard error, seconds, peak RSS in MB) of ``fieldgate COMMAND PATH``;
    killed after TIMEOUT_S (a hang)."""
    started = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldgate", command, path],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    killer = threading.Timer(TIMEOUT_S, proc.kill)
    killer.start()
    try:
        assert proc.stderr is not None
        err = proc.stderr.read()
        _, status, usage = os.wait4(proc.pid, 0)  # this child's own peak
    finally:
        killer.cancel()
        proc.returncode = -1
    code = os.waitstatus_to_exitcode(status)
    if code == -9:
        err += f"\n(killed after {TIMEOUT_S:.0f} s: a hang)"
    return code, err, time.monotonic() - started, usage.ru_maxrss / 1024


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--command", choices=("validate", "run"), default="validate")
    args = parser.parse_args()
    failures = 0
    print(
        f"fieldgate {args.command} on hostile topology files (goal: one line, exit 1, < 2 s, < 200 MB)"
    )
    print(f"{'case':28} {'exit':>4} {'lines':>5} {'time':>7} {'peak RSS':>9}  message")
    example = str(ROOT / "examples" / "i7232d-style.yaml")
    code, _, seconds, peak = run_case("validate", example)
    print(f"{'(a valid example: baseline)':28} {code:>4} {'':>5} {seconds:6.2f}s {peak:7.0f} MB")
    with tempfile.TemporaryDirectory() as tmp:
        for name, (make, expected) in CASES.items():
            folder = Path(tmp) / name.replace(" ", "_").replace("/", "_")
            folder.mkdir()
            path = make(folder)
            code, err, seconds, peak = run_case(args.command, path)
            lines = [line for line in err.splitlines() if line.strip()]
            issue = lines[0] if lines else ""
            ok = code == 1 and expected in issue and "Traceback" not in err
            ok = ok and len(lines) <= 2 and (len(lines) == 1 or "error(s)" in lines[1])
            failures += not ok
            shown = issue if len(issue) < 110 else issue[:107] + "..."
            print(
                f"{name:28} {code:>4} {len(lines):>5} {seconds:6.2f}s {peak:7.0f} MB  "
                f"{'' if ok else 'FAIL: '}{shown}"
            )
    print("verdict:", "PASS" if not failures else f"{failures} case(s) FAILED")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
