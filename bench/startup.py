"""How quick and how small a gateway starts, against Python with can and canopen imported,
every example, in the same run (issue 33).

Run:  .venv/bin/python bench/startup.py [--runs 5] [--examples a.yaml,b.yaml] [--venv DIR]
      [--short]
      (default: fieldgate built as a wheel and installed in a fresh venv under
      /var/tmp/fieldgate-startup, as a user installs it: about a minute the first time;
      --short: one run of each example from this interpreter, the CI version: it prints the
      ratios and exits 0 whatever they are, 2 when a gateway does not start; about 40 s)

For each example, each run: ``fieldgate run EXAMPLE --simulate`` as a process of its own with
a NOTIFY_SOCKET listener, as systemd starts it. Measured:

* READY: from the process's start to systemd's ``READY=1`` (sent once the backs and the
  fieldbus fronts run);
* boot-up: to the fieldbus's first word on the bus: the CANopen boot-up (its log line "NMT
  INITIALISING -> PRE-OPERATIONAL") or the DeviceNet front's start (its duplicate MAC check),
  from the log as it comes, in the same run;
* peak RSS (VmHWM) of the fieldbus process after a second of running, and of each north-facing
  child beside it;
* stop: from SIGTERM to the process's exit.

Beside them, in the same run, the baseline: ``python -c "import can, canopen"``'s wall time and
peak RSS from the same interpreter. Printed: medians and the ratios; the targets: READY within
3x the baseline and peak RSS within 1.5x for examples/i7232d-style.yaml, and every example's
boot-up as quick as i7232d's.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.append(str(ROOT / "tests"))
from netkit import free_port  # noqa: E402  (tests/netkit.py: one helper for tests, benches and scripts)

BOOT_MARKERS = ("NMT INITIALISING -> PRE-OPERATIONAL", "DeviceNet MAC ")
READY_RATIO, RSS_RATIO = 3.0, 1.5
BASELINE = (
    "import can, canopen; "
    "print(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')))"
)


def peak_kb(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def children(pid: int) -> list[int]:
    """A process's children, whichever of its threads started them."""
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found += [int(p) for p in (task / "children").read_text().split()]
        except OSError:
            pass
    return found


def baseline(python: str, env: dict[str, str]) -> tuple[float, int]:
    started = time.monotonic()
    done = subprocess.run([python, "-c", BASELINE], capture_output=True, text=True, env=env)
    return time.monotonic() - started, int(done.stdout.strip())


def overrides(example: Path) -> list[str]:
    """A front on SocketCAN runs on python-can's virtual bus here (no SocketCAN on every host;
    the bus's kind is not what this bench measures), and a listener on a free loopback port
    (the examples' 4840 and 5020 may be another program's on a shared host)."""
    from ruamel.yaml import YAML

    data = YAML(typ="safe").load(example.read_text())
    out: list[str] = []
    for i, front in enumerate(data.get("fronts", [])):
        if front.get("interface") == "socketcan":
            out += ["--set", f"fronts.{i}.interface=virtual"]
        if "listen" in front:
            out += ["--set", f"fronts.{i}.listen=127.0.0.1:{free_port()}"]
    return out


class StartFailed(RuntimeError):
    """The gateway exited, or sent no READY, instead of starting: an error, not noise."""


