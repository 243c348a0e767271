"""SYNC consumer/producer with loss detection; store/restore 0x1010/0x1011 and its file."""

import json

import pytest
from canopen_rig import Rig, seed_node

from fieldgate.plugins.canopen.cia301.service import Service


class SyncRecorder(Service):
    name = "sync_recorder"

    def __init__(self):
        super().__init__()
        self.seen = []

    def on_sync(self, counter, now):
        self.seen.append((counter, round(now, 3)))


@pytest.fixture
def rig():
    node = seed_node(1)
    node.recorder = node.add_service(SyncRecorder())
    return Rig(node)


def test_sync_consumer_notifies_services(rig):
    assert rig.send("080") == []
    rig.send("000 02 01")
    rig.send("080")  # not in stopped
    rig.send("000 01 01")
    rig.send("080")
    assert rig.node.recorder.seen == [(None, 0.0), (None, 0.0)]


def test_sync_loss_emcy_and_clear(rig):
    assert rig.sdo("23 06 10 00 A0 86 01 00") == "60 06 10 00 00 00 00 00"  # 100 ms
    assert rig.advance(1.0) == []  # supervision starts at the first SYNC
    rig.send("080")
    assert rig.advance(0.149) == []
    assert rig.advance(0.002) == ["081 00 81 11 02 00 00 00 00"]
    assert rig.send("080") == ["081 00 00 00 00 00 00 00 00"]


def test_sync_counter_and_overflow_rules(rig):
    assert rig.sdo("2F 19 10 00 01 00 00 00") == "80 19 10 00 30 00 09 06"
    assert rig.sdo("2F 19 10 00 F1 00 00 00") == "80 19 10 00 30 00 09 06"
    assert rig.sdo("2F 19 10 00 04 00 00 00") == "60 19 10 00 00 00 00 00"
    rig.send("080 03")
    rig.send("080")  # wrong length with a counter configured
    assert rig.node.recorder.seen == [(3, 0.0)]
    rig.sdo("23 06 10 00 A0 86 01 00")
    assert rig.sdo("2F 19 10 00 00 00 00 00") == "80 19 10 00 22 00 00 08"


def test_sync_producer(rig):
    rig.sdo("2F 19 10 00 03 00 00 00")
    rig.sdo("23 06 10 00 10 27 00 00")  # 10 ms
    assert rig.sdo("23 05 10 00 80 00 00 40") == "60 05 10 00 00 00 00 00"
    assert rig.advance(0.045) == ["080 01", "080 02", "080 03", "080 01"]
    assert [c for c, _ in rig.node.recorder.seen] == [1, 2, 3, 1]


def test_store_restart_restore(tmp_path):
    path = tmp_path / "node.json"
    r = Rig(seed_node(1, store_path=path, fingerprint="set-A"))
    r.node.service("store").load()
    r.sdo("2B 17 10 00 F4 01 00 00")  # heartbeat 500
    r.sdo("2B 02 21 00 2A 00 00 00")  # application value 42
    assert r.sdo("23 10 10 01 73 61 76 65") == "60 10 10 01 00 00 00 00"
    assert r.sdo("40 10 10 01 00 00 00 00") == "43 10 10 01 01 00 00 00"
    doc = json.loads(path.read_text())
    assert doc["fingerprint"] == "set-A" and doc["values"] == {"1017.00": 500, "2102.00": 42}
    # power cycle
    node = seed_node(1, store_path=path, fingerprint="set-A")
    node.service("store").load()
    r2 = Rig(node)
    assert node.od.get(0x1017) == 500 and node.od.get(0x2102) == 42
    assert r2.advance(0.5) == ["701 7F"]
    # "load": defaults come back at the next reset, not before
    assert r2.sdo("23 11 10 01 6C 6F 61 64") == "60 11 10 01 00 00 00 00"
    assert node.od.get(0x1017) == 500
    r2.send("000 81 01")
    assert node.od.get(0x1017) == 0 and node.od.get(0x2102) == 0
    assert json.loads(path.read_text())["values"] == {}


def test_store_communication_area_only(tmp_path):
    path = tmp_path / "node.json"
    r = Rig(seed_node(1, store_path=path))
    r.sdo("2B 17 10 00 F4 01 00 00")
    r.sdo("2B 02 21 00 2A 00 00 00")
    r.sdo("23 10 10 02 73 61 76 65")
    assert json.loads(path.read_text())["values"] == {"1017.00": 500}
    assert r.sdo("23 11 10 01 6C 6F 61 65") == "80 11 10 01 20 00 00 08"


@pytest.mark.parametrize(
    "content, emcy",
    [
        (b"{not json", "081 00 50 81 02 00 00 00 00"),
        (
            json.dumps(
                {
                    "format": "fieldgate-canopen-store/1",
                    "fingerprint": "set-B",
                    "values": {"1017.00": 500},
                }
            ).encode(),
            "081 00 63 81 0C 00 00 00 00",
        ),
    ],
)
def test_bad_store_falls_back_to_defaults_with_emcy(tmp_path, caplog, content, emcy):
    path = tmp_path / "node.json"
    path.write_bytes(content)
    node = seed_node(1, store_path=path, fingerprint="set-A")
    node.service("store").load()
    r = Rig(node)
    assert r.boot == ["701 00", emcy]
    assert node.od.get(0x1017) == 0
    assert len([rec for rec in caplog.records if "store" in rec.name]) == 1
    # a successful save clears the error
    assert sorted(r.send("601 23 10 10 01 73 61 76 65")) == [
        "081 00 00 00 00 00 00 00 00",
        "581 60 10 10 01 00 00 00 00",
    ]


