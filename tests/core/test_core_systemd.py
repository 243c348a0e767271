"""``fieldgate run`` as a systemd ``Type=notify`` service: the shipped unit's own command line
under a fake notify socket sends READY once started, WATCHDOG while the event loop runs and
none while it is stalled, STATUS, and STOPPING on SIGTERM; the unit passes systemd's checks."""

from __future__ import annotations

import asyncio
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from fieldgate import Gateway, load_registry
from fieldgate.systemd import Notifier, socket_address, status_line, watchdog_period
from fieldgate.unitcmd import unit_text

REPO = Path(__file__).resolve().parents[2]
FIELDGATE = Path(sys.executable).with_name("fieldgate")

TOPOLOGY = """\
gateway: {name: lab}
fronts: [{name: plc, type: memory}]
backs:
  - name: io
    type: loopback
    stall_after_s: 0.6     # once running, block the event loop ...
    stall_s: 1.0           # ... for 10 watchdog periods
    modules: [{address: 1, digital: 2}]
"""


def unit_command(tmp_path: Path, instance: str) -> list[str]:
    """ExecStart of the shipped unit, with %i, %S and /etc/fieldgate/ pointing into tmp_path."""
    (line,) = [x for x in unit_text(str(FIELDGATE)).splitlines() if x.startswith("ExecStart=")]
    command = line.removeprefix("ExecStart=").replace("%i", instance)
    command = command.replace("%S", str(tmp_path / "var-lib"))
    command = command.replace("/etc/fieldgate/", f"{tmp_path}/etc/")
    return shlex.split(command)


class FakeSystemd:
    """The notify socket systemd would own: datagrams in arrival order."""

    def __init__(self, name: str):
        self.name = name
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(socket_address(name))
        self.sock.settimeout(20)
        self.messages: list[str] = []

    def next(self) -> str:
        message = self.sock.recv(4096).decode()
        self.messages.append(message)
        return message

    def until(self, predicate) -> str:
        while not predicate(message := self.next()):
            pass
        return message

    def close(self) -> None:
        self.sock.close()


@pytest.fixture(params=["path", "abstract"])
def systemd(request, tmp_path):
    name = (
        str(tmp_path / "notify.sock")
        if request.param == "path"
        else f"@fieldgate-test-{os.getpid()}-{tmp_path.name}"
    )
    fake = FakeSystemd(name)
    yield fake
    fake.close()


