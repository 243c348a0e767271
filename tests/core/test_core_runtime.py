"""Gateway life cycle: start order, stop with shutdown values, start failures, run-time restarts."""

import asyncio
import signal
import subprocess
import sys
import textwrap

import pytest

from fieldgate import Gateway, GatewayStartError, Quality


async def test_start_read_write_and_loopback_through_the_api(registry, topology_dict):
    async with Gateway.load(topology_dict(), registry=registry) as gw:
        assert [c.name for c in gw.backs] == ["io"] and [c.name for c in gw.fronts] == ["plc"]
        gw.write("io/m3/do1", True)
        assert gw.read("io/m3/di1") is True and gw.image["io/m3/di1"].quality is Quality.GOOD
        front = gw.component("plc")
        # default order: modules by ascending address, then channel index
        assert front.channels[:2] == ["io/m1/di0", "io/m1/do0"]
        assert gw.status()["fronts"]["plc"]["master_ok"] is True
    assert front.stopped and not gw.running


async def test_master_lost_applies_error_modes_once(registry, topology_dict):
    async with Gateway.load(topology_dict(), registry=registry) as gw:
        front = gw.component("plc")
        changed = front.lose_master()
        assert sorted(changed) == [
            "io/m3/ao0",
            "io/m3/do0",
            "io/m3/do1",
        ]  # module 3 has error_mode value 1
        assert (
            gw.read("io/m3/ao0") == 1 and gw.read("io/m3/di0") is True
        )  # looped back to the input
        assert gw.read("io/m1/do0") is False  # module 1 holds
        gw.write("io/m3/do0", False)
        assert front.lose_master() == []  # already lost: nothing re-applied
        assert gw.status()["fronts"]["plc"]["master_ok"] is False
        gw.masters.ok("plc")
        assert gw.masters.all_ok


async def test_stop_applies_shutdown_values(registry, topology_dict):
    gw = Gateway.load(topology_dict(), registry=registry)
    await gw.start()
    gw.write("io/m3/do0", True)
    await gw.stop()
    assert gw.read("io/m3/do0") is False and gw.read("io/m3/ao0") == 0


async def test_start_failure_names_component_and_cause_and_stops_the_rest(registry, topology_dict):
    gw = Gateway.load(topology_dict(fail_start="permission denied on can0"), registry=registry)
    with pytest.raises(
        GatewayStartError, match=r"^front plc \(memory\): permission denied on can0$"
    ):
        await gw.start()
    back = gw.component("io")
    assert back._sub is None  # the back that had started was stopped again
    assert not gw.running


async def test_run_time_failure_marks_channels_comm_fault_and_restarts_with_backoff(
    registry, topology_dict, caplog
):
    topo = topology_dict()
    topo["backs"][0].update(fail_after_s=0.05, restart_backoff_s=0.05)
    gw = Gateway.load(topo, registry=registry)
    await gw.start()
    back = gw.component("io")
    seen = []
    gw.image.subscribe(lambda ch: seen.append(ch.quality), ids=["io/m1/di0"])
    try:
        for _ in range(100):
            await asyncio.sleep(0.02)
            if back.starts >= 3:
                break
        assert back.starts >= 3
        assert Quality.COMM_FAULT in seen
        assert gw.status()["backs"]["io"]["restarts"] >= 2
        assert (
            "back io failed: RuntimeError: injected run-time failure; restarting in 0.1 s"
            in caplog.text
        )
    finally:
        await gw.stop()


TOPOLOGY = textwrap.dedent(
    """\
    gateway: {name: cli}
    fronts:
      - {name: plc, type: memory}
    backs:
      - name: io
        type: loopback
        modules: [{address: 1, digital: 1, shutdown_mode: {value: 1}}]
    """
)


def cli(*args):
    return [sys.executable, "-m", "fieldgate", *args]


