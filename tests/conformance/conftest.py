import uuid

import pytest

from fieldgate.conformance import Timing

# fast timing for in-process virtual buses; measured periods keep a generous slack
FAST = dict(response=0.2, silence=0.1, heartbeat_ms=50, bootup=0.5, sdo_server_timeout=1.0, tolerance_ms=20.0)


@pytest.fixture
def fast_timing() -> Timing:
    return Timing(**FAST)


def unique_channel(prefix: str) -> str:
    return f"{prefix}-{uuid.uuid4().hex[:8]}"