def test_store_without_file_aborts():
    r = Rig(seed_node(1))
    assert r.sdo("23 10 10 01 73 61 76 65") == "80 10 10 01 20 00 00 08"


def test_store_write_failure_keeps_previous_copy(tmp_path, monkeypatch):
    path = tmp_path / "node.json"
    r = Rig(seed_node(1, store_path=path))
    r.sdo("2B 17 10 00 F4 01 00 00")
    r.sdo("23 10 10 01 73 61 76 65")
    before = path.read_bytes()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr("os.fsync", boom)
    r.sdo("2B 17 10 00 64 00 00 00")
    out = r.send("601 23 10 10 01 73 61 76 65")
    assert out == ["081 00 50 81 02 00 00 00 00", "581 80 10 10 01 00 00 06 06"]  # EEPROM error
    assert path.read_bytes() == before


def test_store_path_that_cannot_be_read_falls_back(tmp_path):
    (tmp_path / "blocker").write_text("a file, not a directory")
    node = seed_node(1, store_path=tmp_path / "blocker" / "node.json")
    node.service("store").load()
    r = Rig(node)
    assert r.boot == ["701 00", "081 00 50 81 02 00 00 00 00"]


def test_sync_cob_id_rules(rig):
    assert rig.sdo("23 05 10 00 80 00 00 20") == "80 05 10 00 30 00 09 06"  # 29-bit
    assert rig.sdo("23 05 10 00 80 00 00 40") == "60 05 10 00 00 00 00 00"  # producer on
    assert (
        rig.sdo("23 05 10 00 81 00 00 40") == "80 05 10 00 30 00 09 06"
    )  # id change while producing
    assert rig.sdo("23 05 10 00 80 00 00 00") == "60 05 10 00 00 00 00 00"
    assert rig.sdo("23 05 10 00 90 00 00 00") == "60 05 10 00 00 00 00 00"
    rig.send("090")
    assert len(rig.node.recorder.seen) == 1


def test_store_of_another_module_set_drops_its_sections_too(tmp_path, caplog):
    path = tmp_path / "node.json"
    path.write_text(
        json.dumps(
            {
                "format": "fieldgate-canopen-store/1",
                "fingerprint": "set-B",
                "values": {"1017.00": 500},
                "sections": {"io401": {"pdo": [1, 2]}},
            }
        )
    )
    node = seed_node(1, store_path=path, fingerprint="set-A")
    store = node.service("store")
    store.load()
    r = Rig(node)
    assert r.boot == ["701 00", "081 00 63 81 0C 00 00 00 00"]
    assert store.section("io401") is None and node.od.get(0x1017) == 0
    assert len([rec for rec in caplog.records if "store" in rec.name]) == 1
    # the next save writes this module set's data only
    assert r.send("601 23 10 10 01 73 61 76 65")[-1] == "581 60 10 10 01 00 00 00 00"
    doc = json.loads(path.read_text())
    assert doc["fingerprint"] == "set-A" and doc["sections"] == {} and doc["values"] == {}


def test_store_fingerprint_covers_contributed_parts(tmp_path):
    path = tmp_path / "node.json"

    def node_with(part):
        node = seed_node(1, store_path=path, fingerprint="set-A")
        node.service("store").add_fingerprint(part)
        node.service("store").load()
        Rig(node)  # boot: stored values become the current ones
        return node

    first = node_with("style=icpdas")
    Rig(first, now=1.0).sdo("2B 17 10 00 F4 01 00 00")
    first.service("store").save(1)
    assert node_with("style=icpdas").od.get(0x1017) == 500
    assert node_with("style=na9161").od.get(0x1017) == 0


def test_resets_reload_values_without_calling_write_listeners():
    node = seed_node(1)
    seen = []
    for index in (0x1010, 0x1011, 0x1017, 0x2102):
        node.od.on_write(index, lambda index, sub, value: seen.append((index, sub, value)))
    r = Rig(node)
    r.sdo("2B 17 10 00 F4 01 00 00")
    r.sdo("2B 02 21 00 2A 00 00 00")
    assert seen == [(0x1017, 0, 500), (0x2102, 0, 42)]
    seen.clear()
    assert r.send("000 81 01") == ["701 00"]  # reset node: everything reloaded, nothing "written"
    assert r.send("000 82 01") == ["701 00"]
    assert seen == []
    assert node.od.get(0x1017) == 0 and node.od.get(0x2102) == 0
    assert r.advance(1.0) == []  # the heartbeat producer follows the reloaded 0x1017 = 0


@pytest.mark.parametrize(
    "can_id",
    [
        0x000,
        0x001,
        0x07F,
        0x101,
        0x180,
        0x581,
        0x5FF,
        0x601,
        0x67F,
        0x6E0,
        0x6FF,
        0x701,
        0x77F,
        0x780,
        0x7FF,
    ],
)
def test_sync_cob_id_restricted_can_ids_are_refused(rig, can_id):
    request = "23 05 10 00 " + (can_id | 1 << 31).to_bytes(4, "little").hex(
        " "
    )  # bit 31 is "don't care" for SYNC
    assert rig.sdo(request) == "80 05 10 00 30 00 09 06"
    assert rig.node.od.get(0x1005) == 0x80


@pytest.mark.parametrize("can_id", [0x080, 0x100, 0x181, 0x580, 0x600, 0x680, 0x6DF, 0x700])
def test_sync_cob_id_unrestricted_can_ids_are_taken(rig, can_id):
    assert (
        rig.sdo("23 05 10 00 " + can_id.to_bytes(4, "little").hex(" ")) == "60 05 10 00 00 00 00 00"
    )
    assert rig.node.od.get(0x1005) == can_id
