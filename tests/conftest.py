"""Fixtures shared by the test directories."""

from __future__ import annotations

import os
import pty
import subprocess
import sys

import pytest


@pytest.fixture
def stopped_by_signal():
    """``stop(args, ready, sig)``: run ``python -m fieldgate *args`` with a terminal as its stdin
    (a simulator reads commands there), wait for an output line starting with ``ready``, send
    ``sig``; returns (exit code, standard error). The process never outlives the test."""

    def stop(args: list[str], ready: str, sig: int) -> tuple[int, str]:
        master, terminal = pty.openpty()
        proc = subprocess.Popen(
            [sys.executable, "-m", "fieldgate", *args],
            stdin=terminal,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        try:
            assert any(line.startswith(ready) for line in iter(proc.stdout.readline, "")), (
                f"no line starting {ready!r}"
            )
            proc.send_signal(sig)
            return proc.wait(timeout=20), proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            proc.stdout.close()
            proc.stderr.close()
            os.close(master)
            os.close(terminal)

    return stop


def pytest_collection_modifyitems(config, items):
    """In a slow SocketCAN guest (QEMU's software emulation), each test's time limit
    stretches by the slowdown `.ci/socketcan/run` measured, as its waits do."""
    from socketcan_guest import SLOWDOWN

    if SLOWDOWN <= 1:
        return
    default = float(config.getini("timeout") or 0)
    for item in items:
        marker = item.get_closest_marker("timeout")
        limit = marker.args[0] if marker is not None and marker.args else default
        if limit:
            item.add_marker(pytest.mark.timeout(limit * SLOWDOWN), append=False)


@pytest.fixture
def kernel(monkeypatch: pytest.MonkeyPatch):
    """Every CAN front started in this test controls its interface through a fake kernel
    (tests/fake_can_link.py), whatever its python-can interface: the tests' buses are virtual."""
    from functools import partial

    from fake_can_link import FakeKernel

    from fieldgate.can import front as canfront
    from fieldgate.can.interface import InterfaceControl

    fake = FakeKernel()
    monkeypatch.setattr(canfront, "controls", lambda interface, channel: True)
    monkeypatch.setattr(canfront, "InterfaceControl", partial(InterfaceControl, ops=fake.ops))
    return fake
