"""The Modbus TCP hostile-client campaign (scripts/faults/modbus_tcp_attacks.py), each case
against ``fieldgate run examples/plant-northbound.yaml --simulate`` as a user starts it (its
timeouts shortened to 1 s idle, 0.5 s per request). Each case asserts the behaviour the docs
promise; the figures are the probe's (docs/reliability.md)."""

from __future__ import annotations

import subprocess
import tempfile
from collections.abc import Iterator

import pytest
from modbus_tcp_attacks import CASES, Target, cases_of, start_gateway, status_of

FLOOD = 100


@pytest.fixture(scope="module")
def target() -> Iterator[Target]:
    with tempfile.TemporaryDirectory(prefix="mbtcp-attacks-") as state:
        proc, port, http = start_gateway(state, idle_timeout=1.0, request_timeout=0.5)
        try:
            yield Target(port, lambda: status_of(http), proc.pid)
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def test_every_case_is_in_the_campaign(target):
    assert list(cases_of(target, FLOOD)) == CASES


@pytest.mark.parametrize("case", CASES)
async def test_case(case, target):
    outcome = await cases_of(target, FLOOD)[case]()
    assert outcome.ok, outcome.line()


async def test_the_refusals_are_counted(target):
    """Run last: what the cases did shows in the front's counters (status API, /metrics)."""
    counters = await target.counters_after()
    for key in (
        "closed_evicted",
        "closed_idle_timeout",
        "closed_request_timeout",
        "closed_malformed",
        "unknown_function",
        "pipeline_full",
    ):
        assert counters.get(key, 0) > 0, key
    assert counters["closed_malformed"] >= 7
