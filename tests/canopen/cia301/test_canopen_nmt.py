"""NMT slave, node/life guarding (TV-20), heartbeat producer and consumer, bus-off."""

import pytest
from canopen_rig import Rig, frame, seed_node

from fieldgate.plugins.canopen.cia301.nmt import NmtState


@pytest.fixture
def rig():
    r = Rig(seed_node(1))
    r.master = []
    r.node.on_master(lambda ok, reason: r.master.append((ok, reason)))
    return r


def test_boot_up_then_pre_operational(rig):
    assert rig.boot == ["701 00"]
    assert rig.node.state is NmtState.PRE_OPERATIONAL


@pytest.mark.parametrize(
    "command, state",
    [("01", NmtState.OPERATIONAL), ("02", NmtState.STOPPED), ("80", NmtState.PRE_OPERATIONAL)],
)
def test_tv07_nmt_with_dlc_8_and_broadcast(rig, command, state):
    assert rig.send(f"000 {command} 01 00 00 00 00 00 00") == []
    assert rig.node.state is state
    rig.send("000 80 00")
    assert rig.send(f"000 {command} 00") == []  # node 0 = all nodes
    assert rig.node.state is state


def test_nmt_for_other_node_or_short_is_ignored(rig):
    rig.send("000 01 02")
    rig.send("000 01")
    rig.send("000 07 01")
    assert rig.node.state is NmtState.PRE_OPERATIONAL
    c = rig.node.counters
    assert (c["nmt_other_node"], c["nmt_malformed"], c["nmt_unknown_command"]) == (1, 1, 1)


def test_reset_communication_reloads_communication_area_only(rig):
    rig.sdo("2B 17 10 00 64 00 00 00")  # heartbeat 100 ms (communication area)
    rig.sdo("2B 02 21 00 07 00 00 00")  # application value
    rig.send("000 01 01")
    assert rig.send("000 82 01") == ["701 00"]
    assert rig.node.state is NmtState.PRE_OPERATIONAL
    assert rig.node.od.get(0x1017) == 0
    assert rig.node.od.get(0x2102) == 7


def test_reset_node_reloads_everything(rig):
    rig.sdo("2B 02 21 00 07 00 00 00")
    assert rig.send("000 81 00") == ["701 00"]
    assert rig.node.od.get(0x2102) == 0


def test_tv20_guarding_and_life_guarding(rig):
    assert rig.sdo("2B 0C 10 00 FA 00 00 00") == "60 0C 10 00 00 00 00 00"
    assert rig.sdo("2F 0D 10 00 04 00 00 00") == "60 0D 10 00 00 00 00 00"
    assert rig.advance(5.0) == []  # the life time starts only at the first RTR
    assert rig.send("701 RTR") == ["701 7F"]
    assert rig.advance(0.9) == []
    assert rig.send("701 RTR") == ["701 FF"]  # toggle alternates
    rig.send("000 01 01")
    assert rig.send("701 RTR") == ["701 05"]
    assert rig.advance(0.999) == []
    assert rig.advance(0.002) == ["081 30 81 11 07 00 00 00 00"]
    assert rig.master == [(False, "life guarding timeout")]
    assert rig.sdo("40 01 10 00 00 00 00 00") == "4F 01 10 00 11 00 00 00"
    assert rig.advance(5.0) == []  # one EMCY per error
    # the master comes back: answer, error reset EMCY, master ok
    assert rig.send("701 RTR") == ["701 85", "081 00 00 00 00 00 00 00 00"]
    assert rig.master[-1][0] is True


def test_guarding_answers_in_stopped_and_toggle_restarts_after_reset(rig):
    rig.send("000 02 01")
    assert rig.send("701 RTR") == ["701 04"]
    assert rig.send("701 RTR") == ["701 84"]
    rig.send("000 82 01")
    assert rig.send("701 RTR") == ["701 7F"]


def test_life_guarding_disabled_with_zero_factor(rig):
    rig.sdo("2B 0C 10 00 FA 00 00 00")
    rig.send("701 RTR")
    assert rig.advance(10.0) == []


def test_heartbeat_producer(rig):
    assert rig.sdo("2B 17 10 00 64 00 00 00") == "60 17 10 00 00 00 00 00"
    assert rig.advance(0.35) == ["701 7F"] * 3
    rig.send("000 02 01")
    assert rig.advance(0.1) == ["701 04"]
    rig.send("000 01 01")
    assert rig.advance(0.1) == ["701 05"]
    rig.sdo("2B 17 10 00 00 00 00 00")
    assert rig.advance(1.0) == []


