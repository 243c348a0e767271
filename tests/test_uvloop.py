"""The event loop of ``fieldgate run``: uvloop by default where it is installed, asyncio on request."""

import asyncio
import subprocess
import sys
from pathlib import Path

import pytest

from fieldgate.cli import loop_factory, loop_name

EXAMPLE = Path(__file__).parent.parent / "examples" / "i7232d-style.yaml"


def run(*args, level="warning"):
    return subprocess.run(
        [sys.executable, "-m", "fieldgate", "--log-level", level, *args],
        capture_output=True,
        text=True,
        timeout=60,
    )


def run_demo(tmp_path, *loop_args):
    return run(
        "run",
        str(EXAMPLE),
        "--simulate",
        *loop_args,
        "--status-every",
        "0.5",
        "--duration",
        "2.5",
        "--set",
        f"gateway.state_dir={tmp_path}",
        "--set",
        f"fronts.can.channel=loop-test-{tmp_path.name}",
        level="info",
    )


def assert_demo_ran(result):
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stdout.splitlines() if line.startswith("rs485/m1 di=")]
    assert len(lines) >= 3 and "!" not in lines[-1]  # every channel good
    assert len({line.split(" | ")[0] for line in lines}) >= 2  # the animated inputs changed


def test_the_demo_runs_on_uvloop_by_default(tmp_path):
    pytest.importorskip("uvloop")
    result = run_demo(tmp_path)
    assert_demo_ran(result)
    assert "event loop: uvloop" in result.stderr


def test_the_demo_runs_on_asyncio_when_asked(tmp_path):
    result = run_demo(tmp_path, "--loop", "asyncio")
    assert_demo_ran(result)
    assert "event loop: asyncio" in result.stderr


def test_auto_falls_back_to_asyncio_without_uvloop(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "uvloop", None)  # "import uvloop" raises ImportError
    loop = loop_factory("auto")()
    try:
        assert loop_name(loop) == "asyncio" and isinstance(loop, asyncio.AbstractEventLoop)
    finally:
        loop.close()
    with pytest.raises(SystemExit) as stopped:
        loop_factory("uvloop")
    assert stopped.value.code == 2  # a command line this machine cannot run (README, exit codes)
    assert "--loop uvloop: uvloop is not installed here" in capsys.readouterr().err


def test_auto_and_uvloop_give_uvloop_when_installed():
    uvloop = pytest.importorskip("uvloop")
    assert loop_factory("auto") is uvloop.new_event_loop is loop_factory("uvloop")
    assert loop_factory("asyncio") is asyncio.new_event_loop
    with pytest.raises(ValueError, match="expected one of auto, uvloop, asyncio"):
        loop_factory("trio")


def test_unknown_loop_is_refused():
    result = run("run", str(EXAMPLE), "--loop", "trio")
    assert result.returncode == 2 and "invalid choice: 'trio'" in result.stderr


def test_a_run_with_status_lines_ends_without_asyncio_complaints(tmp_path):
    result = run_demo(tmp_path, "--loop", "asyncio")
    assert_demo_ran(result)
    assert "Task was destroyed but it is pending" not in result.stderr, result.stderr
