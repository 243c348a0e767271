"""One owner of the front's master state: error control's monitoring OR (error_on_stopped and
NMT Stopped), reported to ``context.masters`` on change only; after a front restart the
master stays lost until heard (docs/canopen.md, "Master state" and "After a front restart").

Engine level: a node on a fake clock, :class:`MasterState` and a real ``MasterMonitor``
whose listener records every report.
"""

import pytest
from canopen_rig import Rig, seed_node
from io_bench import demo_7232d

from fieldgate.image import ProcessImage
from fieldgate.masters import MasterMonitor
from fieldgate.plugins.canopen.cia301.nmt import NmtState
from fieldgate.plugins.canopen.cia401.iodevice import IoSettings
from fieldgate.plugins.canopen.master_state import RESTART_REASON, MasterState

FRONT = "can"
LIFE_GUARD = "081 30 81 11 07 00 00 00 00"
RESET = "081 00 00 00 00 00 00 00 00"


def monitor(lost_before: bool = False) -> tuple[MasterMonitor, list]:
    masters = MasterMonitor(ProcessImage(lambda: 0.0))
    masters.register(FRONT)
    if lost_before:
        masters.lost(FRONT, "lost before the restart", [])
    events: list = []
    masters.subscribe(lambda front, ok, reason: events.append((ok, reason)))
    return masters, events


def make_rig(
    stopped_is_error: bool = True, lost_before: bool = False, stored=None, **settings
) -> Rig:
    node = seed_node(1, **settings)
    if stored:
        node.od.set_stored(stored)
    masters, events = monitor(lost_before)
    state = MasterState(masters, FRONT, [], stopped_is_error=stopped_is_error)
    state.attach(node)
    rig = Rig(node)
    rig.masters, rig.events, rig.state = masters, events, state
    return rig


def guard_lost(rig) -> None:
    assert rig.send("701 RTR")[0].startswith("701 ")
    assert LIFE_GUARD in rig.advance(0.25)


GUARD = {"guard_time_ms": 100, "life_time_factor": 2}


# -- monitoring and Stopped combined ------------------------------------------------------------
def test_leaving_stopped_while_guarding_is_lost_keeps_the_master_lost():
    rig = make_rig(**GUARD)
    rig.send("000 01 01")
    guard_lost(rig)
    assert rig.events == [(False, "life guarding timeout")]
    rig.send("000 02 01")  # Stopped: lost already, nothing new
    rig.send("000 01 01")  # leaving Stopped: guarding still lost
    assert rig.events == [(False, "life guarding timeout")] and not rig.masters.is_ok(FRONT)
    assert rig.send("701 RTR")[-1] == RESET
    assert rig.events == [(False, "life guarding timeout"), (True, "life guarding resumed")]
    assert rig.masters.is_ok(FRONT)


def test_guarding_resuming_while_stopped_keeps_the_master_lost():
    rig = make_rig(**GUARD)
    rig.send("701 RTR")
    rig.send("000 02 01")
    assert rig.events == [(False, "NMT Stopped")]
    assert rig.advance(0.25) == []  # the loss EMCY cannot go out in Stopped
    assert rig.node.service("error_control").status()["guarding"] == "lost"
    assert rig.send("701 RTR") == ["701 84"]  # guarding back (toggle 1, Stopped); still Stopped
    assert rig.events == [(False, "NMT Stopped")] and not rig.masters.is_ok(FRONT)
    rig.send("000 80 01")
    assert rig.events == [(False, "NMT Stopped"), (True, "left NMT Stopped")]


def test_stopped_is_no_loss_without_error_on_stopped():
    rig = make_rig(stopped_is_error=False, **GUARD)
    rig.send("000 02 01")
    rig.send("701 RTR")
    rig.advance(0.25)
    assert rig.events == [(False, "life guarding timeout")]
    rig.send("701 RTR")
    assert rig.events[-1] == (True, "life guarding resumed")  # though still Stopped


def test_error_behaviour_stopped_then_master_heard_then_started():
    rig = make_rig(error_behaviour=2, **GUARD)
    rig.send("000 01 01")
    guard_lost(rig)
    assert rig.node.state is NmtState.STOPPED
    assert rig.events == [(False, "life guarding timeout")]  # one loss for both causes
    rig.send("701 RTR")  # guarding resumes, but 0x1029 left the node Stopped
    assert rig.events == [(False, "life guarding timeout")]
    rig.send("000 01 01")
    assert rig.events == [(False, "life guarding timeout"), (True, "left NMT Stopped")]
    assert rig.state.status() == {
        "lost": False,
        "reason": "left NMT Stopped",
        "monitoring_lost": False,
        "stopped_error": False,
        "losses": 1,
    }


def test_reset_from_stopped_with_guarding_lost_is_one_ok():
    rig = make_rig(error_behaviour=2, **GUARD)
    guard_lost(rig)
    assert rig.send("000 82 01") == ["701 00", RESET]
    assert rig.events == [(False, "life guarding timeout"), (True, "reset communication")]


def test_reset_from_stopped_alone_reports_ok_once():
    rig = make_rig()
    rig.send("000 02 01")
    rig.send("000 81 01")
    assert rig.events == [(False, "NMT Stopped"), (True, "reset communication")]


