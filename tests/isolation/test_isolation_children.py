"""North-facing fronts in child processes: the mirror, acknowledged writes, the one-writer rule,
and supervision (liveness, memory, crashes, start failures), with the test plugin's ``probe``
front (a line server in a real child process)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal

import pytest

from fieldgate import Gateway, GatewayStartError, Quality
from fieldgate.isolation.front import IsolatedFront


def topology(**probe: object) -> dict[str, object]:
    isolation = probe.pop("isolation", {})
    return {
        "gateway": {"name": "iso", "isolation": isolation},
        "backs": [
            {
                "name": "lb",
                "type": "loopback",
                "modules": [{"address": 1, "digital": 2, "analog": 2}],
            }
        ],
        "fronts": [{"name": "probe", "type": "probe", "writable": ["lb/m1/ao*"], **probe}],
    }


class Line:
    """A client of the probe's line server."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        self.reader, self.writer = reader, writer

    @classmethod
    async def open(cls, gw: Gateway) -> Line:
        port = gw.component("probe").status()["port"]
        return cls(*await asyncio.open_connection("127.0.0.1", port))

    async def ask(self, line: str, timeout: float = 10.0) -> str:
        self.writer.write(line.encode() + b"\n")
        answer = await asyncio.wait_for(self.reader.readline(), timeout)
        return answer.decode().strip()

    def close(self) -> None:
        self.writer.close()


async def until(condition, timeout: float = 20.0) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        if loop.time() > deadline:
            raise AssertionError("condition not met in time")
        await asyncio.sleep(0.05)


async def probe_status(gw: Gateway) -> dict:
    """The child's first status report (it sends one a second)."""
    front = gw.component("probe")
    await until(lambda: "batches" in front.status())
    return front.status()


async def test_the_front_runs_in_a_child_process_on_a_mirror_of_the_image(registry):
    async with Gateway.load(topology(), registry=registry) as gw:
        front = gw.component("probe")
        assert isinstance(front, IsolatedFront)
        pid = front.child.process.pid
        assert pid != os.getpid()
        line = await Line.open(gw)
        try:
            gw.write("lb/m1/do1", True)  # the loopback back echoes it to di1
            await until(lambda: gw.read("lb/m1/di1") is True)
            # the child sees what the fieldbus process has, quality included
            for _ in range(100):
                if await line.ask("get lb/m1/di1") == f"lb/m1/di1 True {Quality.GOOD}":
                    break
                await asyncio.sleep(0.05)
            assert await line.ask("get lb/m1/di1") == f"lb/m1/di1 True {Quality.GOOD}"
            assert int(await line.ask("batches")) >= 1
        finally:
            line.close()
        children = gw.status()["children"]
        assert children["probe"]["pid"] == pid and children["probe"]["state"] == "running"


async def test_a_client_write_is_applied_before_it_is_acknowledged(registry):
    async with Gateway.load(topology(), registry=registry) as gw:
        line = await Line.open(gw)
        try:
            for value in (7, 12345, -3):
                assert await line.ask(f"set lb/m1/ao0 {value}") == "ok"
                # acknowledged: already in the fieldbus process's image, written by the front
                assert gw.read("lb/m1/ao0") == value
                assert gw.image["lb/m1/ao0"].written_by == "probe"
        finally:
            line.close()
        assert gw.component("probe").child.writes_applied == 3


async def test_writes_outside_the_front_s_writable_outputs_are_refused_by_the_fieldbus_side(
    registry,
):
    async with Gateway.load(topology(), registry=registry) as gw:
        line = await Line.open(gw)
        try:
            # a digital output the probe serves but may not write: refused, nothing written
            answer = await line.ask("set lb/m1/do0 1")
            assert answer.startswith("refused:") and "not an output front probe may write" in answer
            assert gw.read("lb/m1/do0") is False
            answer = await line.ask("set lb/m1/ao1 99999999")  # outside int16
            assert answer.startswith("refused:") and "int16" in answer
            assert gw.read("lb/m1/ao1") == 0
            answer = await line.ask("set lb/m1/ai0 1")  # an input
            assert answer.startswith("refused:") and "input" in answer
        finally:
            line.close()
        assert (
            gw.component("probe").child.writes_refused == 1
        )  # the other two: checked in the child


