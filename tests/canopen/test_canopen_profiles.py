"""Device profiles (``style``) and master profiles (``master``): the defaults each applies
without extra keys, the topology overriding them, ``node_id`` without a silent default.

The front's node is built as the gateway builds it (``fieldgate.plugins.canopen.eds.front_node``)
and driven with a fake clock (:class:`canopen_rig.Rig`); the process image is the front's own.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from canopen_rig import Rig, show

from fieldgate import load_registry
from fieldgate.plugins.canopen.eds import front_node
from fieldgate.topology import TopologyError, load_topology

REGISTRY = load_registry()


def topo(front: dict, modules: list | None = None) -> dict:
    return {
        "gateway": {"name": "profiles"},
        "fronts": [
            {"name": "can", "type": "canopen", "interface": "virtual", "channel": "x", **front}
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": modules or [{"address": 1, "digital": 8, "analog": 2}],
            }
        ],
    }


class Dut:
    """The front's node on a fake clock, with SDO helpers for its node-ID."""

    def __init__(self, front: dict, modules: list | None = None, tmp_path=None, backs=None):
        t = topo(front, modules)
        if backs is not None:
            t["backs"] = backs
        if tmp_path is not None:
            t["gateway"]["state_dir"] = str(tmp_path)
        self.front, self.node = front_node(t, registry=REGISTRY)
        self.image = self.front.context.image
        self.rig = Rig(self.node)
        self.id = self.node.node_id

    def sdo(self, data: str) -> str:
        out = [f for f in self.rig.send(f"{0x600 + self.id:03X} {data}") if f.startswith("5")]
        assert len(out) == 1, out
        return out[0][4:]

    def read(self, index: int, sub: int) -> str:
        return self.sdo(f"40 {index & 0xFF:02X} {index >> 8:02X} {sub:02X} 00 00 00 00")

    def start(self) -> list[str]:
        return self.rig.send(f"000 01 {self.id:02X}")

    def emcys(self, frames: list[str]) -> list[str]:
        return [f[4:] for f in frames if f.startswith(f"{0x80 + self.id:03X} ")]


NO_OBJECT = "00 00 02 06"  # abort 0602 0000


# -- node_id and the master profile -------------------------------------------------------
def load(front: dict):
    return load_topology(topo(front), REGISTRY)


def test_node_id_is_required():
    with pytest.raises(TopologyError) as err:
        load({})
    (issue,) = err.value.issues
    assert issue.path == "fronts[0].node_id"
    assert issue.message.startswith("required field is missing")


def test_null_node_id_is_an_explicit_lss_node():
    assert load({"node_id": None}).fronts[0].node_id is None


@pytest.mark.parametrize(
    ("front", "words"),
    [
        ({"node_id": 1, "master": "delta-as300"}, "the master's own"),
        ({"node_id": 65, "master": "delta-as300"}, "1..64"),
        ({"node_id": 9, "master_node_id": 9}, "the master's own (master_node_id)"),
        ({"node_id": 9, "master": "delta-as300", "master_node_id": 9}, "master_node_id"),
    ],
)
def test_validate_refuses_the_masters_node_id(front, words):
    with pytest.raises(TopologyError) as err:
        load(front)
    (issue,) = err.value.issues
    assert issue.path == "fronts[0].node_id"
    assert words in issue.message


def test_the_master_may_use_another_id_and_then_node_1_is_free():
    assert load({"node_id": 1, "master": "delta-as300", "master_node_id": 2}).fronts[0].node_id == 1
    assert load({"node_id": 1}).fronts[0].node_id == 1  # generic: no master ID known


def test_consumer_heartbeats_are_checked():
    with pytest.raises(TopologyError) as err:
        load(
            {
                "node_id": 5,
                "consumer_heartbeats": [{"node": 1, "time_ms": 300}, {"node": 1, "time_ms": 400}],
            }
        )
    assert err.value.issues[0].path == "fronts[0].consumer_heartbeats"
    with pytest.raises(TopologyError) as err:
        load(
            {
                "node_id": 5,
                "heartbeat_consumers": 1,
                "consumer_heartbeats": [{"node": 1, "time_ms": 300}, {"node": 2, "time_ms": 400}],
            }
        )
    assert err.value.issues[0].path == "fronts[0].heartbeat_consumers"


