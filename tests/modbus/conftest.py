"""Fixtures of the Modbus tests: a real RTU line on a pty pair, driven step by step.

The back's modules, core's LineScheduler and the simulator run their real serial code
over a :class:`PtyPair`; the scheduler's clock is a fake one the tests advance, so which
transaction happens when is deterministic. Reply timeouts are real (and short).
"""

from __future__ import annotations

import pytest
from modbus_line import Line

from fieldgate import load_registry


@pytest.fixture
async def make_line():
    lines: list[Line] = []

    async def factory(modules: list[dict], **kw) -> Line:
        line = Line(modules, **kw)
        lines.append(line)
        return await line.start()

    yield factory
    for line in lines:
        await line.close()


@pytest.fixture(scope="session")
def registry():
    return load_registry()
