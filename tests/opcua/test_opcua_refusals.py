"""Refusals are counted and logged in one short line each (issue 29 D9): before, an
anonymous session on an endpoint with users was refused by asyncua with two ERROR lines
and no count in the front's counters; a client's bad input could log a traceback each
time. A gateway with users, security None on loopback, and asyncua's client (which, unlike
node-opcua, sends the token it is told to)."""

from __future__ import annotations

import logging

import pytest
import pytest_asyncio
from asyncua import Client
from netkit import free_port

from fieldgate import Gateway, load_registry
from fieldgate.testing import in_this_process, wait_for_report

# the test reads the front's log records: the front is built in this process (in a gateway it
# logs from its child process, within the child's budget: tests/isolation)
REGISTRY = in_this_process(load_registry(), "opcua")
pytestmark = pytest.mark.asyncio(loop_scope="module")


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def gateway(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("FG_UA_REFUSALS_PW", "line4-password")
    port = free_port()
    topology = {
        "gateway": {"name": "cell", "state_dir": str(tmp_path_factory.mktemp("state"))},
        "fronts": [
            {
                "name": "ua",
                "type": "opcua",
                "listen": f"127.0.0.1:{port}",
                "users": [{"name": "scada", "password_env": "FG_UA_REFUSALS_PW"}],
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 50,
                "modules": [{"address": 1, "model": "M-7052D"}],
            }
        ],
    }
    gw = Gateway.load(topology, registry=REGISTRY, simulate=True)
    gw.port = port  # type: ignore[attr-defined]
    await gw.start()
    try:
        yield gw
    finally:
        await gw.stop()
        mp.undo()


async def connect(port: int, user: str | None = None, password: str = "") -> bool:
    client = Client(f"opc.tcp://127.0.0.1:{port}/", timeout=5)
    if user is not None:
        client.set_user(user)
        client.set_password(password)
    try:
        await client.connect()
    except Exception:  # noqa: BLE001  (refused)
        return False
    await client.disconnect()
    return True


async def test_d9_anonymous_and_wrong_users_are_counted_in_short_lines(gateway, caplog):
    caplog.set_level(logging.INFO)
    for _ in range(12):
        assert not await connect(gateway.port)  # anonymous
    assert not await connect(gateway.port, "scada", "wrong")
    assert await connect(gateway.port, "scada", "line4-password")
    status = await wait_for_report(
        gateway, "ua", lambda s: s["counters"]["rejected_bad_credentials"] == 1
    )
    counters = status["counters"]
    assert counters["rejected_anonymous_refused"] == 12
    assert counters["rejected_bad_credentials"] == 1
    faults = status["service_faults"]
    assert faults.get("BadIdentityTokenRejected") == 12 and faults.get("BadUserAccessDenied") == 1
    server_records = [
        r
        for r in caplog.records
        if r.name.startswith(("asyncua.server", "fieldgate")) and "anonymous" in r.getMessage()
    ]
    assert server_records, "the refusal is logged"
    assert len(server_records) <= 6  # a few a minute per reason: the counter has the rest
    assert all(r.levelno <= logging.WARNING and r.exc_info is None for r in server_records)
    assert not [
        r
        for r in caplog.records
        if r.name.startswith("asyncua.server") and r.levelno >= logging.ERROR
    ]
    rows = {(row[0], row[4].get("reason")): row[3] for row in gateway.component("ua").metrics()}
    assert rows[("opcua_rejected_total", "anonymous_refused")] == 12
