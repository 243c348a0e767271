"""A DI change from a back becomes a TPDO through one call from CiA 401 into CiA 301: the
profile's batch subscription -> the node's PDO service (``object_changed``), which queues the
TPDO and wakes the node; the node tells its wake listeners (the CAN front runs it once in
the next loop turn, core/can/front.py), and the next ``tick`` sends it."""

from __future__ import annotations

from io_bench import BACK, Kind, demo_7232d

from fieldgate.image import channel_id
from fieldgate.plugins.canopen.cia301.pdo.service import PdoService


def test_a_poll_reply_reaches_the_pdo_service_once_per_object_and_wakes_the_node(monkeypatch):
    b = demo_7232d()
    b.start()
    crossed, woken = [], []
    real = PdoService.object_changed

    def counting(self, index, sub, now):
        crossed.append((index, sub))
        real(self, index, sub, now)

    monkeypatch.setattr(PdoService, "object_changed", counting)
    b.io.profile.attach(b.node.service("pdo").object_changed)  # bound again: the patched one
    b.node.on_wake(lambda: woken.append(b.node.deadline_after_call))
    reply = {channel_id(BACK, 1, Kind.DI, i): bool(i % 2) for i in range(8)}
    b.image.update_inputs(reply)  # one poll reply of 8 DI, outside any node call
    assert crossed == [(0x6000, 1)]  # one object changed: one crossing, not eight
    assert woken == [b.node.now]  # the node is due at once
    assert b.flush() == ["181 [1] AA"]  # what the front's wake-up runs: the TPDO leaves
    assert b.flush() == []


def test_a_node_without_listeners_keeps_the_work_for_its_next_call():
    b = demo_7232d()
    b.start()
    b.image.update_inputs({channel_id(BACK, 1, Kind.DI, 0): True})
    assert b.node.deadline_after_call == b.node.now  # due: quick answers wait for the loop
    assert b.flush() == ["181 [1] 01"]
