"""Bad input never escapes: random frames into the node; the dictionary exports as EDS."""

import random

import canopen
from canopen_rig import Rig, seed_node

from fieldgate.can.frame import Frame

IDS = [0x000, 0x080, 0x081, 0x100, 0x201, 0x601, 0x602, 0x701, 0x77F, 0x7E5, 0x7FF]


def test_random_frames_never_raise_and_answers_are_well_formed():
    rng = random.Random(20261122)
    rig = Rig(seed_node(1, heartbeat_consumers=2))
    rig.sdo("23 16 10 01 20 00 7F 00")
    for i in range(20_000):
        can_id = rng.choice(IDS) if rng.random() < 0.9 else rng.randrange(0x800)
        if can_id == 0x601 and rng.random() < 0.7:  # mostly plausible SDO requests
            data = (
                bytes(
                    [
                        rng.choice(
                            [
                                0x20,
                                0x23,
                                0x2B,
                                0x2F,
                                0x40,
                                0x60,
                                0x70,
                                0x00,
                                0x10,
                                0x80,
                                0xA0,
                                0xA3,
                                0xA2,
                                0xA1,
                                0xC0,
                                0xC6,
                                0x81,
                                0x01,
                            ]
                        )
                    ]
                )
                + rng.choice(
                    [b"\x00\x10", b"\x08\x10", b"\x03\x10", b"\x01\x21", b"\x00\x14", b"\x16\x10"]
                )
                + bytes(rng.randrange(256) for _ in range(5))
            )
        elif can_id == 0x000 and rng.random() < 0.3:
            data = bytes(
                [rng.choice([0x01, 0x02, 0x80]), rng.choice([0, 1])]
            )  # never a reset: keep state
        else:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        rtr = rng.random() < 0.05
        out = rig.node.receive(Frame(can_id, b"" if rtr else data, rtr=rtr, dlc=len(data)), rig.now)
        if i % 50 == 0:
            out += rig.node.tick(rig.now + 0.01)
            rig.now += 0.01
        for f in out:
            assert 0 <= f.can_id <= 0x7FF and len(f.data) <= 8
    assert rig.node.counters["internal_errors"] == 0
    assert rig.node.service("sdo").counters["aborts"] > 100
    # still serving
    rig.send("000 80 01")
    assert rig.sdo("40 00 14 00 00 00 00 00") == "4F 00 14 00 02 00 00 00"


def test_dictionary_exports_as_eds_and_reimports(tmp_path):
    node = seed_node(1)
    path = tmp_path / "node.eds"
    canopen.export_od(node.od.model, str(path))
    od = canopen.import_od(str(path), node_id=1)
    assert od[0x1018][1].default == 0x1234
    assert od[0x1014].default == 0x81
    assert od[0x1003][5].access_type == "ro"
    assert od[0x1200][1].default == 0x601


def test_a_failing_service_is_counted_not_raised(caplog):
    from fieldgate.plugins.canopen.cia301.service import Service

    class Broken(Service):
        name = "broken"

        def on_frame(self, frame, now):
            if frame.can_id == 0x123:
                raise RuntimeError("bug")
            return False

        def deadline(self):
            return 0.0

        def poll(self, now):
            raise ValueError("bug in a timer")

    rig = Rig(seed_node(1))
    rig.node.add_service(Broken())
    assert rig.send("123 01") == []
    assert rig.node.counters["internal_errors"] == 2  # on_frame, then its overdue poll
    assert rig.sdo("40 00 14 00 00 00 00 00") == "4F 00 14 00 02 00 00 00"
    assert any("broken" in r.getMessage() for r in caplog.records)


def test_dictionary_serves_an_imported_eds(tmp_path):
    from fieldgate.plugins.canopen.cia301.od import Dictionary

    path = tmp_path / "node.eds"
    canopen.export_od(seed_node(1).od.model, str(path))
    served = Dictionary(canopen.import_od(str(path), node_id=7), node_id=7)
    assert served.get(0x1014) == 0x87 and served.get(0x1200, 2) == 0x587
    assert served.read(0x1008, 0) == b"CPS_DCON\x00"
    served.node_id = 9
    served.reload()
    assert served.get(0x1014) == 0x89


def test_frame_routes_follow_cob_id_changes():
    rig = Rig(seed_node(1))
    assert rig.sdo("40 00 14 00 00 00 00 00") == "4F 00 14 00 02 00 00 00"  # 0x601 routed to SDO
    seen = []
    rig.node.service("sync").on_sync = lambda counter, now: seen.append(counter)
    # SYNC moved onto 0x601 (sync comes before sdo in the node): it must now win. 0x601 is a
    # restricted CAN-ID that an SDO write refuses; a local write bypasses the validators.
    rig.node.od.set(0x1005, 0, 0x601)
    assert rig.send("601") == []
    assert seen == [None]
    rig.node.od.set(0x1005, 0, 0x80)
    assert rig.sdo("40 00 14 00 00 00 00 00") == "4F 00 14 00 02 00 00 00"


def test_integer_encoding_matches_canopens_and_refuses_bad_values():
    """od.encode packs integers itself (the SDO fast path); it must agree with canopen's encoder."""
    import pytest
    from canopen.objectdictionary import ODVariable
    from canopen.objectdictionary import datatypes as cdt

    from fieldgate.plugins.canopen.cia301.od import encode

    for data_type in cdt.INTEGER_TYPES:
        var = ODVariable("x", 0x2000)
        var.data_type = data_type
        size = var.STRUCT_TYPES[data_type].size
        signed = data_type in cdt.SIGNED_TYPES
        for value in (
            (-(1 << (8 * size - 1)), -1, 0, 1, (1 << (8 * size - 1)) - 1)
            if signed
            else (0, 1, (1 << (8 * size)) - 1)
        ):
            assert encode(var, value) == var.encode_raw(value)
        if size in (
            1,
            2,
            4,
            8,
        ):  # canopen's 24/40/48/56-bit packers truncate silently (theirs, unchanged)
            with pytest.raises(ValueError):
                encode(var, 1 << (8 * size))
        with pytest.raises(TypeError):
            encode(var, "1")


def test_frames_are_immutable_values():
    import pytest

    a, b = (
        Frame(0x605, b"\x40\x00\x10\x00\x00\x00\x00\x00"),
        Frame(0x605, bytes.fromhex("4000100000000000")),
    )
    assert (
        a == b and hash(a) == hash(b) and a != Frame(0x605, b"\x40", rtr=False) and len({a, b}) == 1
    )
    with pytest.raises(AttributeError):
        a.can_id = 0x606
    assert (
        str(Frame(0x705, b"", rtr=True, dlc=1)) == "705 RTR [1]"
        and Frame(0x705, b"", rtr=True, dlc=1).length == 1
    )
    assert str(a) == "605 [8] 40 00 10 00 00 00 00 00"
