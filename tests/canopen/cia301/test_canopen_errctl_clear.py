"""Monitoring errors end with their monitoring: guarding off, 0x1016 rewritten, reset, bus-off.

A life-guarding or heartbeat-consumer timeout sets EMCY 0x8130 (0x1001 = 0x11) and
reports the master lost. These tests pin down when that error ends other than by the
master coming back (docs/canopen.md, "Monitoring switched off"): frames byte for byte,
0x1001, 0x1003 and the master state seen by ``node.on_master``.
"""

import pytest
from canopen_rig import Rig, seed_node

from fieldgate.plugins.canopen.cia301.nmt import NmtState

RESET = "081 00 00 00 00 00 00 00 00"  # error reset, no error left
LIFE_GUARD = "081 30 81 11 07 00 00 00 00"  # TV-20


def make_rig(**settings) -> Rig:
    r = Rig(seed_node(1, **settings))
    r.master = []
    r.node.on_master(lambda ok, reason: r.master.append((ok, reason)))
    return r


def register(rig) -> int:
    return rig.node.od.get(0x1001)


def guard_lost(rig) -> None:
    """Life guarding 100 ms x 2 started by one RTR, then timed out."""
    assert rig.send("701 RTR") == ["701 7F"]
    assert rig.advance(0.25) == [LIFE_GUARD]
    assert register(rig) == 0x11 and rig.master == [(False, "life guarding timeout")]


def heartbeat_lost(rig, producer: int = 0x7F, sub: int = 1) -> None:
    """Consumer entry ``sub`` watches ``producer`` every 200 ms; one heartbeat, then silence."""
    assert (
        rig.sdo(f"23 16 10 {sub:02X} C8 00 {producer:02X} 00") == f"60 16 10 {sub:02X} 00 00 00 00"
    )
    rig.send(f"{0x700 + producer:03X} 05")
    assert rig.advance(0.25) == [f"081 30 81 11 07 {producer:02X} 00 00 00"]


# -- life guarding switched off ---------------------------------------------------------------
@pytest.mark.parametrize(
    "write",
    [
        "2B 0C 10 00 00 00 00 00",  # guard time 0
        "2F 0D 10 00 00 00 00 00",  # life time factor 0
        "2B 17 10 00 E8 03 00 00",  # heartbeat producer on: heartbeat replaces guarding
    ],
)
def test_guarding_switched_off_clears_the_life_guarding_error(write):
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    guard_lost(rig)
    out = rig.send("601 " + write)
    assert out[0] == RESET and out[1].startswith("581 60")
    assert register(rig) == 0
    assert rig.master[-1] == (True, "life guarding switched off")
    assert rig.sdo("40 03 10 01 00 00 00 00") == "43 03 10 01 00 00 00 00"  # the reset, newest
    assert rig.sdo("40 03 10 02 00 00 00 00") == "43 03 10 02 30 81 07 00"
    assert [f for f in rig.advance(2.0) if f.startswith("081")] == []
    assert rig.node.service("error_control").status()["master"] == "ok"


def test_guarding_switched_back_on_starts_at_the_next_rtr_and_raises_a_new_error():
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    guard_lost(rig)
    assert rig.send("601 2B 0C 10 00 00 00 00 00")[0] == RESET
    rig.sdo("2B 0C 10 00 64 00 00 00")
    assert rig.advance(5.0) == []  # not started again before an RTR
    assert rig.send("701 RTR") == ["701 FF"]  # the toggle runs on (no reset communication)
    assert rig.advance(0.25) == [LIFE_GUARD]  # a new error: its EMCY again
    assert rig.master == [
        (False, "life guarding timeout"),
        (True, "life guarding switched off"),
        (False, "life guarding timeout"),
    ]


def test_guard_time_changed_but_still_on_keeps_the_error_until_the_master_is_back():
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    guard_lost(rig)
    assert rig.send("601 2B 0C 10 00 C8 00 00 00") == ["581 60 0C 10 00 00 00 00 00"]
    assert register(rig) == 0x11 and rig.master[-1][0] is False
    assert rig.send("701 RTR") == ["701 FF", RESET]
    assert rig.master[-1] == (True, "life guarding resumed")


def test_switching_off_with_another_error_active_reports_the_remaining_register():
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    rig.node.emcy.raise_error(0xFF00, 0x81, b"\x0b\x05")
    assert [str(f) for f in rig.node.flush()] == ["081 [8] 00 FF 81 0B 05 00 00 00"]
    rig.send("701 RTR")
    assert rig.advance(0.25) == ["081 30 81 91 07 00 00 00 00"]  # 0x81 | 0x11
    assert rig.send("601 2F 0D 10 00 00 00 00 00")[0] == "081 00 00 81 00 00 00 00 00"
    assert register(rig) == 0x81  # the module error stays


def test_heartbeat_producer_on_stops_a_running_life_guard():
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    rig.send("701 RTR")
    rig.sdo("2B 17 10 00 E8 03 00 00")
    assert [
        f for f in rig.advance(0.5) if f.startswith("081")
    ] == []  # RTRs are ignored now: no timeout either
    assert rig.master == []


