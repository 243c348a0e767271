"""No verdict depends on the order of the cases (issue 31): fieldgate's canopen front (the
I-7232D-style topology of the gateway tests, in-process on the virtual bus, every profile) is
graded in an order shuffled with a fixed seed and case by case, each alone in a fresh run;
both must give every case the same verdict (test_conformance_gateway.py grades the in-order
run). CI runs the cases alone for a seed-fixed sample of SAMPLE cases (about 35 s with the
shuffled run); all of them (about 2.5 min, about 130 cases):

    FIELDGATE_ORDER_ALL=1 .venv/bin/python -m pytest tests/conformance/test_conformance_order.py

The SocketCAN stage grades the examples themselves in a shuffled order
(test_conformance_examples.py), the independent stacks are graded shuffled on the host
(test_conformance_peers.py)."""

from __future__ import annotations

import os
import random
import uuid

import can
import pytest
from conformance_gateway import NODE_ID, GatewayThread, front_unavailable, topology, write_eds

from fieldgate.conformance import Options, SuiteConfig, Timing, run_suite
from fieldgate.conformance.framework import OPT_IN

TIMING = dict(response=0.3, silence=0.1, heartbeat_ms=50, bootup=1.0, sdo_server_timeout=1.0)
SEED = 31
SAMPLE = 15


def exactly(case_id: str) -> str:
    """A -k pattern that selects this case only (a plain pattern is a substring)."""
    return f"{case_id[:-1]}[{case_id[-1]}]"


@pytest.mark.timeout(600)
def test_in_order_shuffled_and_alone_give_the_same_verdicts(tmp_path):
    reason = front_unavailable()
    if reason:
        pytest.skip(reason)
    channel = f"gw-order-{uuid.uuid4().hex[:8]}"
    topo = topology(tmp_path / "state", channel)
    eds = str(write_eds(topo, tmp_path))
    with GatewayThread(topo):
        bus = can.Bus(interface="virtual", channel=channel)
        try:

            def grade(**select) -> dict[str, str]:
                config = SuiteConfig(
                    NODE_ID,
                    eds,
                    timing=Timing(**TIMING),
                    options=Options(loopback=True),
                    profiles=["all", *OPT_IN],
                    **select,
                )
                return {r.case.id: r.verdict.value for r in run_suite(config, bus=bus)}

            shuffled = grade(shuffle=SEED)
            cases = sorted(shuffled)
            if not os.environ.get("FIELDGATE_ORDER_ALL"):
                cases = sorted(random.Random(SEED).sample(cases, SAMPLE))
            alone = {}
            for case_id in cases:
                alone.update(grade(patterns=[exactly(case_id)]))
        finally:
            bus.shutdown()
    assert len(shuffled) > 100 and list(shuffled) != sorted(shuffled, key=order_of)
    assert set(alone) == set(cases)
    differ = {c: (shuffled[c], alone[c]) for c in cases if shuffled[c] != alone[c]}
    assert not differ, f"(shuffled, alone): {differ}"


def order_of(case_id: str) -> int:
    """Where the case runs in order (the catalog's)."""
    from fieldgate.conformance.catalog import select

    return [c.id for c in select(["all", *OPT_IN])].index(case_id)
