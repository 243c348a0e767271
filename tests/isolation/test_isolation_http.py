"""The HTTP status server in its child process: it serves the fieldbus process's state from a
mirror, says on /healthz when the fieldbus process stops answering, and is restarted when it
dies; the fieldbus side never waits for it."""

from __future__ import annotations

import asyncio
import json
import os
import signal

from fieldgate import Gateway

from .test_isolation_children import topology, until


async def http_get(port: int, path: str) -> tuple[int, bytes]:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode())
    raw = await asyncio.wait_for(reader.read(), 10)
    writer.close()
    head, _, body = raw.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


def with_http(**extra: object) -> dict:
    topo = topology(**extra)
    topo["gateway"]["http"] = {"listen": "127.0.0.1:0", "metrics_max_age_ms": 0}  # type: ignore[index]
    return topo


def port_of(gw: Gateway) -> int:
    return int(gw.http.url.rsplit(":", 1)[1].strip("/"))


async def test_the_status_server_runs_in_a_child_and_serves_the_gateway_from_its_mirror(registry):
    async with Gateway.load(with_http(), registry=registry) as gw:
        child = gw.http.child
        assert child.process.pid != os.getpid()
        port = port_of(gw)
        gw.write("lb/m1/ao1", 321)  # the loopback back echoes it to ai1

        async def point() -> dict:
            status, body = await http_get(port, "/api/v1/points/lb/m1/ai1")
            assert status == 200
            return json.loads(body)

        for _ in range(100):
            if (await point())["value"] == 321:
                break
            await asyncio.sleep(0.05)
        assert (await point())["value"] == 321 and (await point())["quality"] == "good"
        # readiness and the components' status come once a second from the fieldbus process
        for _ in range(60):
            status, body = await http_get(port, "/api/v1/status")
            report = json.loads(body)
            if report["ready"] and "process" in report["fronts"]["probe"]:
                break
            await asyncio.sleep(0.1)
        assert report["ready"] and report["children"]["http"]["pid"] == child.process.pid
        assert report["fronts"]["probe"]["process"]["state"] == "running"
        assert (await http_get(port, "/readyz"))[0] == 200
        status, metrics = await http_get(port, "/metrics")
        assert b'fieldgate_child_resident_bytes{component="probe",front="probe"}' in metrics
        assert b"fieldgate_probe_batches_total" in metrics
        status, body = await http_get(port, "/healthz")
        assert status == 200 and b"fieldbus event loop" in body


async def test_healthz_says_when_the_fieldbus_process_stops_answering(registry):
    gw = Gateway.load(with_http(), registry=registry)
    await gw.start()
    try:
        port = port_of(gw)
        assert (await http_get(port, "/healthz"))[0] == 200
        # the fieldbus process stops (as a stalled loop would): no pings reach the child
        os.kill(os.getpid(), 0)
        for task in gw.http.child._tasks:
            if task.get_name().endswith(":watch"):
                task.cancel()
        await asyncio.sleep(2.5)
        status, body = await http_get(port, "/healthz")
        assert status == 503 and b"has not been heard from" in body
    finally:
        await gw.stop()


async def test_a_killed_status_server_is_restarted_and_the_fieldbus_side_runs_on(registry):
    async with Gateway.load(with_http(), registry=registry) as gw:
        first = gw.http.child.process.pid
        os.kill(first, signal.SIGKILL)
        gw.write("lb/m1/do0", True)  # the fieldbus side does not wait for it
        assert gw.read("lb/m1/di0") is True
        await until(lambda: gw.http.restarts == 1 and gw.http.child.state == "running")
        assert gw.http.child.process.pid != first
        status, _ = await http_get(port_of(gw), "/readyz")
        assert status in (200, 503)  # it answers (ready once its first report arrived)
