""".ci/uml/run itself: the command's output and exit code come back, and a hung guest times out.

Runs on the host (not inside UML) when linux.uml is installed; each case boots a guest (2-4 s).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
RUN = REPO / ".ci" / "uml" / "run"

pytestmark = pytest.mark.skipif(
    shutil.which("linux.uml") is None or os.environ.get("FIELDGATE_UML") == "1",
    reason="needs linux.uml on the host (.ci/uml/run installs it), and not already inside UML",
)


def run(
    *command: str, timeout_s: int | None = None, tmpdir: Path | None = None
) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    if tmpdir is not None:
        env["TMPDIR"] = str(tmpdir)  # the script's work directory (and the guest's memory) go here
    if timeout_s is not None:
        env["FIELDGATE_UML_TIMEOUT"] = str(timeout_s)
    return subprocess.run(
        [str(RUN), *command], capture_output=True, text=True, env=env, timeout=120
    )


def test_command_output_exit_code_and_environment_come_back():
    done = run(
        "sh",
        "-c",
        'echo "on $(cat /sys/class/net/vcan0/type) as $FIELDGATE_TEST_CAN in $PWD"; exit 7',
    )
    assert done.returncode == 7, done.stderr
    # ARPHRD_CAN = 280: vcan0 is a real CAN device in the guest
    assert f"on 280 as socketcan:vcan0 in {REPO}" in done.stdout
    assert "command exit code 7" in done.stderr


def test_arguments_keep_their_quoting():
    done = run("python", "-c", "import sys; print(sys.argv[1:])", "two words", "$HOME", "a'b")
    assert done.returncode == 0, done.stderr
    assert "['two words', '$HOME', \"a'b\"]" in done.stdout


def test_a_hung_guest_times_out_with_124_and_leaves_nothing_behind(tmp_path):
    done = run("sleep", "120", timeout_s=3, tmpdir=tmp_path)
    assert done.returncode == 124, done.stderr
    assert "timed out after 3s" in done.stderr
    # every guest process carries init=<work dir>/init on its command line
    leftovers = subprocess.run(["pgrep", "-f", f"init={tmp_path}"], capture_output=True, text=True)
    assert leftovers.stdout == ""
    assert list(tmp_path.iterdir()) == []  # the work directory is gone


def test_install_only_boots_no_guest(tmp_path):
    done = run("--install", tmpdir=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout == ""
    assert "command exit code" not in done.stderr  # no guest ran a command
    assert list(tmp_path.iterdir()) == []  # no work directory was made
