"""The store's rows of the seed audit (issue 32): an EMCY when the settings cannot be written
(000 #14, 001 #6), the NA-9161's "Changed HW configuration" EMCY on a head running on its
defaults (004 #27), and its stored COB-IDs kept across a node-ID change (004 #30).
docs/canopen-io.md has the "manual says / fieldgate does" rows."""

from __future__ import annotations

import errno

import pytest
from test_canopen_profiles import Dut

import fieldgate.plugins.canopen.cia301.store as store_module

SAVE = "23 10 10 01 73 61 76 65"  # 0x1010:1 = "save"
LOAD = "23 11 10 01 6C 6F 61 64"  # 0x1011:1 = "load"


def boot_emcys(dut: Dut) -> list[str]:
    return dut.emcys(dut.rig.boot)


@pytest.mark.parametrize("style", ["icpdas", "na9161"])
def test_a_save_that_cannot_be_written_aborts_and_raises_the_eeprom_emcy(
    style, tmp_path, monkeypatch
):
    dut = Dut({"node_id": 5, "style": style}, tmp_path=tmp_path)

    def full_disk(path, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(store_module, "write_atomic", full_disk)
    out = dut.rig.send(f"605 {SAVE}")
    assert "585 80 10 10 01 00 00 06 06" in out  # abort 0606 0000: hardware error
    assert dut.emcys(out) == ["00 50 81 02 00 00 00 00"]  # EEPROM access error (seed-000 §2.5)
    assert dut.read(0x1001, 0).startswith("4F 01 10 00 81")
    monkeypatch.undo()
    out = dut.rig.send(f"605 {SAVE}")
    assert "585 60 10 10 01 00 00 00 00" in out
    assert dut.emcys(out) == ["00 00 00 00 00 00 00 00"]  # the error ends with a save that works
    assert dut.node.service("store").status()["write_failures"] == 1


def test_an_unsaved_na9161_head_announces_its_defaults_at_power_on_once(tmp_path):
    dut = Dut({"node_id": 5, "style": "na9161"}, tmp_path=tmp_path)
    assert boot_emcys(dut) == ["00 63 81 0C 00 00 00 00"]  # Changed HW configuration
    assert dut.read(0x1001, 0).startswith("4F 01 10 00 00")  # an event: no error stays
    assert dut.emcys(dut.rig.send("000 81 05")) == []  # reset node: not a power-on
    dut.rig.send(f"605 {SAVE}")
    saved = Dut({"node_id": 5, "style": "na9161"}, tmp_path=tmp_path)  # power cycle
    assert boot_emcys(saved) == []
    saved.rig.send(f"605 {LOAD}")  # defaults at the next power-on, and announced again
    assert boot_emcys(Dut({"node_id": 5, "style": "na9161"}, tmp_path=tmp_path)) == [
        "00 63 81 0C 00 00 00 00"
    ]


def test_an_icpdas_head_on_its_defaults_is_silent(tmp_path):
    assert boot_emcys(Dut({"node_id": 5, "style": "icpdas"}, tmp_path=tmp_path)) == []


@pytest.mark.parametrize(
    ("style", "tpdo1", "emcy"),
    [("na9161", "85 01 00 00", "85 00 00 00"), ("icpdas", "86 01 00 00", "86 00 00 00")],
)
def test_stored_cob_ids_after_a_node_id_change(style, tpdo1, emcy, tmp_path):
    """NA-9161 (0x1010, [AMBIG-24]): saved COB-IDs keep their values when only the node-ID
    changes; the I-7232D style's follow the new node-ID (CiA 301's predefined set)."""
    dut = Dut({"node_id": 5, "style": style}, tmp_path=tmp_path)
    assert "585 60 10 10 01" in " ".join(dut.rig.send(f"605 {SAVE}"))
    moved = Dut({"node_id": 6, "style": style}, tmp_path=tmp_path)
    assert moved.read(0x1800, 1) == f"43 00 18 01 {tpdo1}"
    assert moved.read(0x1014, 0) == f"43 14 10 00 {emcy}"
