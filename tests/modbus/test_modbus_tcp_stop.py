"""Stopping a gateway whose ``modbus-tcp-client`` back is connecting to a host that does not
answer (issue 33: a stop is as quick as a start): the connect in progress is cancelled, the
stop does not wait for ``connect_timeout_ms``."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest
from netkit import blackhole_port

from fieldgate import Gateway, load_registry
from fieldgate.testing import wait_until


@pytest.fixture
def blackhole() -> Iterator[int]:
    with blackhole_port() as port:
        if port is None:
            pytest.skip("this kernel answers SYNs beyond a full backlog: no loopback blackhole")
        yield port


def topology(port: int) -> dict:
    return {
        "gateway": {"name": "t"},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [
            {
                "name": "net",
                "type": "modbus-tcp-client",
                "connect_timeout_ms": 60_000,  # far longer than any stop may take
                "offline_probe_ms": 60_000,
                "modules": [
                    {
                        "address": 1,
                        "host": f"127.0.0.1:{port}",
                        "channels": [{"kind": "ao", "table": "holding_registers", "address": 0}],
                    }
                ],
            }
        ],
    }


async def test_a_back_connecting_to_a_blackholed_host_stops_at_once(blackhole):
    gw = Gateway.load(topology(blackhole), registry=load_registry())
    await gw.start()
    back = gw.component("net")
    (link,) = (link for links in back.links.values() for link in links)  # type: ignore[attr-defined]
    await wait_until(lambda: link.attempts >= 1, 5)
    assert not link.connected  # the connect is in progress (its timeout is a minute)
    gw.write("net/m1/ao0", 5)  # a shutdown value it cannot write: flush must not wait either
    loop = asyncio.get_running_loop()
    started = loop.time()
    async with asyncio.timeout(10):  # a hang detector, not a speed target
        await gw.stop()
    assert loop.time() - started < 5, "the stop waited for the connect"
    assert not gw.running and not link.connected
