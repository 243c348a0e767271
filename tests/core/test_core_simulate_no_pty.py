"""``fieldgate run --simulate`` where no pseudo-terminal can be opened: one start error, exit 2."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fieldgate.serial_link import PtyPair

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "i7232d-style.yaml"

# os.openpty fails the way it does in a container without /dev/pts or past the pty limit
NO_PTY = """
import errno, os, sys
def openpty():
    raise OSError(errno.ENOENT, "No such file or directory")
os.openpty = openpty
from fieldgate.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_run_simulate_without_pseudo_terminals_is_one_start_error_and_exit_2() -> None:
    result = subprocess.run(
        [sys.executable, "-c", NO_PTY, "run", str(EXAMPLE), "--simulate", "--duration", "5"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1, result.stderr
    assert errors[0].endswith(
        "cannot start: back rs485 (modbus): cannot open a pseudo-terminal for its simulated"
        " modules: No such file or directory"
    )


def test_a_pty_pair_that_cannot_open_its_second_end_closes_the_first(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    opened: list[int] = []
    real_openpty = os.openpty

    def openpty_once() -> tuple[int, int]:
        if opened:
            raise OSError(errno.EAGAIN, "Resource temporarily unavailable")
        master, slave = real_openpty()
        opened.extend((master, slave))
        return master, slave

    monkeypatch.setattr(os, "openpty", openpty_once)
    with pytest.raises(OSError, match="Resource temporarily unavailable"):
        PtyPair()
    assert len(opened) == 2
    for fd in opened:  # both closed: fstat on a closed descriptor fails
        with pytest.raises(OSError):
            os.fstat(fd)