async def test_status_metrics_and_locations_come_from_the_child(registry):
    async with Gateway.load(topology(), registry=registry) as gw:
        status = await probe_status(gw)
        assert status["state"] == "listening"
        assert status["process"]["rss_mb"] >= 0 and status["process"]["memory_limit_mb"] == 384
        names = {s[0] for s in gw.component("probe").metrics()}
        assert {"probe_batches_total", "child_resident_bytes", "child_resyncs_total"} <= names
        assert gw.component("probe").point_locations() == {"lb/m1/ao0": ["probe line 1"]}


async def test_a_child_whose_event_loop_hangs_is_killed_and_restarted(registry):
    topo = topology(isolation={"liveness_timeout_s": 1.0}, restart_backoff_s=0.1)
    async with Gateway.load(topo, registry=registry) as gw:
        front = gw.component("probe")
        first = front.child.process.pid
        line = await Line.open(gw)
        line.writer.write(b"hang 30\n")  # its loop blocks for 30 s
        await until(lambda: gw.restarts("probe") == 1 and front.child.state == "running")
        line.close()
        assert front.child.process.pid != first
        assert front.child.kills == {"liveness": 1}
        # the fieldbus side ran on meanwhile, and the new child serves
        gw.write("lb/m1/ao1", 5)
        line = await Line.open(gw)
        try:
            assert await line.ask("set lb/m1/ao0 9") == "ok" and gw.read("lb/m1/ao0") == 9
        finally:
            line.close()


async def test_a_child_over_its_memory_limit_is_killed_and_restarted(registry):
    topo = topology(isolation={"memory_limit_mb": 120}, restart_backoff_s=0.1)
    async with Gateway.load(topo, registry=registry) as gw:
        front = gw.component("probe")
        line = await Line.open(gw)
        with contextlib.suppress(ConnectionError, asyncio.IncompleteReadError, TimeoutError):
            for _ in range(8):
                await line.ask("eat 50", timeout=5)
        line.close()
        await until(lambda: gw.restarts("probe") == 1 and front.child.state == "running")
        assert front.child.kills == {"memory limit": 1}
        assert front.child.peak_rss > 120 * 2**20


async def test_a_front_that_fails_at_run_time_is_restarted_with_back_off(registry):
    async with Gateway.load(topology(restart_backoff_s=0.1), registry=registry) as gw:
        front = gw.component("probe")
        line = await Line.open(gw)
        assert await line.ask("crash") == "crashing"
        line.close()
        await until(lambda: gw.restarts("probe") == 1 and front.child.state == "running")
        assert "probe" not in gw.down


async def test_a_child_killed_from_outside_is_restarted(registry):
    async with Gateway.load(topology(restart_backoff_s=0.1), registry=registry) as gw:
        front = gw.component("probe")
        first = front.child.process.pid
        os.kill(first, signal.SIGKILL)
        await until(lambda: gw.restarts("probe") == 1 and front.child.state == "running")
        assert front.child.process.pid != first


async def test_a_front_s_start_failure_stops_the_gateway_with_its_own_reason(registry):
    gw = Gateway.load(topology(fail_start="port 4840 in use"), registry=registry)
    with pytest.raises(GatewayStartError, match=r"^front probe \(probe\): port 4840 in use$"):
        await gw.start()
    assert gw.component("lb").started is False


async def test_a_child_that_falls_behind_in_time_skips_to_a_fresh_snapshot(registry):
    topo = topology(isolation={"feed_max_lag_ms": 300, "liveness_timeout_s": 30})
    async with Gateway.load(topo, registry=registry) as gw:
        front = gw.component("probe")
        line = await Line.open(gw)
        try:
            line.writer.write(b"hang 2\n")  # its loop sleeps 2 s; the image changes meanwhile
            for value in range(200):
                gw.write("lb/m1/ao1", value)
                await asyncio.sleep(0.005)
            assert (await asyncio.wait_for(line.reader.readline(), 20)).strip() == b"woke"
            await until(lambda: front.child.outbox.resyncs >= 1)
            # once the snapshot is in, the child holds the latest value
            for _ in range(100):
                if await line.ask("get lb/m1/ai1") == f"lb/m1/ai1 199 {Quality.GOOD}":
                    break
                await asyncio.sleep(0.05)
            assert await line.ask("get lb/m1/ai1") == f"lb/m1/ai1 199 {Quality.GOOD}"
            status = await probe_status(gw)
            await until(lambda: front.status().get("feed_changes_skipped", 0) > 0)
            assert status["process"]["resyncs"] >= 1
        finally:
            line.close()