def test_io_device_as_owner_both_orders_on_the_outputs():
    """A standalone I/O device (no front) owns the same combination: outputs and masters agree."""
    b = demo_7232d(settings=IoSettings(style="icpdas", error_on_stopped=True), guard=(100, 2))
    b.start()
    b.write(0x6206, 1, 0xFF, 1)  # every DO of module 3 has an error mode (value 0)
    b.rx(0x201, "FF")
    b.rx(0x701, rtr=True)
    b.advance(0.25)
    assert not b.masters.is_ok("can") and b.value(0x6200, 1) == 0x00
    b.nmt(0x02)
    b.nmt(0x01)  # left Stopped, guarding still lost
    assert not b.masters.is_ok("can") and b.io.status()["master_lost"]
    b.rx(0x701, rtr=True)
    assert b.masters.is_ok("can") and b.value(0x6200, 1) == 0x00  # outputs stay until new data
    b.nmt(0x02)
    assert not b.masters.is_ok("can")
    b.rx(0x701, rtr=True)  # guarding fine, still Stopped
    assert not b.masters.is_ok("can")
    b.nmt(0x01)
    assert b.masters.is_ok("can")


# -- after a front restart ------------------------------------------------------------------------------
def test_restart_with_the_master_lost_stays_lost_until_a_guard_request():
    rig = make_rig(lost_before=True, **GUARD)
    assert rig.boot == ["701 00"]  # no EMCY: this node detected nothing
    ec = rig.node.service("error_control")
    assert ec.status()["master_unheard"] and rig.state.lost and not rig.masters.is_ok(FRONT)
    assert rig.state.reason == RESTART_REASON
    assert rig.events == []  # already lost in masters: nobody told again
    assert rig.advance(5.0) == [] and not rig.masters.is_ok(FRONT)
    assert rig.send("701 RTR") == ["701 7F"]
    assert rig.events == [(True, "guard request")] and rig.masters.is_ok(FRONT)
    assert rig.advance(0.25) == [LIFE_GUARD]  # guarding started by that RTR, as ever
    assert rig.events[-1] == (False, "life guarding timeout")


@pytest.mark.parametrize(
    "frame, reason",
    [
        ("000 01 01", "NMT OPERATIONAL"),
        ("000 02 00", None),  # broadcast stop: heard, and Stopped is itself an error here
        ("000 82 01", "reset communication"),
        ("77F 05", "heartbeat of node 127"),
        ("601 2B 17 10 00 E8 03 00 00", "monitoring configured"),
    ],
)
def test_restart_master_heard_by_nmt_heartbeat_or_monitoring_write(frame, reason):
    rig = make_rig(lost_before=True, stored={(0x1016, 1): 0x7F00C8})
    assert not rig.masters.is_ok(FRONT)
    rig.send(frame)
    assert not rig.node.service("error_control").status()["master_unheard"]
    if reason is None:
        assert rig.events == [] and not rig.masters.is_ok(FRONT)  # lost through Stopped now
        rig.send("000 01 00")
        reason = "left NMT Stopped"
    assert rig.events == [(True, reason)] and rig.masters.is_ok(FRONT)


@pytest.mark.parametrize(
    "frame",
    [
        "601 40 00 10 00 00 00 00 00",  # an SDO read: a configuration tool, not necessarily the master
        "080",  # SYNC
        "000 01 02",  # NMT for another node
        "000 01",  # malformed NMT
        "77E 05",  # heartbeat of a node nobody watches
        "702 RTR",  # guarding of another node
    ],
)
def test_restart_master_not_heard_by_other_traffic(frame):
    rig = make_rig(lost_before=True, stored={(0x1016, 1): 0x7F00C8})
    rig.send(frame)
    assert rig.events == [] and not rig.masters.is_ok(FRONT)
    assert rig.node.service("error_control").status()["master_unheard"]


def test_restart_with_the_master_ok_assumes_nothing():
    rig = make_rig(lost_before=False, **GUARD)
    assert not rig.node.service("error_control").status()["master_unheard"]
    assert rig.events == [] and rig.masters.is_ok(FRONT) and not rig.state.lost


def test_own_error_behaviour_state_change_is_not_the_master():
    rig = make_rig(lost_before=True, error_behaviour=2, stored={(0x1016, 1): 0x7F00C8})
    ec = rig.node.service("error_control")
    rig.send("77F 05")  # heard: ok
    assert rig.events == [(True, "heartbeat of node 127")]
    ec.assume_master_lost("test: unheard again")  # as after a restart
    assert rig.events[-1] == (False, "test: unheard again")
    rig.send("77F 05")
    assert rig.events[-1] == (True, "heartbeat of node 127")
    assert rig.advance(0.25) == [
        "081 30 81 11 07 7F 00 00 00"
    ]  # 0x1029 = 2: Stopped by the node itself
    assert rig.node.state is NmtState.STOPPED
    ec.assume_master_lost("test: unheard again")
    ec.bus_state(True, rig.now)
    ec.bus_state(False, rig.now)  # nothing of this is the master
    assert ec.status()["master_unheard"]


def test_only_the_first_boot_of_a_node_assumes_the_master_lost():
    """A later reset with masters still lost (bus off through it) does not make it unheard."""
    rig = make_rig(**GUARD)
    ec = rig.node.service("error_control")
    ec.bus_state(True, rig.now)
    assert rig.events == [(False, "CAN bus-off")]
    rig.send("000 82 01")
    assert not ec.status()["master_unheard"]
    ec.bus_state(False, rig.now)
    assert rig.events == [(False, "CAN bus-off"), (True, "recovered from bus-off")]