def test_cli_start_failure_is_one_clear_line_and_exit_2(tmp_path):
    path = tmp_path / "t.yaml"
    path.write_text(TOPOLOGY)
    result = subprocess.run(
        cli(
            "run", str(path), "--set", "backs.io.fail_start=cannot open /dev/ttyS9: no such device"
        ),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2
    errors = [line for line in result.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and errors[0].endswith(
        "cannot start: back io (loopback): cannot open /dev/ttyS9: no such device"
    )
    assert "Traceback" not in result.stderr


def test_cli_invalid_file_exit_1_with_line(tmp_path):
    path = tmp_path / "t.yaml"
    path.write_text(TOPOLOGY.replace("type: memory", "type: profibus"))
    result = subprocess.run(cli("run", str(path)), capture_output=True, text=True, timeout=30)
    assert result.returncode == 1
    assert f"{path}:3:" in result.stderr and "front type 'profibus'" in result.stderr


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_cli_signal_stops_cleanly_with_exit_0_and_shutdown_values(tmp_path, sig):
    path = tmp_path / "t.yaml"
    path.write_text(TOPOLOGY)
    proc = subprocess.Popen(
        cli("--log-level", "info", "run", str(path)), stderr=subprocess.PIPE, text=True
    )
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if "running" in line:
            break
    proc.send_signal(sig)
    rest = proc.communicate(timeout=20)[1]
    log = "".join(lines) + rest
    assert proc.returncode == 0, log
    assert "shutdown values applied to 1 output(s)" in log and "gateway cli stopped" in log


def test_cli_validate_prints_a_summary(tmp_path):
    path = tmp_path / "t.yaml"
    path.write_text(TOPOLOGY)
    result = subprocess.run(cli("validate", str(path)), capture_output=True, text=True, timeout=30)
    assert result.returncode == 0
    assert "gateway cli: 1 front(s), 1 back(s), 1 module(s), 2 channel(s)" in result.stdout
    assert "1 DI, 1 DO, 0 AI, 0 AO" in result.stdout


def test_status_line_groups_modules_and_flags_bad_quality():
    from fieldgate import ChannelSpec, Kind, ProcessImage, Quality, Source
    from fieldgate.cli import format_image

    image = ProcessImage()
    for i in range(3):
        image.add(ChannelSpec(f"b/m1/di{i}", Kind.DI, Source("b", 1, i)))
    image.add(ChannelSpec("b/m2/ai0", Kind.AI, Source("b", 2, 0)))
    image.update_input("b/m1/di0", True)
    image.update_input("b/m1/di1", False)
    image.update_input("b/m1/di2", True)
    image.update_input("b/m2/ai0", -5)
    image.set_quality(["b/m2/ai0"], Quality.COMM_FAULT)
    assert format_image(image) == "b/m1 di=101 | b/m2 ai=[-5]!comm-fault"


async def test_simulated_lines_drop_parity_a_pty_cannot_carry(registry):
    """examples/devicenet-modbus.yaml uses parity E; under --simulate it must still run."""
    from fieldgate.simulation import SimulationBench
    from fieldgate.topology import load_topology

    topo = load_topology(
        {
            "gateway": {"name": "sim"},
            "fronts": [{"name": "plc", "type": "memory"}],
            "backs": [
                {
                    "name": "rs485",
                    "type": "modbus",
                    "port": "/dev/null",
                    "parity": "E",
                    "modules": [{"address": 1, "model": "M-7055D"}],
                }
            ],
        },
        registry,
    )
    bench = SimulationBench(topo, registry)
    await bench.start()
    try:
        assert topo.backs[0].parity == "N" and topo.backs[0].port.startswith("/dev/pts/")
    finally:
        await bench.stop()


async def run_and_stop_with_back_run(run, registry, topology_dict, monkeypatch) -> Gateway:
    """Start a gateway whose loopback back runs ``run``, then stop it within 5 s (or fail)."""
    monkeypatch.setattr(registry.lookup("back", "loopback").factory, "run", run)
    gw = Gateway.load(topology_dict(), registry=registry)
    await gw.start()
    await asyncio.sleep(0.01)
    async with asyncio.timeout(5):
        await gw.stop()
    return gw


async def test_stop_cancels_again_a_component_that_swallows_its_cancellation(
    registry, topology_dict, monkeypatch, caplog
):
    """Gateway.stop() never hangs on a task that lost a cancellation (asyncio.wait_for in 3.11 can)."""
    from fieldgate import runtime

    monkeypatch.setattr(runtime, "CANCEL_GRACE_S", 0.02)
    swallowed = 0

    async def stubborn_run(self):
        nonlocal swallowed
        while True:
            try:
                await asyncio.sleep(3600)
            except asyncio.CancelledError:
                if swallowed == 3:
                    raise
                swallowed += 1

    gw = await run_and_stop_with_back_run(stubborn_run, registry, topology_dict, monkeypatch)
    assert swallowed == 3 and not gw.running
    assert (
        sum(
            "still running" in r.getMessage() and "back io" in r.getMessage()
            for r in caplog.records
        )
        == 3
    )


async def test_stop_gives_up_on_a_component_that_never_stops_and_says_so(
    registry, topology_dict, monkeypatch, caplog
):
    from fieldgate import runtime

    monkeypatch.setattr(runtime, "CANCEL_GRACE_S", 0.01)
    monkeypatch.setattr(runtime, "CANCEL_ATTEMPTS", 3)
    release = asyncio.Event()

    async def deaf_run(self):
        while not release.is_set():
            try:
                await asyncio.sleep(3600)
            except asyncio.CancelledError:
                pass

    gw = await run_and_stop_with_back_run(deaf_run, registry, topology_dict, monkeypatch)
    assert not gw.running
    assert any("back io does not stop when cancelled" in r.getMessage() for r in caplog.records)
    release.set()  # let the abandoned task end so that the test's loop can close
    for task in [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]:
        task.cancel()


def test_restart_delays_double_up_to_a_minute_and_start_over_after_a_stable_run():
    from fieldgate.backoff import Backoff

    b = Backoff(1.0)
    assert [b.next() for _ in range(8)] == [1, 2, 4, 8, 16, 32, 60, 60]
    b.ran(59.0)  # failed again within the minute: still backing off
    assert b.next() == 60
    b.ran(60.0)  # ran a minute: the next failure is a new story
    assert [b.next() for _ in range(2)] == [1, 2]
    long_first = Backoff(300.0)  # a first delay above the cap is never shortened
    assert [long_first.next() for _ in range(3)] == [300, 300, 300]


async def test_a_component_whose_stop_never_returns_is_left_behind_and_logged(
    registry, topology_dict, monkeypatch, caplog
):
    """Issue 33: a stop is bounded; a back that never finishes stopping is logged and left
    behind (the process exits anyway) instead of holding the service manager's stop."""
    from fieldgate import runtime

    monkeypatch.setattr(runtime, "STOP_TIMEOUT_S", 0.05)
    never = asyncio.Event()
    stops = 0

    async def stuck_stop(self):
        nonlocal stops
        stops += 1
        await never.wait()

    monkeypatch.setattr(registry.lookup("back", "loopback").factory, "stop", stuck_stop)
    gw = Gateway.load(topology_dict(), registry=registry)
    await gw.start()
    async with asyncio.timeout(5):
        await gw.stop()
    assert stops == 1 and not gw.running
    assert any(
        "back io: still stopping after" in r.getMessage() and "left behind" in r.getMessage()
        for r in caplog.records
    )