def one_run(
    python: str, example: Path, env: dict[str, str], work: Path, settle: float = 1.0
) -> dict[str, float]:
    """One start: READY, the boot-up (from the log as it comes), peak RSS after ``settle``
    seconds of running, and the stop."""
    notify = work / f"notify-{time.monotonic_ns()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(notify))
    sock.settimeout(0.2)
    state = work / "state"
    cmd = [python, "-m", "fieldgate", "run", str(example), "--simulate"]
    cmd += ["--set", f"gateway.state_dir={state}", *overrides(example)]
    started = time.monotonic()
    proc = subprocess.Popen(
        cmd,
        env={**env, "NOTIFY_SOCKET": str(notify)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    log: list[str] = []
    booted: list[float] = []

    def read_log() -> None:  # the boot-up marker's arrival, and the log for an error
        assert proc.stderr is not None
        for line in proc.stderr:
            log.append(line)
            if not booted and any(m in line for m in BOOT_MARKERS):
                booted.append(time.monotonic() - started)

    reader = threading.Thread(target=read_log, daemon=True)
    reader.start()
    result: dict[str, float] = {}
    try:
        while True:
            try:
                if b"READY=1" in sock.recv(4096):
                    break
            except TimeoutError:
                pass
            if proc.poll() is not None or time.monotonic() - started > 60:
                raise StartFailed(
                    f"{example.name}: no READY ({'exit code ' + str(proc.returncode) if proc.returncode is not None else 'after 60 s'}): "
                    + "".join(log[-5:]).strip()
                )
        result["ready"] = time.monotonic() - started
        time.sleep(settle)  # the children are up, the image polled
        result["peak_kb"] = peak_kb(proc.pid)
        result["children_kb"] = sum(peak_kb(c) for c in children(proc.pid))
        result["children"] = len(children(proc.pid))
        stop = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(60)
        result["stop"] = time.monotonic() - stop
        reader.join(5)
        result["boot"] = booted[0] if booted else float("nan")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        sock.close()
        notify.unlink(missing_ok=True)
    return result


def wheel_venv(base: Path) -> str:
    """fieldgate as a user installs it: its wheel in a fresh venv (reused while the tree's
    sources are the same)."""
    digest = hashlib.sha256()
    for folder in ("core", "plugins", "conformance"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            digest.update(path.read_bytes())
    digest.update((ROOT / "pyproject.toml").read_bytes())
    venv = base / digest.hexdigest()[:16]
    python = venv / "bin" / "python"
    if python.exists():
        return str(python)
    print(f"building the wheel and a fresh venv in {venv} ...", flush=True)
    with tempfile.TemporaryDirectory() as wheels:
        subprocess.run(
            [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", wheels, str(ROOT)],
            check=True,
        )
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        wheel = next(Path(wheels).glob("fieldgate-*.whl"))
        subprocess.run([str(python), "-m", "pip", "install", "-q", str(wheel)], check=True)
    return str(python)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--examples", default="", help="comma-separated (default: every example)")
    parser.add_argument("--venv", help="the venv to run from (default: a fresh wheel install)")
    parser.add_argument(
        "--short",
        action="store_true",
        help="one run each, this interpreter; exit 0 above target (the CI's run: one run is "
        "noise), 2 when a gateway does not start",
    )
    parser.add_argument("--json", help="also write the figures here")
    args = parser.parse_args()
    examples = (
        [ROOT / e for e in args.examples.split(",") if e]
        if args.examples
        else sorted((ROOT / "examples").glob("*.yaml"))
    )
    runs = 1 if args.short else args.runs
    if args.venv:
        python = str(Path(args.venv) / "bin" / "python")
    elif args.short:
        python = sys.executable
    else:
        python = wheel_venv(Path("/var/tmp/fieldgate-startup"))
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NOTIFY_", "WATCHDOG_"))}
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # compiled modules, as an installation has them
    env["PYTHONPYCACHEPREFIX"] = str(Path(tempfile.gettempdir()) / "fieldgate-startup-pyc")
    figures: dict[str, dict[str, list[float]]] = {}
    base_t: list[float] = []
    base_kb: list[int] = []
    with tempfile.TemporaryDirectory() as work_dir:
        work = Path(work_dir)
        try:
            for example in examples:  # a warm-up: compiled modules and the OS's file cache
                one_run(python, example, env, work, settle=0.0)
            for r in range(runs):
                t, kb = baseline(python, env)
                base_t.append(t)
                base_kb.append(kb)
                for example in examples:
                    got = one_run(python, example, env, work)
                    row = figures.setdefault(example.name, {})
                    for key, value in got.items():
                        row.setdefault(key, []).append(value)
                print(f"  run {r + 1}/{runs} done", flush=True)
        except StartFailed as exc:
            print(f"ERROR: {exc}", file=sys.stderr)
            return 2
    verdict = report(python, figures, base_t, base_kb, args.json)
    if args.short:  # the CI's run: the ratios are printed; one run is noise, not a failure
        return 0
    return verdict


def report(
    python: str,
    figures: dict[str, dict[str, list[float]]],
    base_t: list[float],
    base_kb: list[int],
    json_path: str | None,
) -> int:
    med = statistics.median
    bt, bkb = med(base_t), med(base_kb)
    print()
    print(f"interpreter: {python}")
    print(f"baseline `import can, canopen`: {bt * 1000:.0f} ms, peak RSS {bkb / 1024:.1f} MB")
    print()
    print(
        f"{'example':28} {'READY':>8} {'x base':>7} {'boot-up':>8} {'peak RSS':>9} {'x base':>7}"
        f" {'children':>14} {'stop':>7}"
    )
    table: dict[str, dict[str, float]] = {}
    for name, row in figures.items():
        ready, boot, kb = med(row["ready"]), med(row["boot"]), med(row["peak_kb"])
        kids, kids_kb, stop = med(row["children"]), med(row["children_kb"]), med(row["stop"])
        table[name] = {
            "ready_s": ready,
            "ready_ratio": ready / bt,
            "bootup_s": boot,
            "peak_rss_mb": kb / 1024,
            "rss_ratio": kb / bkb,
            "children": kids,
            "children_rss_mb": kids_kb / 1024,
            "stop_s": stop,
        }
        boot_text = "-" if boot != boot else f"{boot * 1000:.0f}ms"
        kids_text = f"{int(kids)}: {kids_kb / 1024:.0f} MB" if kids else "-"
        print(
            f"{name:28} {ready * 1000:6.0f}ms {ready / bt:7.2f} {boot_text:>8} "
            f"{kb / 1024:7.1f}MB {kb / bkb:7.2f} {kids_text:>14} {stop * 1000:5.0f}ms"
        )
    if json_path:
        Path(json_path).write_text(json.dumps({"baseline_s": bt, "baseline_kb": bkb, **table}))
    verdicts = []
    i7232d = table.get("i7232d-style.yaml")
    if i7232d is not None:
        verdicts.append(
            (
                i7232d["ready_ratio"] <= READY_RATIO,
                f"i7232d READY {i7232d['ready_ratio']:.2f}x (<= 3)",
            )
        )
        verdicts.append(
            (
                i7232d["rss_ratio"] <= RSS_RATIO,
                f"i7232d peak RSS {i7232d['rss_ratio']:.2f}x (<= 1.5)",
            )
        )
        plant = table.get("plant-northbound.yaml")
        if plant is not None:
            ratio = plant["bootup_s"] / i7232d["bootup_s"]
            verdicts.append(
                (ratio <= 1.2, f"plant-northbound boot-up {ratio:.2f}x i7232d's (<= 1.2)")
            )
    print()
    for ok, text in verdicts:
        print(f"  {'ok  ' if ok else 'FAIL'} {text}")
    passed = all(ok for ok, _ in verdicts)
    print(f"verdict: {'PASS' if passed else 'ABOVE TARGET'}")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
