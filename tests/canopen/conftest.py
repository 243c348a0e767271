"""What every CANopen test shares: no gateway it started outlives it."""

from __future__ import annotations

import pytest
from canopen_dut import stop_all_made


@pytest.fixture(autouse=True)
def _no_gateway_outlives_its_test():
    yield
    stop_all_made()
