"""Expedited uploads answered on the SDO server's short path (QUIET): same answers, timers kept.

The node skips its timer pass after a frame a service reports as QUIET (a read that moved
no timer) unless a timer is already due. These tests pin what must not change because of it.
"""

from __future__ import annotations

import pytest
from canopen_rig import Rig, seed_node

from fieldgate.plugins.canopen.cia301.service import QUIET

UPLOAD_1000 = "601 40 00 10 00 00 00 00 00"
ANSWER_1000 = "581 43 00 10 00 91 01 0F 00"


@pytest.fixture
def rig():
    return Rig(seed_node(1, heartbeat_ms=100))


def test_a_read_before_any_timer_is_due_sends_only_its_answer_and_keeps_the_deadline(rig):
    rig.now = 0.05
    assert rig.send(UPLOAD_1000) == [ANSWER_1000]
    assert rig.node.deadline_after_call == pytest.approx(0.1)  # the heartbeat, as before the read


def test_a_read_when_a_timer_is_due_runs_it_in_the_same_call(rig):
    rig.now = 0.15  # the heartbeat (every 100 ms) is overdue
    assert rig.send(UPLOAD_1000) == [ANSWER_1000, "701 7F"]
    assert rig.node.deadline_after_call == pytest.approx(0.2)  # the next heartbeat, on its own grid


def test_the_sdo_server_reports_quiet_only_for_a_successful_expedited_read(rig):
    sdo = rig.node.service("sdo")
    from canopen_rig import frame

    assert sdo.on_frame(frame(UPLOAD_1000), 0.0) is QUIET
    assert (
        sdo.on_frame(frame("601 40 00 20 00 00 00 00 00"), 0.0) is True
    )  # no object: abort, general path
    assert (
        sdo.on_frame(frame("601 40 08 10 00 00 00 00 00"), 0.0) is True
    )  # 0x1008 is 9 bytes: segmented
    assert sdo.deadline() is not None  # the segmented upload is open and timed


@pytest.mark.parametrize(
    ("request_", "answer"),
    [
        ("601 40 00 20 00 00 00 00 00", "581 80 00 20 00 00 00 02 06"),  # object does not exist
        ("601 40 00 10 01 00 00 00 00", "581 80 00 10 01 11 00 09 06"),  # sub-index does not exist
        ("601 40 03 21 00 00 00 00 00", "581 80 03 21 00 01 00 01 06"),  # write-only
        ("601 40 00 14 02 00 00 00 00", "581 4F 00 14 02 FF 00 00 00"),  # one byte, n = 3
    ],
)
def test_reads_that_leave_the_short_path_are_answered_as_before(rig, request_, answer):
    assert rig.send(request_) == [answer]


def test_a_read_during_an_open_transfer_supersedes_it_as_before(rig):
    assert rig.send("601 21 00 21 00 0A 00 00 00") == [
        "581 60 00 21 00 00 00 00 00"
    ]  # segmented download of 10 bytes
    assert rig.send(UPLOAD_1000) == [ANSWER_1000]
    sdo = rig.node.service("sdo")
    assert sdo.status()["superseded"] == 1 and sdo.status()["phase"] == "idle"


def test_status_counts_short_path_reads_as_requests_and_transfers(rig):
    for _ in range(3):
        rig.send(UPLOAD_1000)
    rig.send("601 40 00 20 00 00 00 00 00")  # an abort, on the general path
    status = rig.node.service("sdo").status()
    assert status["requests"] == 4 and status["transfers"] == 3 and status["aborts"] == 1
    assert rig.node.status()["counters"]["rx"] == 4


def test_an_emcy_raised_from_outside_is_not_held_back_by_quiet_reads(rig):
    """flush() after an outside call refreshes the deadline the short path relies on."""
    emcy = rig.node.emcy
    rig.send("601 2B 15 10 00 E8 03 00 00")  # 0x1015 inhibit = 1000 x 100 us = 0.1 s
    emcy.raise_error(0x1000, 0x01, now=rig.now)
    emcy.raise_error(0x5000, 0x01, now=rig.now)  # queued behind the inhibit time
    first = rig.node.flush()
    assert len(first) == 1
    rig.now += 0.11  # the queued EMCY is due now
    out = rig.send(UPLOAD_1000)
    assert out[0] == ANSWER_1000
    assert any(line.startswith("081 00 50") for line in out[1:]), out


def test_without_any_timer_a_read_skips_the_timer_pass_and_a_later_timer_still_runs():
    rig = Rig(seed_node(1))  # no heartbeat, no guarding: no deadline at all
    assert rig.node.deadline_after_call is None
    assert rig.send(UPLOAD_1000) == [ANSWER_1000]
    assert rig.send("601 2B 17 10 00 64 00 00 00") == [
        "581 60 17 10 00 00 00 00 00"
    ]  # heartbeat 100 ms: a write
    assert rig.node.deadline_after_call == pytest.approx(0.1)
    rig.now = 0.1
    assert rig.send(UPLOAD_1000) == [ANSWER_1000, "701 7F"]
