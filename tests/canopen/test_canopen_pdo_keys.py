"""The topology's per-PDO communication and mapping keys (``tpdos:`` / ``rpdos:``): the node
serves them as its defaults, the EDS states them (so a master's configuration tool and the
running node agree), ``validate`` refuses what the engine would refuse."""

from __future__ import annotations

import canopen
import pytest
from canopen_rig import show
from test_canopen_profiles import Dut, topo
from test_eds_generation import generate

from fieldgate import load_registry
from fieldgate.topology import TopologyError, load_topology

REGISTRY = load_registry()
KEYS = {
    "node_id": 5,
    "tpdos": {
        2: {"transmission_type": 1, "inhibit_time": 0, "event_timer_ms": 0},
        5: {"cob_id": 0x1A5, "mapping": ["0x6000:1/8", "0x6401:2/16"]},
    },
    "rpdos": {1: {"transmission_type": 0}, 3: {"valid": False}},
}


def test_the_node_serves_the_keys_as_its_defaults():
    dut = Dut(KEYS)
    assert dut.read(0x1801, 2) == "4F 01 18 02 01 00 00 00"
    assert dut.read(0x1804, 1) == "43 04 18 01 A5 01 00 00"  # valid, as given
    assert dut.read(0x1A04, 0) == "4F 04 1A 00 02 00 00 00"
    assert dut.read(0x1A04, 2) == "43 04 1A 02 10 02 01 64"
    assert dut.read(0x1400, 2) == "4F 00 14 02 00 00 00 00"
    assert dut.read(0x1402, 1) == "43 02 14 01 05 04 00 80"  # invalid
    # they are defaults: a master changes them as usual, a reset brings them back
    assert dut.sdo("2F 01 18 02 FF 00 00 00") == "60 01 18 02 00 00 00 00"
    dut.rig.send("000 82 05")
    assert dut.read(0x1801, 2) == "4F 01 18 02 01 00 00 00"


def test_tpdo5_with_its_own_cob_id_and_mapping_runs():
    dut = Dut(KEYS)
    dut.start()
    dut.image.update_input("io/m1/di0", True)
    dut.image.update_input("io/m1/ai1", 0x0102)
    out = show(dut.node.flush()) + dut.rig.advance(0.0)
    assert "1A5 01 02 01" in out  # DI byte, AI 2


def test_the_eds_states_the_keys(tmp_path):
    od = canopen.import_od(str(generate(tmp_path, **KEYS)), node_id=5)
    assert od[0x1801][2].default == 1
    assert od[0x1804][1].default == 0x1A5  # the CAN-ID itself, not $NODEID+...
    assert [od[0x1A04][s].default for s in (1, 2)] == [0x60000108, 0x64010210]
    assert od[0x1A04][0].default == 2
    assert od[0x1402][1].default == 0x80000405
    assert od[0x1400][2].default == 0


@pytest.mark.parametrize(
    ("pdos", "path", "words"),
    [
        ({"tpdos": {1: {"mapping": ["0x6206:1/8"]}}}, "tpdos[1]", "cannot be mapped"),
        ({"rpdos": {1: {"mapping": ["0x6000:1/8"]}}}, "rpdos[1]", "cannot be mapped"),
        ({"tpdos": {1: {"mapping": ["0x6000:1/16"]}}}, "tpdos[1]", "not 16"),
        ({"tpdos": {1: {"mapping": ["0x6000:9/8"]}}}, "tpdos[1]", "mapping"),
        ({"rpdos": {2: {"inhibit_time": 10}}}, "rpdos[2]", "no inhibit time"),
        ({"rpdos": {2: {"transmission_type": 252}}}, "rpdos[2]", "for TPDOs"),
        ({"tpdos": {40: {"transmission_type": 1}}}, "fronts[0]", "PDOs 1..32"),
        ({"tpdos": {5: {"cob_id": 0x701}}}, "tpdos[5]", "cob_id 0x701"),
        ({"tpdos": {5: {"cob_id": 0x185}}}, "tpdos[5]", "TPDO1's too"),
        ({"tpdos": {6: {"valid": True}}}, "tpdos[6]", "give cob_id"),
    ],
)
def test_validate_refuses_what_the_engine_would(pdos, path, words):
    with pytest.raises(TopologyError) as err:
        load_topology(topo({"node_id": 5, **pdos}), REGISTRY)
    (issue,) = err.value.issues
    assert issue.path.startswith("fronts[0]") and path in issue.path, issue
    assert words in issue.message, issue


@pytest.mark.parametrize(
    ("entry", "words"),
    [("6000-1-8", "index:sub/bits"), ("0x6000:1/65", "1..64 bits"), (-1, "32-bit")],
)
def test_mapping_entries_are_parsed(entry, words):
    with pytest.raises(TopologyError) as err:
        load_topology(topo({"node_id": 5, "tpdos": {1: {"mapping": [entry]}}}), REGISTRY)
    assert words in err.value.issues[0].message
    assert err.value.issues[0].path.startswith("fronts[0].tpdos[1].mapping")


def test_reserved_transmission_types_are_refused():
    with pytest.raises(TopologyError) as err:
        load_topology(topo({"node_id": 5, "tpdos": {1: {"transmission_type": 245}}}), REGISTRY)
    assert "reserved" in err.value.issues[0].message