def test_validate_prints_a_line_where_the_master_profile_wins(tmp_path):
    path = tmp_path / "t.yaml"
    path.write_text(
        "gateway: {name: t}\n"
        "fronts:\n  - {name: can, type: canopen, node_id: 5, master: delta-as300}\n"
        "backs:\n  - {name: io, type: loopback, modules: [{address: 1, digital: 8}]}\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "fieldgate", "validate", str(path)], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    notes = [line for line in done.stdout.splitlines() if "warning:" in line]
    assert len(notes) == 2  # heartbeat, and the TPDOs at Start (E2); no analog input here
    assert "delta-as300" in notes[0] and "icpdas" in notes[0] and "0x1016/0x1017" in notes[0]
    assert "each asynchronous TPDO once at Start" in notes[1]
    path.write_text(path.read_text().replace("master: delta-as300", "style: na9161"))
    done = subprocess.run(
        [sys.executable, "-m", "fieldgate", "validate", str(path)], capture_output=True, text=True
    )
    assert "warning:" not in done.stdout


# -- icpdas: the I-7232D -------------------------------------------------------------------
def test_icpdas_guards_only_as_the_i7232d():
    dut = Dut({"node_id": 2})
    assert dut.rig.boot == ["702 00"]
    assert dut.read(0x1017, 0) == "80 17 10 00 00 00 02 06"  # no heartbeat producer
    assert dut.read(0x1016, 1) == "80 16 10 01 00 00 02 06"  # no heartbeat consumer
    assert dut.read(0x100C, 0) == "4B 0C 10 00 00 00 00 00"  # guard time 0: the master sets it
    assert dut.read(0x100D, 0) == "4F 0D 10 00 00 00 00 00"
    assert dut.read(0x1029, 1) == "4F 29 10 01 01 00 00 00"  # keeps its NMT state
    # TV-20: guard time 250 ms x 4, first RTR answered toggle 0, life guarding after 1 s
    assert dut.sdo("2B 0C 10 00 FA 00 00 00") == "60 0C 10 00 00 00 00 00"
    assert dut.sdo("2F 0D 10 00 04 00 00 00") == "60 0D 10 00 00 00 00 00"
    assert dut.rig.send("702 RTR") == ["702 7F"]
    assert dut.rig.advance(0.99) == []
    assert dut.emcys(dut.rig.advance(0.02)) == ["30 81 11 07 00 00 00 00"]
    assert not dut.front.context.masters.is_ok("can")


def test_icpdas_error_values_are_off_by_default():
    dut = Dut({"node_id": 2})
    assert dut.read(0x6206, 1) == "4F 06 62 01 00 00 00 00"
    assert dut.read(0x6443, 1) == "4F 43 64 01 00 00 00 00"
    dut.image.write_output("io/m1/do0", True, "test")
    dut.front.context.masters.lost("can", "test", None)
    assert dut.image.value("io/m1/do0") is True  # hold


def test_icpdas_announces_an_nmt_reset_request():
    dut = Dut({"node_id": 2})
    out = dut.rig.send("000 82 02")
    assert out[:2] == ["082 00 FF 80 0A 00 00 00 00", "702 00"]


@pytest.mark.parametrize(
    ("index", "write", "read"),
    [
        (0x6443, "2B 43 64 01 01 00 00 00", "4F 43 64 01 01 00 00 00"),
        (0x6444, "2B 44 64 01 FF 7F 00 00", "43 44 64 01 FF 7F 00 00"),
        (0x6444, "2B 44 64 01 00 80 00 00", "43 44 64 01 00 80 FF FF"),  # sign-extended
    ],
)
def test_icpdas_takes_the_manuals_two_byte_writes(index, write, read):
    dut = Dut({"node_id": 2})
    assert dut.sdo(write) == f"60 {write[3:11]} 00 00 00 00"
    assert dut.read(index, 1) == read
    assert dut.sdo("2B 43 64 01 01 01 00 00") == "80 43 64 01 30 00 09 06"  # U16 0x0101 > 1
    assert dut.sdo("27 44 64 01 00 00 00 00")[:2] == "80"  # 3 bytes: still refused


def test_na9161_takes_two_byte_0x6444_writes_but_not_0x6443():
    dut = Dut({"node_id": 5, "style": "na9161"})
    assert dut.sdo("2B 44 64 01 34 12 00 00") == "60 44 64 01 00 00 00 00"
    assert dut.sdo("2B 43 64 01 01 00 00 00") == "80 43 64 01 12 00 07 06"  # 0607 0012


def test_icpdas_sync_loss_is_an_emcy_only():
    dut = Dut({"node_id": 2, "error_mode_default": "zero"})
    dut.start()
    dut.image.write_output("io/m1/do0", True, "test")
    assert dut.sdo("23 06 10 00 10 27 00 00") == "60 06 10 00 00 00 00 00"  # 10 ms
    dut.rig.send("080")
    assert dut.emcys(dut.rig.advance(0.02)) == ["00 81 11 02 00 00 00 00"]
    assert dut.front.context.masters.is_ok("can")
    assert dut.image.value("io/m1/do0") is True
    assert dut.node.state.label == "OPERATIONAL"


# -- na9161: the NA-9161 -------------------------------------------------------------------
def test_na9161_defaults_as_its_manual():
    dut = Dut({"node_id": 5, "style": "na9161"})
    assert dut.read(0x100C, 0) == "4B 0C 10 00 C8 00 00 00"  # 200 ms
    assert dut.read(0x100D, 0) == "4F 0D 10 00 02 00 00 00"  # x 2
    assert dut.read(0x1016, 0) == "4F 16 10 00 01 00 00 00"  # one consumer entry
    assert dut.read(0x1017, 0) == "4B 17 10 00 00 00 00 00"
    assert dut.read(0x1029, 1) == "4F 29 10 01 00 00 00 00"  # pre-operational
    assert dut.read(0x1003, 0) == "4F 03 10 00 00 00 00 00"
    assert dut.node.emcy.depth == 20 and dut.node.emcy.queue_limit == 20
    assert dut.read(0x6206, 1) == "4F 06 62 01 FF 00 00 00"
    assert dut.read(0x6207, 1) == "4F 07 62 01 00 00 00 00"
    assert dut.read(0x6443, 1) == "4F 43 64 01 01 00 00 00"
    assert dut.read(0x6444, 2) == "43 44 64 02 00 00 00 00"
    assert dut.read(0x6423, 0) == "80 23 64 00 00 00 02 06"  # no AI interrupt objects
    # U32 written with 2 bytes, as its own examples do (TV-10)
    assert dut.sdo("2B 00 45 03 01 00 00 00") == "60 00 45 03 00 00 00 00"


def test_na9161_heartbeat_loss_drives_every_output_to_0():
    dut = Dut({"node_id": 5, "style": "na9161"})
    dut.start()
    for n in range(8):
        dut.image.write_output(f"io/m1/do{n}", True, "test")
    dut.image.write_output("io/m1/ao0", 1234, "test")
    dut.image.write_output("io/m1/ao1", -5, "test")
    assert dut.sdo("23 16 10 01 C8 00 01 00") == "60 16 10 01 00 00 00 00"  # node 1, 200 ms
    dut.rig.send("701 05")
    assert dut.emcys(dut.rig.advance(0.21)) == ["30 81 11 07 01 00 00 00"]
    assert [dut.image.value(f"io/m1/do{n}") for n in range(8)] == [False] * 8
    assert [dut.image.value(f"io/m1/ao{n}") for n in range(2)] == [0, 0]
    assert dut.node.state.label == "PRE-OPERATIONAL"


def test_na9161_module_error_mode_still_wins():
    modules = [{"address": 1, "digital": 8, "analog": 1, "error_mode": "hold"}]
    dut = Dut({"node_id": 5, "style": "na9161"}, modules)
    assert dut.read(0x6206, 1) == "4F 06 62 01 00 00 00 00"
    modules = [{"address": 1, "digital": 8, "analog": 1, "error_modes": {"do3": {"value": 1}}}]
    dut = Dut({"node_id": 5, "style": "na9161"}, modules)
    assert dut.read(0x6206, 1) == "4F 06 62 01 FF 00 00 00"
    assert dut.read(0x6207, 1) == "4F 07 62 01 08 00 00 00"
    dut = Dut({"node_id": 5, "style": "na9161", "error_mode_default": "hold"})
    assert dut.read(0x6206, 1) == "4F 06 62 01 00 00 00 00"


def test_na9161_sync_loss_is_an_error_event():
    """seed-004 §4.8 / §3.2 0x1006: outputs to the fault state, PRE-OPERATIONAL, ERR triple flash."""
    dut = Dut({"node_id": 5, "style": "na9161"})
    dut.start()
    dut.image.write_output("io/m1/do2", True, "test")
    assert dut.sdo("23 06 10 00 10 27 00 00") == "60 06 10 00 00 00 00 00"  # TV-23: 10 ms
    dut.rig.send("080")
    assert dut.rig.advance(0.014) == []
    out = dut.rig.advance(0.002)
    assert dut.emcys(out) == ["00 81 11 02 00 00 00 00"]
    assert dut.image.value("io/m1/do2") is False
    assert dut.node.state.label == "PRE-OPERATIONAL"
    assert not dut.front.context.masters.is_ok("can")
    dut.rig.send("080")  # SYNC back: the error ends; outputs keep their error values
    assert dut.front.context.masters.is_ok("can")
    assert dut.image.value("io/m1/do2") is False


def test_na9161_emcy_queue_overflow_is_reported_at_once():
    dut = Dut({"node_id": 5, "style": "na9161"})
    dut.start()
    assert dut.sdo("2B 15 10 00 10 27 00 00") == "60 15 10 00 00 00 00 00"  # 1 s inhibit
    dut.rig.advance(1.0)  # past the inhibit time of the power-on EMCY (a head on its defaults)
    emcy = dut.node.emcy
    sent: list[str] = []
    for n in range(22):  # the 1st goes out, 20 wait for the inhibit time, the 22nd overflows
        emcy.raise_error(0xFF00, 0x81, bytes([0x0B, n + 1]), dut.rig.now)
        sent += dut.emcys(show(dut.node.flush()))
    assert sent == ["00 FF 81 0B 01 00 00 00", "10 81 91 20 00 00 00 00"]  # at once
    assert emcy.counters["queue_overflow"] == 1 and emcy.queued == 20
    later = dut.emcys(dut.rig.advance(25.0))
    assert len(later) == 21  # the 20 queued, then the overrun's reset (quiet for 1 s)
    assert later[-1] == "00 00 81 00 00 00 00 00"  # the module errors are still active


# -- master profile -------------------------------------------------------------------------
def test_delta_as300_watches_the_masters_heartbeat_without_an_sdo_write():
    dut = Dut({"node_id": 2, "master": "delta-as300"})
    assert dut.read(0x1016, 1) == "43 16 10 01 F4 01 01 00"  # node 1, 500 ms
    assert dut.read(0x1017, 0) == "4B 17 10 00 E8 03 00 00"  # 1000 ms
    dut.start()
    dut.image.write_output("io/m1/do0", True, "test")
    for _ in range(5):  # the AS300's heartbeat every 200 ms, then it stops
        dut.rig.send("701 05")
        assert dut.emcys(dut.rig.advance(0.2)) == []
    assert dut.emcys(dut.rig.advance(0.29)) == []  # 490 ms since the last
    assert dut.emcys(dut.rig.advance(0.02)) == ["30 81 11 07 01 00 00 00"]
    assert not dut.front.context.masters.is_ok("can")
    assert dut.image.value("io/m1/do0") is True  # icpdas: error modes off (hold)


def test_delta_as300_invalidates_pdos_without_data():
    modules = [{"address": 1, "digital": 8}]  # no analog: PDO2-4 carry nothing
    plain = Dut({"node_id": 2}, modules)
    assert plain.read(0x1801, 1) == "43 01 18 01 82 02 00 00"  # icpdas: valid though empty
    dut = Dut({"node_id": 2, "master": "delta-as300"}, modules)
    assert dut.read(0x1800, 1) == "43 00 18 01 82 01 00 00"
    assert dut.read(0x1801, 1) == "43 01 18 01 82 02 00 80"
    assert dut.read(0x1401, 1) == "43 01 14 01 02 03 00 80"


def test_topology_keys_override_the_profiles():
    dut = Dut(
        {
            "node_id": 4,
            "style": "na9161",
            "master": "delta-as300",
            "heartbeat_ms": 250,
            "guard_time_ms": 0,
            "consumer_heartbeats": [{"node": 1, "time_ms": 700}, {"node": 9, "time_ms": 900}],
            "on_master_lost": "no-change",
            "emcy_history": 7,
        }
    )
    assert dut.read(0x1017, 0) == "4B 17 10 00 FA 00 00 00"
    assert dut.read(0x1016, 0) == "4F 16 10 00 02 00 00 00"
    assert dut.read(0x1016, 2) == "43 16 10 02 84 03 09 00"
    assert dut.read(0x100C, 0) == "4B 0C 10 00 00 00 00 00"
    assert dut.read(0x1029, 1) == "4F 29 10 01 01 00 00 00"
    assert dut.node.emcy.depth == 7
    # an explicit null: no heartbeat producer even under the AS300
    dut = Dut({"node_id": 4, "master": "delta-as300", "heartbeat_ms": None})
    assert dut.read(0x1017, 0) == "80 17 10 00 00 00 02 06"


# -- analog events ---------------------------------------------------------------------------
def tpdo2(dut: Dut, frames: list[str]) -> list[str]:
    return [f[4:] for f in frames if f.startswith(f"{0x280 + dut.id:03X} ")]


def test_na9161_analog_change_sends_tpdo2_within_the_inhibit_time():
    """seed-004 §3.4 / §4.7: a type-254 TPDO carrying analog data is sent on any change,
    limited by the inhibit time (500 ms), without any SDO write (no 0x6423 to set)."""
    dut = Dut({"node_id": 5, "style": "na9161"})
    assert tpdo2(dut, dut.start()) == ["00 00 00 00"]  # every TPDO once on entering Operational
    dut.rig.advance(0.6)  # past the inhibit time of that transmission
    dut.image.update_input("io/m1/ai1", 0x1234)
    assert tpdo2(dut, show(dut.node.flush()) + dut.rig.advance(0.0)) == ["00 00 34 12"]
    dut.image.update_input("io/m1/ai0", -2)  # within the inhibit time: held back, then sent
    assert tpdo2(dut, show(dut.node.flush()) + dut.rig.advance(0.49)) == []
    assert tpdo2(dut, dut.rig.advance(0.02)) == ["FE FF 34 12"]


def test_icpdas_analog_change_sends_no_tpdo():
    """seed-000 §2.7, step 4: analog changes are no TPDO events (0x6423 default FALSE)."""
    dut = Dut({"node_id": 2})
    assert tpdo2(dut, dut.start()) == []  # TV-07: no frame after Start
    dut.image.update_input("io/m1/ai0", 0x1234)
    assert tpdo2(dut, show(dut.node.flush()) + dut.rig.advance(2.0)) == []
    assert dut.read(0x6423, 0) == "4F 23 64 00 00 00 00 00"  # served, FALSE
    assert dut.sdo("2F 23 64 00 01 00 00 00") == "60 23 64 00 00 00 00 00"  # opt in: CiA 401
    dut.image.update_input("io/m1/ai0", 0x1300)
    assert tpdo2(dut, show(dut.node.flush()) + dut.rig.advance(0.0)) == ["00 13 00 00"]
