"""CPU placement (``gateway.isolation.fieldbus_cpus`` / ``north_cpus``): `fieldgate run` pins
every thread of the fieldbus process, the north-facing children run on the other CPUs (or
the ones named), a CPU the host does not offer is one warning line and no failed start, and
overlapping sets are refused at validation. Checked in /proc, in processes of their own (the
test process keeps its CPUs)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fieldgate.topology import TopologyError, load_topology

from .test_isolation_children import topology

ROOT = Path(__file__).resolve().parents[2]
CPUS = sorted(os.sched_getaffinity(0))
two_cpus = pytest.mark.skipif(len(CPUS) < 2, reason="pinning apart needs two CPUs")


def cpus_of(pid: int) -> dict[int, str]:
    """Each thread of ``pid``: its Cpus_allowed_list."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            status = (task / "status").read_text()
        except OSError:
            continue
        for line in status.splitlines():
            if line.startswith("Cpus_allowed_list:"):
                out[int(task.name)] = line.split(":", 1)[1].strip()
    return out


def children_of(pid: int) -> list[int]:
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            kids += [int(k) for k in (task / "children").read_text().split()]
        except OSError:
            continue
    return kids


def as_list(cpus: list[int]) -> str:
    """The kernel's way of writing a set of CPUs (ranges joined by commas)."""
    runs: list[list[int]] = []
    for c in sorted(cpus):
        if runs and c == runs[-1][-1] + 1:
            runs[-1].append(c)
        else:
            runs.append([c])
    return ",".join(f"{r[0]}-{r[-1]}" if len(r) > 1 else str(r[0]) for r in runs)


def run_gateway(tmp_path: Path, isolation: dict[str, object]) -> subprocess.Popen[str]:
    topo = tmp_path / "gw.json"  # JSON is YAML
    topo.write_text(json.dumps(topology(isolation=isolation)))
    return subprocess.Popen(
        [sys.executable, "-m", "fieldgate", "run", str(topo), "--duration", "60"],
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )


def wait_for_child(proc: subprocess.Popen[str]) -> tuple[int, list[str]]:
    """The child's pid once the children are running; the log lines so far."""
    assert proc.stderr is not None
    log: list[str] = []
    for line in proc.stderr:
        log.append(line)
        if "gateway utilities running" in line or "fieldbus side running" in line:
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline:
                kids = children_of(proc.pid)
                if kids:
                    return kids[0], log
                time.sleep(0.05)
    pytest.fail("no child process:\n" + "".join(log))


def stop(proc: subprocess.Popen[str]) -> None:
    proc.send_signal(signal.SIGTERM)
    try:
        proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def settle(pid: int, want: str, timeout: float = 20.0) -> dict[int, str]:
    """The child pins itself first thing after it starts: wait until it has (or time out)."""
    deadline = time.monotonic() + timeout
    seen = cpus_of(pid)
    while time.monotonic() < deadline and set(seen.values()) != {want}:
        time.sleep(0.05)
        seen = cpus_of(pid)
    return seen


@two_cpus
@pytest.mark.parametrize(
    "isolation, fieldbus, north",
    [
        ({"fieldbus_cpus": [CPUS[0]]}, [CPUS[0]], CPUS[1:]),  # the children: every other CPU
        ({"fieldbus_cpus": [CPUS[-1]], "north_cpus": [CPUS[0]]}, [CPUS[-1]], [CPUS[0]]),
    ],
    ids=["north-by-default", "both-named"],
)
def test_the_fieldbus_process_and_the_children_run_on_their_own_cpus(
    tmp_path, isolation, fieldbus, north
):
    proc = run_gateway(tmp_path, isolation)
    try:
        child, log = wait_for_child(proc)
        threads = cpus_of(proc.pid)
        assert len(threads) > 1, "the fieldbus process has threads (the CAN and serial ones)"
        assert set(threads.values()) == {as_list(fieldbus)}, (threads, "".join(log))
        seen = settle(child, as_list(north))
        assert set(seen.values()) == {as_list(north)}, seen
        assert any("pinned to CPU" in line for line in log), "".join(log)
    finally:
        stop(proc)


def test_a_cpu_the_host_does_not_offer_is_a_warning_and_the_gateway_runs(tmp_path):
    proc = run_gateway(tmp_path, {"fieldbus_cpus": [4095]})
    try:
        child, log = wait_for_child(proc)
        text = "".join(log)
        assert "fieldbus_cpus 4095: CPU 4095 not available here" in text, text
        assert set(cpus_of(proc.pid).values()) == {as_list(CPUS)}  # left where it was
        assert proc.poll() is None
    finally:
        stop(proc)


def test_overlapping_sets_are_refused_at_validation(registry):
    topo = topology(isolation={"fieldbus_cpus": [0, 1], "north_cpus": [1]})
    with pytest.raises(TopologyError, match="fieldbus_cpus and north_cpus share CPU 1"):
        load_topology(topo, registry)


@two_cpus
def test_a_child_is_born_on_its_cpus_and_the_forking_thread_keeps_its_own(capfd):
    """Its interpreter's start and imports (~0.1 s of CPU) never run on the fieldbus CPUs."""
    from fieldgate.isolation.supervisor import _popen_on

    before = os.sched_getaffinity(0)
    code = "import os; print('born on', sorted(os.sched_getaffinity(0)))"
    r, w = os.pipe()
    try:
        child = _popen_on([CPUS[-1]], [sys.executable, "-c", code], w)
        assert child.wait(30) == 0
    finally:
        os.close(r)
        os.close(w)
    assert f"born on {[CPUS[-1]]}" in capfd.readouterr().out
    assert os.sched_getaffinity(0) == before