def test_ready_watchdog_from_the_loop_status_and_stopping(systemd, tmp_path):
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "lab.yaml").write_text(TOPOLOGY)
    env = {
        **os.environ,
        "NOTIFY_SOCKET": systemd.name,
        "WATCHDOG_USEC": "200000",  # WATCHDOG=1 every 0.1 s
        "PYTHONUNBUFFERED": "1",
    }
    env.pop("WATCHDOG_PID", None)
    proc = subprocess.Popen(
        unit_command(tmp_path, "lab"),
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        ready = systemd.next()
        assert ready.splitlines() == [
            "READY=1",
            "STATUS=running: 1 front(s), 1 back(s), 0/0 module(s) online",
        ]
        # keep-alives while the loop runs, then the stall: not one while the loop is blocked
        begin = systemd.until(lambda m: m.startswith("X-FIELDGATE-TEST"))
        assert begin == "X-FIELDGATE-TEST=stall-begin"
        assert systemd.messages.count("WATCHDOG=1") >= 2
        assert systemd.next() == "X-FIELDGATE-TEST=stall-end"  # nothing in between
        assert systemd.next() == "WATCHDOG=1"  # and they resume with the loop
        assert systemd.next() == "WATCHDOG=1"
        proc.send_signal(signal.SIGTERM)
        stopping = systemd.until(lambda m: "STOPPING=1" in m)
        assert stopping.splitlines() == ["STOPPING=1", "STATUS=stopping"]
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = proc.stderr.read()
    proc.stdout.close()
    proc.stderr.close()
    assert "Traceback" not in stderr


def test_ready_goes_out_with_the_fieldbus_side_before_the_north_facing_parts(systemd, tmp_path):
    """A north-facing front that takes seconds to start (an OPC UA certificate) never delays
    READY: systemd hears it when the backs and the fieldbus fronts run, the STATUS says what
    still starts, and changes when it runs."""
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "lab.yaml").write_text(
        "gateway: {name: lab}\n"
        "fronts:\n"
        "  - {name: plc, type: memory}\n"
        "  - {name: scada, type: probe, start_s: 3}\n"
        "backs: [{name: io, type: loopback, modules: [{address: 1, digital: 2}]}]\n"
    )
    env = {**os.environ, "NOTIFY_SOCKET": systemd.name, "WATCHDOG_USEC": "1000000"}
    env.pop("WATCHDOG_PID", None)
    proc = subprocess.Popen(
        unit_command(tmp_path, "lab"), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    try:
        ready = systemd.next()
        assert ready.splitlines() == [
            "READY=1",
            "STATUS=running: 2 front(s), 1 back(s), 0/0 module(s) online; starting: scada",
        ]
        running = systemd.until(lambda m: "STATUS=" in m)
        assert "STATUS=running: 2 front(s), 1 back(s), 0/0 module(s) online" in running
        assert "starting" not in running
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()


def test_without_notify_socket_nothing_is_sent_and_a_bad_socket_never_stops_the_gateway(
    tmp_path, caplog
):
    assert Notifier.from_environment({}) is None
    assert Notifier.from_environment({"NOTIFY_SOCKET": "relative/path"}) is None
    gone = Notifier.from_environment({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens")})
    assert gone is not None
    assert gone.send("READY=1") is False and gone.send("WATCHDOG=1") is False
    assert [r.message for r in caplog.records].count(
        "cannot notify the service manager: No such file or directory"
    ) == 1  # logged once, not at every keep-alive
    gone.close()


@pytest.mark.parametrize(
    "environ, period",
    [
        ({"WATCHDOG_USEC": "10000000"}, 10.0),
        ({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid())}, 10.0),
        ({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": "1"}, None),  # meant for another process
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
        ({}, None),
    ],
)
def test_the_watchdog_period_honours_watchdog_usec_and_pid(environ, period):
    assert watchdog_period(environ) == period


async def test_status_is_sent_when_the_summary_changes(tmp_path):
    listener = FakeSystemd(str(tmp_path / "notify.sock"))
    notifier = Notifier(listener.name, watchdog_s=0.02)
    topology = {
        "gateway": {"name": "lab"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 1}]}],
    }
    gw = Gateway.load(topology, registry=load_registry())
    async with gw:
        notifier.ready(status_line(gw))
        task = asyncio.create_task(notifier.keep_alive(lambda: status_line(gw)))
        try:
            loop = asyncio.get_running_loop()
            assert (await loop.run_in_executor(None, listener.next)).startswith("READY=1")
            assert await loop.run_in_executor(None, listener.next) == "WATCHDOG=1"
            gw.component("plc").lose_master("heartbeat timeout")
            changed = await loop.run_in_executor(None, listener.next)
            assert changed.splitlines() == [
                "WATCHDOG=1",
                "STATUS=running: 1 front(s), 1 back(s), 0/0 module(s) online; master lost: plc",
            ]
            assert await loop.run_in_executor(None, listener.next) == "WATCHDOG=1"  # once
        finally:
            task.cancel()
    notifier.close()
    listener.close()


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="no systemd-analyze here")
def test_the_shipped_unit_passes_systemd_analyze_verify(tmp_path):
    unit = tmp_path / "fieldgate@lab.service"
    unit.write_text(unit_text(str(FIELDGATE)))
    result = subprocess.run(
        ["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0 and result.stderr == "", result.stderr
    text = unit.read_text()
    for setting in ("Type=notify", "NotifyAccess=main", "WatchdogSec=", "Restart=on-failure"):
        assert f"\n{setting}" in text


def test_service_unit_prints_this_installation_s_fieldgate():
    out = subprocess.run(
        [str(FIELDGATE), "service-unit"], capture_output=True, text=True, check=True
    ).stdout
    assert f"\nExecStart={FIELDGATE} run /etc/fieldgate/%i.yaml " in out
    assert "/opt/fieldgate/bin/fieldgate" not in out
