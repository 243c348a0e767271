"""The process layout from the outside: `fieldgate run` with a north-facing front, its child
gone when the fieldbus process is killed, paced client writes, a child that breaks the channel."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from fieldgate import Gateway
from fieldgate.isolation import wire
from fieldgate.isolation.supervisor import _Link

from .test_isolation_children import Line, topology, until


def children_of(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True)
    return [int(p) for p in out.stdout.split()]


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"


def test_killing_the_fieldbus_process_takes_its_children_with_it(tmp_path):
    topo = tmp_path / "gw.json"  # JSON is YAML
    topo.write_text(json.dumps(topology()))
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldgate", "run", str(topo), "--duration", "60"],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "running:" in line:
                break
        kids = children_of(proc.pid)
        assert len(kids) == 1 and alive(kids[0])
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        deadline = time.monotonic() + 10
        while alive(kids[0]) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive(kids[0]), "the child outlived the fieldbus process"
    finally:
        proc.kill()
        proc.wait()


def test_a_clean_stop_stops_the_children_and_exits_0(tmp_path):
    topo = tmp_path / "gw.json"
    topo.write_text(json.dumps(topology()))
    done = subprocess.run(
        [sys.executable, "-m", "fieldgate", "run", str(topo), "--duration", "2"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert "killing" not in done.stderr and "ERROR" not in done.stderr


async def test_client_writes_are_paced_and_none_is_lost(registry):
    topo = topology(isolation={"writes_per_s": 20})
    async with Gateway.load(topo, registry=registry) as gw:
        line = await Line.open(gw)
        started = time.monotonic()
        try:
            for value in range(40):
                assert await line.ask(f"set lb/m1/ao0 {value}") == "ok"
        finally:
            line.close()
        # 40 batches at 20 a second (the first second's worth at once): about a second more
        assert time.monotonic() - started >= 0.9
        assert gw.read("lb/m1/ao0") == 39 and gw.component("probe").child.writes_applied == 40


async def test_a_child_that_breaks_the_channel_is_killed(registry):
    async with Gateway.load(topology(restart_backoff_s=0.1), registry=registry) as gw:
        child = gw.component("probe").child
        link = _Link(child)
        link.data_received(wire.HEADER.pack(wire.MAX_UP + 1))  # a frame over the limit
        await until(lambda: gw.restarts("probe") == 1 and child.state == "running")
        assert child.kills == {"protocol": 1} and child.protocol_errors == 1
        link = _Link(child)
        body = b'{"t":"write","id":"x","values":{}}'
        link.data_received(wire.HEADER.pack(len(body)) + body)  # not a valid write request
        await until(lambda: gw.restarts("probe") == 2 and child.state == "running")
        assert child.kills == {"protocol": 2}