# -- heartbeat consumer entries rewritten ----------------------------------------------------------
@pytest.mark.parametrize("entry", ["00 00 00 00", "C8 00 20 00"])  # time 0, or another node
def test_consumer_entry_cleared_or_moved_clears_that_nodes_error(entry):
    rig = make_rig()
    heartbeat_lost(rig)
    assert rig.send(f"601 23 16 10 01 {entry}") == [RESET, "581 60 16 10 01 00 00 00 00"]
    assert register(rig) == 0
    assert rig.master == [
        (False, "heartbeat of node 127 timed out"),
        (True, "heartbeat consumer for node 127 switched off"),
    ]
    assert rig.send("77F 05") == []  # node 127 is no longer consumed
    assert rig.advance(1.0) == []  # node 0x20 (if now watched) starts at its first heartbeat


def test_consumer_entry_rewritten_for_the_same_node_keeps_its_error():
    rig = make_rig()
    heartbeat_lost(rig)
    assert rig.sdo("23 16 10 01 F4 01 7F 00") == "60 16 10 01 00 00 00 00"  # 500 ms now
    assert register(rig) == 0x11 and rig.master[-1][0] is False
    assert rig.send("77F 05") == [RESET]
    assert rig.advance(0.45) == []
    assert rig.advance(0.1) == ["081 30 81 11 07 7F 00 00 00"]  # timed with the new 500 ms


def test_consumer_time_changed_restarts_at_the_next_heartbeat_others_keep_running():
    rig = make_rig(heartbeat_consumers=2)
    rig.sdo("23 16 10 01 C8 00 7F 00")
    rig.sdo("23 16 10 02 C8 00 10 00")
    rig.send("77F 05")
    rig.send("710 05")
    rig.advance(0.1)
    rig.sdo("23 16 10 02 E8 03 10 00")  # node 0x10: 1000 ms, from its next heartbeat
    assert rig.advance(0.11) == ["081 30 81 11 07 7F 00 00 00"]  # node 0x7F's watch ran on
    assert rig.advance(2.0) == []  # the old 200 ms deadline of node 0x10 is gone
    rig.send("710 05")
    assert rig.advance(0.99) == []
    assert rig.advance(0.02) == ["081 30 81 11 07 10 00 00 00"]


def test_two_producers_lost_master_ok_only_when_both_end():
    rig = make_rig(heartbeat_consumers=2)
    rig.sdo("23 16 10 01 C8 00 7F 00")
    rig.sdo("23 16 10 02 C8 00 10 00")
    rig.send("77F 05")
    rig.send("710 05")
    assert rig.advance(0.25) == ["081 30 81 11 07 7F 00 00 00", "081 30 81 11 07 10 00 00 00"]
    assert rig.master == [(False, "heartbeat of node 127 timed out")]  # one loss, told once
    assert rig.send("710 05") == ["081 00 00 11 00 00 00 00 00"]  # node 0x7F still missing
    assert rig.master[-1][0] is False and register(rig) == 0x11
    assert rig.send("601 23 16 10 01 00 00 00 00")[0] == RESET
    assert rig.master[-1] == (True, "heartbeat consumer for node 127 switched off")
    assert rig.node.service("error_control").status()["heartbeat_lost"] == []


# -- reset communication / reset node ------------------------------------------------------
@pytest.mark.parametrize("command", ["82", "81"])
def test_reset_ends_the_life_guarding_error_after_the_boot_up(command):
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    guard_lost(rig)
    assert rig.send(f"000 {command} 01") == ["701 00", RESET]
    assert register(rig) == 0
    assert rig.master[-1] == (True, "reset communication")
    assert rig.send("701 RTR") == ["701 7F"]  # toggle 0 again, life guarding restarts here
    assert rig.advance(0.25) == [LIFE_GUARD]  # and can be lost again: a new EMCY


def test_reset_ends_heartbeat_errors_and_restarts_the_consumer_at_the_first_heartbeat():
    rig = make_rig()
    rig.node.od.set_stored({(0x1016, 1): 0x7F00C8})  # as if saved with 0x1010
    rig.send("000 82 01")
    rig.send("77F 05")
    assert rig.advance(0.25) == ["081 30 81 11 07 7F 00 00 00"]
    assert rig.send("000 82 00") == ["701 00", RESET]
    assert rig.master == [(False, "heartbeat of node 127 timed out"), (True, "reset communication")]
    assert rig.advance(5.0) == []  # waits for the producer's first heartbeat
    rig.send("77F 05")
    assert rig.advance(0.25) == ["081 30 81 11 07 7F 00 00 00"]


