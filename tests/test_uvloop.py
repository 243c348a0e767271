"""``fieldgate run --loop uvloop``: the whole demo (CANopen front, Modbus back, simulators) on uvloop."""

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).parent.parent / "examples" / "i7232d-style.yaml"


def run(*args):
    return subprocess.run([sys.executable, "-m", "fieldgate", "--log-level", "warning", *args], capture_output=True, text=True, timeout=60)


def test_the_demo_runs_on_uvloop(tmp_path):
    pytest.importorskip("uvloop")
    result = run("run", str(EXAMPLE), "--simulate", "--loop", "uvloop", "--status-every", "0.5", "--duration", "2.5",
                 "--set", f"gateway.state_dir={tmp_path}", "--set", "fronts.can.channel=uvloop-test")
    assert result.returncode == 0, result.stderr
    lines = [l for l in result.stdout.splitlines() if l.startswith("rs485/m1 di=")]
    assert len(lines) >= 3 and "!" not in lines[-1]  # every channel good
    assert len({l.split(" | ")[0] for l in lines}) >= 2  # the animated inputs changed


def test_unknown_loop_is_refused():
    result = run("run", str(EXAMPLE), "--loop", "trio")
    assert result.returncode == 2 and "invalid choice: 'trio'" in result.stderr
