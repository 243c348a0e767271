"""What the SocketCAN tests with real controller drivers share."""

from __future__ import annotations

import subprocess

import pytest
from socketcan_guest import CONTROLLERS


@pytest.fixture
def pair():
    """The two emulated controllers (`.ci/socketcan/run --can-controllers`), left down and out
    of listen-only mode after the test."""
    a, b = CONTROLLERS[:2]
    yield a, b
    for name in (a, b):
        subprocess.run(["ip", "link", "set", name, "down"], check=False)
        subprocess.run(
            ["ip", "link", "set", name, "type", "can", "listen-only", "off"], check=False
        )
