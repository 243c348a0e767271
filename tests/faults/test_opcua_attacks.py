"""Issue 29's hostile OPC UA client, each case a regression test: the probes of
scripts/faults/opcua_attacks.py against ``fieldgate run examples/plant-northbound.yaml
--simulate`` in a child process (its listeners on free loopback ports), with smaller
figures than the full campaign (docs/reliability.md). Each asserts the server's answer
(ERR and its status, the close), that a fresh client is still served, and that the case
left no traceback in the gateway's log; the D2 floods also that the gateway's RSS did not
grow by the flood. Before the fix every one of them failed (the figures are in
docs/reliability.md)."""

from __future__ import annotations

import argparse

import opcua_attacks  # scripts/faults (see conftest)
import pytest
import pytest_asyncio

pytestmark = pytest.mark.asyncio(loop_scope="module")

ARGS = argparse.Namespace(
    flood_mb=24, idle=100, sessions=20, items=2000, lifetime=10, publish_s=2.0, settle_s=1.0
)
PROBES = [
    "d2-flood-after-hello",
    "d2-flood-without-hello",
    "d2-chunk-over-buffer",
    "d2-message-over-max",
    "d2-too-many-chunks",
    "first-not-hello",
    "http-request",
    "hello-twice",
    "chunk-shorter-than-header",
    "d7-hello-buffers",
    "d8-endpoint-url",
    "d9-refusals-counted",
    "limits",
    "d1-expired-subscriptions",
    "d4-idle-sockets",
    "d4-other-peer-crowd",
    "d4-sessions",
]


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def gateway():
    gw = await opcua_attacks.GatewayProcess.start(
        sets=("fronts.opcua.hello_timeout_s=1", "fronts.opcua.activation_timeout_s=3")
    )
    try:
        yield gw
    finally:
        gw.stop()


async def test_every_case_of_the_campaign_is_tested_here():
    assert sorted(PROBES) == sorted(opcua_attacks.CASES)


@pytest.mark.parametrize("name", PROBES)
async def test_hostile_client_case(gateway, name):
    log0 = gateway.log_size()
    try:
        outcome = await opcua_attacks.CASES[name](gateway, ARGS)
    except Exception as exc:
        raise AssertionError(
            f"{name}: {exc!r}; the gateway's log:\n{gateway.log_text(log0)[-3000:]}"
        ) from exc
    assert outcome.ok, outcome.line()
    assert gateway.proc.poll() is None, "the gateway exited"
