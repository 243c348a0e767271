"""The canopen front's 0x2001-0x2003 come from the gateway's one host-watchdog view,
``HostWatchdogs.from_context``: which backs have host watchdogs and their configured
settings are known before any back runs (EDS generation, a front starting first)."""

from __future__ import annotations

import pytest

from fieldgate import Gateway, load_registry
from fieldgate.host_watchdog import HostWatchdogs


@pytest.fixture(scope="module")
def registry():
    registry = load_registry()
    if registry.lookup("back", "dcon") is None:
        pytest.skip("the dcon back plugin is not installed")
    return registry


def topology(tmp_path, *backs) -> dict:
    return {
        "gateway": {"name": "i7231d", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "virtual",
                "channel": "unused",
                "node_id": 1,
            }
        ],
        "backs": list(backs),
    }


DCON = {
    "name": "rs485",
    "type": "dcon",
    "port": "simulated",
    "modules": [
        {"address": 1, "model": "I-7060", "watchdog": {"enabled": True, "timeout_ms": 300}},
        {"address": 2, "model": "I-7052"},
    ],
}
LOOPBACK = {"name": "io", "type": "loopback", "modules": [{"address": 3, "digital": 2}]}


def built_front(tmp_path, registry, *backs):
    from fieldgate.plugins.canopen.plugin import CanopenFront

    gateway = Gateway.load(topology(tmp_path, *backs), registry=registry, simulate=True)
    front = CanopenFront(gateway.topology.fronts[0], gateway.context)
    return gateway, front, front.build()


def test_configured_watchdogs_are_served_before_the_back_runs(tmp_path, registry):
    gateway, front, node = built_front(tmp_path, registry, DCON)
    assert gateway.context.backs == {}  # nothing runs yet
    assert [node.od.get(0x2001, s) for s in range(3)] == [2, 1, 0]  # module 2 keeps its own: off
    assert [node.od.get(0x2002, s) for s in range(3)] == [2, 3, 0]  # 300 ms = 3 x 0.1 s
    assert node.od.get(0x2003, 1) == 0
    expected = HostWatchdogs.from_context(gateway.context)
    served = front.io.manufacturer.host_watchdogs
    assert (
        (served.capable, served.configured)
        == (expected.capable, expected.configured)
        == ({"rs485"}, {("rs485", 1): (True, 300)})
    )
    assert served.backs is gateway.context.backs  # running backs are looked up live


def test_no_watchdog_objects_without_a_watchdog_back(tmp_path, registry):
    _, front, node = built_front(tmp_path, registry, LOOPBACK)
    assert 0x2000 in node.od and 0x2001 not in node.od and 0x2003 not in node.od
    assert front.io.manufacturer.host_watchdogs.capable == set()
