"""Fixtures of the HTTP tests (helpers in httpkit.py)."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import pytest
from httpkit import Running, load_gateway, start


@pytest.fixture
async def running(tmp_path: Path) -> AsyncIterator[Running]:
    gw = load_gateway(tmp_path)
    r = await start(gw)
    try:
        yield r
    finally:
        await gw.stop()
