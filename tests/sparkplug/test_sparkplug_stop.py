"""Stopping the Sparkplug front is bounded (issue 33): a broker that does not take the
NDEATH and DISCONNECT holds the stop at most ``CLOSE_TIMEOUT_S`` (its will tells the host),
and the journal is closed all the same. No broker needed: the broker is a loopback port
that never answers."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Any

import pytest
from netkit import blackhole_port

from fieldgate.plugin import load_registry
from fieldgate.plugins.sparkplug import front as spb_front
from fieldgate.plugins.sparkplug.link import Link
from fieldgate.runtime import Gateway
from fieldgate.testing import in_this_process, wait_until

INLINE = in_this_process(load_registry(), "sparkplug")


def topology(port: int, state_dir: Path) -> dict[str, Any]:
    return {
        "gateway": {"name": "gw1", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "spb",
                "type": "sparkplug",
                "group_id": "plant",
                "brokers": [{"host": "127.0.0.1", "port": port}],
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 1}]}],
    }


async def test_a_disconnect_the_broker_does_not_take_is_left_after_its_timeout(
    tmp_path, monkeypatch, caplog
):
    caplog.set_level(logging.WARNING)
    monkeypatch.setattr(spb_front, "CLOSE_TIMEOUT_S", 0.05)
    closes = 0

    async def never_closes(self: Link) -> None:  # NDEATH and DISCONNECT into a dead socket
        nonlocal closes
        closes += 1
        self.closed = True
        await asyncio.Event().wait()

    monkeypatch.setattr(Link, "close", never_closes)
    with blackhole_port() as port:
        if port is None:
            pytest.skip("this kernel answers SYNs beyond a full backlog: no loopback blackhole")
        gw = Gateway.load(topology(port, tmp_path / "state"), registry=INLINE)
        await gw.start()
        front = gw.component("spb")
        await wait_until(lambda: front._link is not None, 10)  # type: ignore[attr-defined]
        async with asyncio.timeout(10):  # a hang detector
            await gw.stop()
    assert closes == 1
    assert front.journal is None  # type: ignore[attr-defined]  # closed all the same
    assert "did not take the disconnect" in caplog.text
    assert "left behind" not in caplog.text  # within the front's bound, not the runtime's
