"""SYNC loss (EMCY 0x8100) ends with its supervision: next SYNC, 0x1006 = 0, producer, reset.

0x1006 = 100 ms; a SYNC missing for 150 ms after the first one raises
``81 00 81 11 02 ...`` and 0x1001 = 0x11. These tests pin down when it ends
(docs/canopen.md, "Monitoring switched off"): frames byte for byte, 0x1001, 0x1003.
"""

import pytest
from canopen_rig import Rig, seed_node

from fieldgate.plugins.canopen.cia301.nmt import NmtState

RESET = "081 00 00 00 00 00 00 00 00"  # error reset, no error left
SYNC_LOSS = "081 00 81 11 02 00 00 00 00"
LIFE_GUARD = "081 30 81 11 07 00 00 00 00"
PERIOD_100MS = "23 06 10 00 A0 86 01 00"


def register(rig) -> int:
    return rig.node.od.get(0x1001)


def sync_lost(rig) -> None:
    """0x1006 = 100 ms, one SYNC, then silence: the loss EMCY after 150 ms."""
    assert rig.sdo(PERIOD_100MS) == "60 06 10 00 00 00 00 00"
    assert rig.send("080") == []
    assert rig.advance(0.149) == []
    assert rig.advance(0.002) == [SYNC_LOSS]
    assert register(rig) == 0x11 and rig.node.service("sync").status()["sync_lost"]


@pytest.fixture
def rig():
    return Rig(seed_node(1))


# -- the SYNC comes back ----------------------------------------------------------------------
def test_next_sync_ends_the_loss_and_supervision_runs_on(rig):
    sync_lost(rig)
    assert rig.send("080") == [RESET]
    assert register(rig) == 0
    assert rig.advance(0.149) == []
    assert rig.advance(0.002) == [SYNC_LOSS]  # lost again: a new EMCY


def test_sync_of_the_wrong_length_does_not_end_the_loss(rig):
    sync_lost(rig)
    assert (
        rig.send("080 01") == []
    )  # no counter configured: DLC 1 is not a SYNC (CANopenNode: neither)
    assert register(rig) == 0x11
    assert rig.node.service("sync").counters["bad_length"] == 1


def test_stopped_keeps_the_loss_and_the_first_sync_after_start_ends_it(rig):
    sync_lost(rig)
    assert rig.send("000 02 01") == []
    assert rig.send("080") == []  # not consumed in Stopped
    assert register(rig) == 0x11
    assert rig.send("000 01 01") == []
    assert rig.advance(1.0) == []  # supervision restarts at the first SYNC
    assert rig.send("080") == [RESET]


# -- supervision switched off ---------------------------------------------------------------------
def test_period_0_ends_the_loss_before_the_sdo_answer(rig):
    sync_lost(rig)
    assert rig.send("601 23 06 10 00 00 00 00 00") == [RESET, "581 60 06 10 00 00 00 00 00"]
    assert register(rig) == 0 and not rig.node.service("sync").status()["sync_lost"]
    assert rig.sdo("40 03 10 01 00 00 00 00") == "43 03 10 01 00 00 00 00"  # the reset, newest
    assert rig.sdo("40 03 10 02 00 00 00 00") == "43 03 10 02 00 81 02 00"  # the loss
    assert rig.advance(5.0) == []


def test_becoming_the_sync_producer_ends_the_loss(rig):
    sync_lost(rig)
    assert rig.send("601 23 05 10 00 80 00 00 40") == [RESET, "581 60 05 10 00 00 00 00 00"]
    assert register(rig) == 0
    assert rig.advance(0.25) == ["080", "080"]  # its own SYNC every 100 ms, no loss EMCY


def test_new_period_keeps_the_loss_until_the_next_sync(rig):
    sync_lost(rig)
    assert rig.send("601 23 06 10 00 40 0D 03 00") == ["581 60 06 10 00 00 00 00 00"]  # 200 ms
    assert register(rig) == 0x11  # still supervised, still no SYNC
    assert rig.advance(1.0) == []  # restarts at the first SYNC: no second EMCY
    assert rig.send("080") == [RESET]
    assert rig.advance(0.299) == []
    assert rig.advance(0.002) == [SYNC_LOSS]  # 1.5 x 200 ms


