"""Stopping is as quick as starting (issue 33): a north-facing child that is still starting
is ended at once, a child exits when asked even with a worker thread blocked in a library,
and `fieldgate run` exits soon after SIGTERM, also while its children start."""

from __future__ import annotations

import asyncio
import json
import logging
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from netkit import free_port

from fieldgate import Gateway

from .test_isolation_children import topology, until

ROOT = Path(__file__).resolve().parents[2]


async def test_a_stop_while_a_child_starts_ends_it_at_once(registry, caplog):
    caplog.set_level(logging.INFO, logger="fieldgate.isolation")
    gw = Gateway.load(topology(start_s=60), registry=registry)  # an OPC UA certificate, say
    starting = asyncio.ensure_future(gw.start())
    await until(lambda: bool(gw.fronts) and gw.fronts[0].child.state == "starting")  # type: ignore[attr-defined]
    front = gw.component("probe")
    proc = front.child.process  # type: ignore[attr-defined]
    starting.cancel()  # what `fieldgate run` does on SIGTERM before the start ends
    await asyncio.gather(starting, return_exceptions=True)
    async with asyncio.timeout(20):  # a hang detector: the child would start for 60 s
        await gw.stop()
    assert proc.returncode is not None and front.child.state == "stopped"  # type: ignore[attr-defined]
    assert any("stopped while starting" in r.getMessage() for r in caplog.records)
    # ended because it was starting, not after the grace a serving child gets
    assert not front.child.kills  # type: ignore[attr-defined]


async def test_a_child_exits_when_asked_though_a_worker_thread_is_blocked(registry):
    """A library's blocking call in a worker thread (paho's connect to a broker that does not
    answer) once held the child's exit, joined at the interpreter's end, until SIGKILL."""
    gw = Gateway.load(topology(thread_s=60), registry=registry)
    await gw.start()
    child = gw.component("probe").child  # type: ignore[attr-defined]
    proc = child.process
    async with asyncio.timeout(20):
        await gw.stop()
    assert proc.returncode == 0, f"exit code {proc.returncode}"  # its own exit, not SIGKILL
    assert not child.kills


def run_then_sigterm(args: list[str], marker: str) -> tuple[float, int, str]:
    """`fieldgate run ARGS`, SIGTERM as soon as ``marker`` is logged: (seconds to the exit
    after SIGTERM, exit code, the log)."""
    proc = subprocess.Popen(  # --duration: a marker that never comes ends in EOF, not a hang
        [sys.executable, "-m", "fieldgate", "run", *args, "--duration", "60"],
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    log: list[str] = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            log.append(line)
            if marker in line:
                break
        else:
            pytest.fail("no " + repr(marker) + " in the log:\n" + "".join(log))
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        try:
            _, rest = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            pytest.fail("no exit within 30 s of SIGTERM:\n" + "".join(log))
        return time.monotonic() - sent, proc.returncode, "".join(log) + rest
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_run_exits_soon_after_sigterm_while_a_child_starts(tmp_path):
    topo = tmp_path / "gw.json"  # JSON is YAML
    topo.write_text(json.dumps(topology(start_s=60)))
    took, code, log = run_then_sigterm([str(topo)], "fieldbus side running")
    assert code == 0, log
    assert took < 5, f"{took:.1f} s from SIGTERM to the exit (a hang detector, not a target)"
    assert "stopping (asked to while starting)" in log


def test_the_modbus_tcp_meters_example_exits_soon_after_sigterm(tmp_path):
    """The end-to-end hang detector of issue 33 (bench/startup.py measures the time)."""
    pytest.importorskip("asyncua")
    args = ["examples/modbus-tcp-meters.yaml", "--simulate"]
    args += ["--set", f"gateway.state_dir={tmp_path}"]
    args += ["--set", f"fronts.0.listen=127.0.0.1:{free_port()}"]
    args += ["--set", f"fronts.1.listen=127.0.0.1:{free_port()}"]
    for marker in ("fieldbus side running", "gateway utilities running"):
        took, code, log = run_then_sigterm(args, marker)
        assert code == 0, log
        assert took < 5, f"{took:.1f} s from SIGTERM to the exit after {marker!r}"
        assert "killing" not in log and "left behind" not in log, log
