"""The test fixtures fieldgate ships (``fieldgate.testing``, a pytest plugin through the
``pytest11`` entry point) do what docs/plugins.md says, against the real system."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fieldgate import Quality
from fieldgate.testing import ANY, assert_channel, wait_for_channel

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "i7232d-style.yaml"


def overrides(tmp_path: Path, **more: object) -> dict[str, object]:
    return {
        "gateway.state_dir": str(tmp_path / "state"),
        "fronts.can.channel": f"fg-testing-{tmp_path.name[-10:]}",
        **more,
    }


async def test_gateway_fixture_and_the_channel_helpers(fieldgate_gateway, tmp_path):
    async with fieldgate_gateway(EXAMPLE, overrides(tmp_path)) as gw:
        simulator = gw.bench.simulator("rs485")
        simulator.set_input("rs485/m5/ai0", 1234)
        channel = await wait_for_channel(gw.image, "rs485/m5/ai0", 1234)
        assert (channel.value, channel.quality) == (1234, Quality.GOOD)
        assert_channel(gw.image, "rs485/m5/ai0", 1234)
        with pytest.raises(AssertionError) as wrong:
            assert_channel(gw.image, "rs485/m5/ai0", 99)
        assert str(wrong.value).startswith("rs485/m5/ai0 is 1234 (good); expected 99 (good)")
        with pytest.raises(AssertionError) as late:
            await wait_for_channel(gw.image, "rs485/m5/ai0", quality="comm-fault", timeout=0.2)
        assert str(late.value).startswith(
            "rs485/m5/ai0 is 1234 (good) after 0.2 s; expected (comm-fault)"
        )
        assert_channel(gw.image, "rs485/m3/do0", ANY, quality=None)  # anything, any quality


def test_thread_fixture_for_synchronous_tests(fieldgate_thread, tmp_path):
    dut = fieldgate_thread(EXAMPLE, overrides(tmp_path))
    dut.call(lambda: dut.simulator("rs485").set_input("rs485/m1/di5", True))
    assert dut.wait_for_channel("rs485/m1/di5", True) == (True, Quality.GOOD)
    dut.write("rs485/m3/do1", True)
    assert dut.read("rs485/m3/do1") is True
    dut.stop()
    assert not dut.running
    dut.start()  # a power cycle: a new gateway of the same topology
    assert dut.running and dut.channel("rs485/m3/do1")[0] is False


def test_pty_fixture(fieldgate_pty):
    pair = fieldgate_pty()
    with open(pair.a, "wb", buffering=0) as a, open(pair.b, "rb", buffering=0) as b:
        a.write(b"ping\r")
        assert b.read(5) == b"ping\r"


async def test_http_fixture_reads_the_status_api(fieldgate_gateway, fieldgate_http, tmp_path):
    gateway = fieldgate_gateway(
        EXAMPLE, overrides(tmp_path, **{"gateway.http.listen": "127.0.0.1:0"})
    )
    async with gateway as gw:
        client = fieldgate_http(gw)
        status = await client.status()
        assert status["gateway"] == "i7232d" and status["ready"] is True
        missing = await client.get("/api/v1/points/nope")
        assert missing.status == 404


def test_a_plugin_s_tests_get_the_fixtures_from_the_entry_points_alone(tmp_path):
    """A test file outside this repository's conftests, run by a fresh pytest: the fixtures
    come from the installed distributions' ``pytest11`` entry points."""
    (tmp_path / "test_user.py").write_text(
        "def test_fixtures(request):\n"
        "    names = ('fieldgate_registry', 'fieldgate_gateway', 'fieldgate_thread',\n"
        "             'fieldgate_pty', 'fieldgate_http', 'canopen_master', 'devicenet_scanner')\n"
        "    for name in names:\n"
        "        assert request.getfixturevalue(name) is not None, name\n"
        "    registry = request.getfixturevalue('fieldgate_registry')\n"
        "    assert registry.lookup('back', 'modbus') is not None\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")}
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_user.py"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 passed" in result.stdout


def test_a_gateway_left_running_fails_the_test(tmp_path):
    (tmp_path / "test_left.py").write_text(
        "import asyncio\n"
        f"EXAMPLE = {str(EXAMPLE)!r}\n"
        "def test_left(fieldgate_gateway):\n"
        "    gw = fieldgate_gateway(EXAMPLE, {'fronts.can.channel': 'fg-left'})\n"
        "    loop = asyncio.new_event_loop()\n"
        "    loop.run_until_complete(gw.start())\n"
    )
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_left.py"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 1
    assert "gateway(s) i7232d still running: use async with gateway: ..." in result.stdout


def test_wait_for_channel_is_woken_by_the_change_not_by_polling():
    from fieldgate import ChannelSpec, Kind, ProcessImage, Source

    async def scenario() -> None:
        image = ProcessImage()
        image.add(ChannelSpec("io/m1/ai0", Kind.AI, Source("io", 1, 0)))
        waiter = asyncio.create_task(wait_for_channel(image, "io/m1/ai0", 5, timeout=30))
        await asyncio.sleep(0)
        assert not waiter.done()
        image.update_input("io/m1/ai0", 5)  # the subscription wakes it: no time has to pass
        for _ in range(10):
            await asyncio.sleep(0)
        assert waiter.done() and waiter.result().value == 5

    asyncio.run(scenario())