def test_new_cob_id_keeps_the_loss_until_a_sync_on_it(rig):
    sync_lost(rig)
    assert rig.send("601 23 05 10 00 81 00 00 00") == ["581 60 05 10 00 00 00 00 00"]
    assert rig.send("080") == []  # the old identifier is no SYNC any more
    assert register(rig) == 0x11
    assert rig.send("081") == [RESET]


def test_switching_off_with_another_error_active_reports_the_remaining_register(rig):
    rig.node.emcy.raise_error(0xFF00, 0x81, b"\x0b\x05")
    assert [str(f) for f in rig.node.flush()] == ["081 [8] 00 FF 81 0B 05 00 00 00"]
    rig.sdo(PERIOD_100MS)
    rig.send("080")
    assert rig.advance(0.2) == ["081 00 81 91 02 00 00 00 00"]  # 0x81 | 0x11
    assert rig.send("601 23 06 10 00 00 00 00 00")[0] == "081 00 00 81 00 00 00 00 00"
    assert register(rig) == 0x81


# -- reset communication / reset node -----------------------------------------------------------
@pytest.mark.parametrize("command", ["82", "81"])
def test_reset_ends_the_loss_after_the_boot_up(rig, command):
    sync_lost(rig)
    assert rig.send(f"000 {command} 01") == ["701 00", RESET]
    assert register(rig) == 0 and not rig.node.service("sync").status()["sync_lost"]
    assert rig.advance(5.0) == []  # 0x1006 reloaded (0): nothing supervised


def test_reset_with_a_stored_period_supervises_again_from_the_first_sync():
    rig = Rig(seed_node(1))
    rig.node.od.set_stored({(0x1006, 0): 100_000})  # as if saved with 0x1010
    rig.send("000 82 01")
    rig.send("080")
    assert rig.advance(0.2) == [SYNC_LOSS]
    assert rig.send("000 82 01") == ["701 00", RESET]
    assert rig.advance(5.0) == []
    rig.send("080")
    assert rig.advance(0.2) == [SYNC_LOSS]  # lost again: raised again (it was really cleared)


def test_reset_ends_sync_loss_and_life_guarding_error_with_one_emcy():
    rig = Rig(seed_node(1, guard_time_ms=100, life_time_factor=2))
    sync_lost(rig)
    assert rig.send("701 RTR") == ["701 7F"]
    assert rig.advance(0.25) == ["081 30 81 11 07 00 00 00 00"]
    assert rig.send("000 82 01") == ["701 00", RESET]  # both end together: one error reset
    assert register(rig) == 0
    assert (
        rig.sdo("40 03 10 00 00 00 00 00") == "4F 03 10 00 03 00 00 00"
    )  # loss, guarding, one reset


def test_reset_keeps_other_errors_and_reports_them_in_the_reset_emcy(rig):
    rig.node.emcy.raise_error(0xFF00, 0x81, b"\x0b\x05")
    rig.node.flush()
    rig.sdo(PERIOD_100MS)
    rig.send("080")
    rig.advance(0.2)
    assert rig.send("000 82 01") == ["701 00", "081 00 00 81 00 00 00 00 00"]
    assert register(rig) == 0x81


def test_reset_from_stopped_sends_the_error_reset_after_the_boot_up(rig):
    sync_lost(rig)
    rig.send("000 02 01")
    assert rig.node.state is NmtState.STOPPED
    assert rig.send("000 82 01") == ["701 00", RESET]


def test_sync_alone_ends_its_loss_at_a_reset_without_error_control():
    """The SYNC service clears by itself when no error control gathers its error."""
    from fieldgate.plugins.canopen.cia301.emcy import EmcyProducer
    from fieldgate.plugins.canopen.cia301.node import Node
    from fieldgate.plugins.canopen.cia301.sync import SyncService

    node = Node(1)
    node.add_service(EmcyProducer())
    node.add_service(SyncService())
    rig = Rig(node)
    node.od.set(0x1006, 0, 100_000)
    rig.send("080")
    assert rig.advance(0.2) == [SYNC_LOSS]
    assert rig.send("000 82 01") == ["701 00", RESET]
    assert register(rig) == 0