def test_guard_rtr_ignored_while_heartbeat_runs(rig):
    rig.sdo("2B 17 10 00 E8 03 00 00")
    assert rig.send("701 RTR") == []
    assert rig.node.service("error_control").counters["guard_rtr_ignored_heartbeat_on"] == 1


def test_heartbeat_consumer_timeout_is_master_lost(rig):
    # watch node 0x7F every 200 ms
    assert rig.sdo("23 16 10 01 C8 00 7F 00") == "60 16 10 01 00 00 00 00"
    assert rig.advance(1.0) == []  # monitoring starts at the first heartbeat
    rig.send("77F 05")
    assert rig.advance(0.15) == []
    rig.send("77F 05")
    assert rig.advance(0.21) == ["081 30 81 11 07 7F 00 00 00"]
    assert rig.master == [(False, "heartbeat of node 127 timed out")]
    assert rig.send("77F 05") == ["081 00 00 00 00 00 00 00 00"]
    assert rig.master[-1] == (True, "heartbeat of node 127 back")


def test_heartbeat_consumer_duplicate_node_aborts():
    r = Rig(seed_node(1, heartbeat_consumers=2))
    r.sdo("23 16 10 01 C8 00 7F 00")
    assert r.sdo("23 16 10 02 C8 00 7F 00") == "80 16 10 02 43 00 04 06"


def test_bus_off_is_master_lost_and_recovery_emcy(rig):
    ec = rig.node.service("error_control")
    ec.bus_state(True, rig.now)
    assert rig.master == [(False, "CAN bus-off")]
    ec.bus_state(False, rig.now)
    # nothing monitors the master here (no guarding, no 0x1016 entry): the recovery EMCY
    # is an event, reset at once (with monitoring it waits for the master: test_canopen_errctl_clear)
    assert [str(f) for f in rig.node.flush()] == [
        "081 [8] 40 81 11 08 00 00 00 00",
        "081 [8] 00 00 00 00 00 00 00 00",
    ]
    assert rig.master[-1] == (True, "recovered from bus-off")
    assert rig.node.od.get(0x1001) == 0


def test_unconfigured_node_waits_silently():
    r = Rig(seed_node(node_id=None))
    assert r.boot == []
    assert r.node.state is NmtState.INITIALISING
    assert r.send("000 01 00") == []
    assert r.send("7FF RTR") == []
    assert r.node.state is NmtState.INITIALISING
    r.node.set_node_id(5)
    r.node.reset_communication(r.now)
    assert [str(f) for f in r.node.flush()] == ["705 [1] 00"]
    assert r.send("605 40 00 14 00 00 00 00 00") == ["585 4F 00 14 00 02 00 00 00"]
    assert r.node.od.get(0x1014) == 0x85


def test_new_node_id_moves_every_cob_id(rig):
    rig.node.set_node_id(9)
    assert rig.send("000 82 01") == ["709 00"]
    assert rig.send("609 40 00 12 01 00 00 00 00") == ["589 43 00 12 01 09 06 00 00"]
    assert rig.node.od.get(0x1400, 1) == 0x209
    assert rig.send("709 RTR") == ["709 7F"]


def test_frame_helper_round_trip():
    assert frame("701 RTR").rtr and frame("601 40 00").data == b"\x40\x00"


@pytest.mark.parametrize(
    "behaviour, state",
    [(0, NmtState.PRE_OPERATIONAL), (1, NmtState.OPERATIONAL), (2, NmtState.STOPPED)],
)
def test_error_behaviour_1029_on_life_guarding(behaviour, state):
    r = Rig(seed_node(1, guard_time_ms=100, life_time_factor=2))
    assert r.sdo(f"2F 29 10 01 {behaviour:02X} 00 00 00") == "60 29 10 01 00 00 00 00"
    r.send("000 01 01")
    r.send("701 RTR")
    r.advance(0.25)
    assert r.node.state is state


def test_error_behaviour_range():
    r = Rig(seed_node(1, error_behaviour=0))
    assert r.sdo("40 29 10 01 00 00 00 00") == "4F 29 10 01 00 00 00 00"
    assert r.sdo("2F 29 10 01 03 00 00 00") == "80 29 10 01 31 00 09 06"
