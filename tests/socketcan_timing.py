"""Waits of the SocketCAN tests, scaled to the guest they run in.

`.ci/socketcan/run` measures at boot how much slower than the host its guest runs Python
(`FIELDGATE_SOCKETCAN_SLOWDOWN`: 1.0 on native-speed backends, about 10 under QEMU's software
emulation) and the tests stretch every wait for something to happen by it: a slow guest
then takes longer, it is never skipped. Protocol timing under test (a heartbeat period, a
tolerance the tester allows a device) is scaled only where the test says so.
"""

from __future__ import annotations

import os

SLOWDOWN = max(1.0, float(os.environ.get("FIELDGATE_SOCKETCAN_SLOWDOWN", "1") or 1))


def scaled(seconds: float) -> float:
    """``seconds`` of waiting, as long as it takes in this guest."""
    return seconds * SLOWDOWN
