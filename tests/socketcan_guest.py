"""What the SocketCAN tests share: the marker that puts them in the guest, and their waits.

`IN_GUEST` is a test module's `pytestmark`: marker `socketcan` (scripts/test runs these
inside the guest of `.ci/socketcan/run`) and a skip wherever the buses do not exist.

`.ci/socketcan/run` measures at boot how much slower than the host its guest runs Python
(`FIELDGATE_SOCKETCAN_SLOWDOWN`: 1.0 on native-speed backends, about 10 under QEMU's software
emulation) and the tests stretch every wait for something to happen by it (`scaled`): a slow
guest then takes longer, it is never skipped. Protocol timing under test (a heartbeat period,
a tolerance the tester allows a device) is scaled only where the test says so.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

SLOWDOWN = max(1.0, float(os.environ.get("FIELDGATE_SOCKETCAN_SLOWDOWN", "1") or 1))


def scaled(seconds: float) -> float:
    """``seconds`` of waiting, as long as it takes in this guest."""
    return seconds * SLOWDOWN


def in_guest(*buses: str) -> list[pytest.MarkDecorator]:
    """The `pytestmark` of a module that needs these SocketCAN buses (default vcan0)."""
    buses = buses or ("vcan0",)
    missing = [bus for bus in buses if not Path(f"/sys/class/net/{bus}").exists()]
    return [
        pytest.mark.socketcan,
        pytest.mark.skipif(
            bool(missing),
            reason=f"no {', '.join(missing)}: real SocketCAN runs inside the guest of"
            " .ci/socketcan/run (scripts/test --socketcan)",
        ),
    ]


IN_GUEST = in_guest()


CONTROLLERS = os.environ.get("FIELDGATE_TEST_CAN_CONTROLLERS", "").split()
"""The emulated CAN controllers' interfaces (`.ci/socketcan/run --can-controllers`), e.g. can0 can1."""


def with_controllers(count: int = 2) -> list[pytest.MarkDecorator]:
    """The `pytestmark` of a module that needs real CAN controller drivers: marker
    `can_controller` (the stage's QEMU run with emulated controllers) and a skip elsewhere."""
    return [
        pytest.mark.can_controller,
        pytest.mark.skipif(
            len(CONTROLLERS) < count,
            reason=f"needs {count} CAN controllers: .ci/socketcan/run --can-controllers"
            " (scripts/test --socketcan runs it)",
        ),
    ]