def test_reset_after_stopped_by_0x1029_and_with_the_reset_emcy_option():
    rig = make_rig(guard_time_ms=100, life_time_factor=2, error_behaviour=2, emcy_on_nmt_reset=True)
    rig.send("000 01 01")
    rig.send("701 RTR")
    assert rig.advance(0.25) == [LIFE_GUARD]
    assert rig.node.state is NmtState.STOPPED
    # the I-7232D's reset EMCY cannot go out in Stopped; the error reset follows the boot-up
    assert rig.send("000 82 01") == ["701 00", RESET]
    assert rig.node.state is NmtState.PRE_OPERATIONAL and register(rig) == 0


def test_reset_keeps_other_errors_and_reports_them_in_the_reset_emcy():
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    rig.node.emcy.raise_error(0xFF00, 0x81, b"\x0b\x05")
    rig.node.flush()
    rig.send("701 RTR")
    rig.advance(0.25)
    assert rig.send("000 82 01") == ["701 00", "081 00 00 81 00 00 00 00 00"]
    assert register(rig) == 0x81


def test_reset_without_monitoring_errors_sends_no_emcy():
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    rig.send("701 RTR")
    assert rig.send("000 82 01") == ["701 00"]
    assert rig.master == []


# -- bus-off --------------------------------------------------------------------------------------
def test_bus_off_recovery_error_ends_at_the_next_guard_request():
    rig = make_rig(guard_time_ms=1000, life_time_factor=3)
    ec = rig.node.service("error_control")
    rig.send("701 RTR")
    ec.bus_state(True, rig.now)
    ec.bus_state(False, rig.now)
    assert [str(f) for f in rig.node.flush()] == ["081 [8] 40 81 11 08 00 00 00 00"]
    assert register(rig) == 0x11
    assert rig.master == [(False, "CAN bus-off"), (True, "recovered from bus-off")]
    assert rig.send("701 RTR") == ["701 FF", RESET]  # the master is heard: 0x8140 ends
    assert register(rig) == 0 and not ec.status()["bus_off_recovered"]


def test_bus_off_recovery_error_ends_at_a_monitored_heartbeat():
    rig = make_rig()
    rig.sdo("23 16 10 01 E8 03 7F 00")
    ec = rig.node.service("error_control")
    ec.bus_state(True, rig.now)
    ec.bus_state(False, rig.now)
    assert len(rig.node.flush()) == 1
    assert rig.send("77F 05") == [RESET]


def test_life_guarding_lost_during_bus_off_one_loss_one_return():
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    ec = rig.node.service("error_control")
    rig.send("701 RTR")
    ec.bus_state(True, rig.now)
    assert rig.advance(0.25) == [LIFE_GUARD]  # produced (the adapter counts the failed send)
    ec.bus_state(False, rig.now)
    assert [str(f) for f in rig.node.flush()] == ["081 [8] 40 81 11 08 00 00 00 00"]
    assert rig.master == [(False, "CAN bus-off")]  # still lost: guarding says so
    assert rig.send("701 RTR") == ["701 FF", RESET]  # both errors end together: one EMCY
    assert rig.master == [(False, "CAN bus-off"), (True, "life guarding resumed")]
    assert rig.sdo("40 03 10 00 00 00 00 00") == "4F 03 10 00 03 00 00 00"


@pytest.mark.parametrize("end", ["601 2B 0C 10 00 00 00 00 00", "000 82 01"])
def test_bus_off_recovery_error_ends_with_the_monitoring_or_a_reset(end):
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    ec = rig.node.service("error_control")
    ec.bus_state(True, rig.now)
    ec.bus_state(False, rig.now)
    rig.node.flush()
    assert RESET in rig.send(end)
    assert register(rig) == 0


def test_bus_still_off_through_a_reset_keeps_the_master_lost():
    rig = make_rig(guard_time_ms=100, life_time_factor=2)
    ec = rig.node.service("error_control")
    guard_lost(rig)
    ec.bus_state(True, rig.now)
    assert rig.send("000 82 01") == ["701 00", RESET]
    assert rig.master == [(False, "life guarding timeout")]  # bus-off: still lost
    ec.bus_state(False, rig.now)
    assert rig.master[-1] == (True, "recovered from bus-off")


# -- EMCY: several errors cleared together ------------------------------------------------------
def test_clear_errors_sends_one_emcy_and_skips_inactive_ones():
    rig = make_rig()
    emcy = rig.node.emcy
    emcy.raise_error(0x8130, 0x11, b"\x07")
    emcy.raise_error(0x8140, 0x11, b"\x08")
    emcy.raise_error(0xFF00, 0x81, b"\x0b\x03")
    rig.node.flush()
    assert (
        emcy.clear_errors(
            [(0x8130, b"\x07"), (0x8140, b"\x08"), (0x8130, b"\x07\x10"), (0x8130, b"\x07")]
        )
        == 2
    )
    assert [str(f) for f in rig.node.flush()] == ["081 [8] 00 00 81 00 00 00 00 00"]
    assert emcy.clear_errors([(0x8130, b"\x07")]) == 0
    assert rig.node.flush() == []
    assert len(emcy.history) == 4 and emcy.history[0] == 0
