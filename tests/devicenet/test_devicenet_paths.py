"""I/O connection paths (which assembly each connection carries) and change-of-state / cyclic
data from the master (instance 2 in its COS/cyclic role), on the engine with a fake clock.

The image is examples/i7241d-style.yaml's: I-7055 (8 DI, 8 DO) at 1, I-7017 (8 AI) at 2,
I-7024 (4 AO) at 3, so the assemblies are 0x64 DO (1 byte), 0x65 AO (8), 0x66 DI (1),
0x67 AI (16), and fieldgate's combined 0x68 all outputs (9) and 0x69 all inputs (17).
"""

from __future__ import annotations

import pytest
from dnet_rig import Rig, image_with

from fieldgate.image import Kind


def i7241d_rig(**paths) -> Rig:
    image = image_with(
        [(1, {Kind.DI: 8, Kind.DO: 8}), (2, {Kind.AI: 8}), (3, {Kind.AO: 4})], back="rs485"
    )
    rig = Rig(image, io_paths=paths)
    return rig


def path(instance: int) -> str:
    return f"20 04 24 {instance:02X} 30 03"


def test_default_paths_name_the_combined_assemblies_and_sizes_follow():
    rig = i7241d_rig()
    assert rig.allocate(0x03) == "44B 0A CB 00"
    assert rig.explicit("0E 04 00 02") == "0A 8E 69 00"  # max instance: 0x69 all inputs
    assert rig.explicit("0E 05 02 0D") == "0A 8E 06 00"
    assert rig.explicit("0E 05 02 0E") == "0A 8E " + path(0x69)
    assert rig.explicit("0E 05 02 10") == "0A 8E " + path(0x68)
    assert rig.explicit("0E 05 02 07") == "0A 8E 11 00"  # 17 = DI 1 + AI 16
    assert rig.explicit("0E 05 02 08") == "0A 8E 09 00"  # 9 = DO 1 + AO 8
    rig.image.update_input("rs485/m1/di0", True)
    rig.image.update_input("rs485/m2/ai7", -2)
    assert rig.slave.assemblies.instances[0x69].data() == bytes([1]) + bytes(14) + bytes(
        [0xFE, 0xFF]
    )
    assert rig.send("44C 0A 0E 04 69 03") == ["44B 8A 00 8E 01 00 00 00 00"]  # fragmented


def test_a_selected_poll_path_carries_one_assembly_each_way():
    rig = i7241d_rig(poll=("di", "do"))
    rig.allocate(0x03)
    assert rig.explicit("0E 05 02 0E") == "0A 8E " + path(0x66)
    assert rig.explicit("0E 05 02 10") == "0A 8E " + path(0x64)
    assert rig.explicit("0E 05 02 07") == "0A 8E 01 00"
    assert rig.explicit("0E 05 02 08") == "0A 8E 01 00"
    rig.explicit("10 05 02 09 E8 03")
    rig.image.update_input("rs485/m1/di3", True)
    assert rig.send("44D A5") == ["3C9 08"]
    assert [rig.image.value(f"rs485/m1/do{i}") for i in range(8)] == [
        bool(0xA5 >> i & 1) for i in range(8)
    ]
    assert rig.send("44D A5 00") == []  # 9 bytes of all outputs no longer fit
    assert rig.slave.counters["rx_poll_wrong_size"] == 1


def test_the_strobe_answers_the_first_8_bytes_of_its_assembly():
    rig = i7241d_rig(strobe=("ai", "none"))
    rig.allocate(0x05)
    assert rig.explicit("0E 05 03 0E") == "0A 8E " + path(0x67)
    assert rig.explicit("0E 05 03 07") == "0A 8E 08 00"  # 16 bytes of AI, at most 8
    assert rig.explicit("0E 05 03 10") == "0A 8E"  # consumes the strobe bits: no path
    rig.explicit("10 05 03 09 E8 03")
    for n in range(8):
        rig.image.update_input(f"rs485/m2/ai{n}", n + 1)
    assert rig.send("450 00 00 00 00 00 00 00 00") == ["389 01 00 02 00 03 00 04 00"]


def test_paths_are_set_while_configuring_and_sizes_follow():
    rig = i7241d_rig()
    rig.allocate(0x03)
    assert rig.explicit("10 05 02 0E " + path(0x67)) == "0A 90"
    assert rig.explicit("0E 05 02 07") == "0A 8E 10 00"  # AI: 16 bytes
    assert rig.explicit("10 05 02 10 " + path(0x65)) == "0A 90"
    assert rig.explicit("0E 05 02 08") == "0A 8E 08 00"
    assert rig.explicit("10 05 02 10 20 04 25 00 64 00 30 03") == "0A 90"  # 16-bit instance
    assert rig.explicit("0E 05 02 08") == "0A 8E 01 00"
    assert rig.explicit("10 05 02 10") == "0A 90"  # empty: consumes nothing
    assert rig.explicit("0E 05 02 08") == "0A 8E 00 00"
    assert rig.explicit("10 05 02 0E " + path(0x64)) == "0A 94 09 FF"  # an output to produce
    assert rig.explicit("10 05 02 0E " + path(0x70)) == "0A 94 09 FF"  # no such instance
    assert rig.explicit("10 05 02 0E 20 01 24 01 30 07") == "0A 94 09 FF"  # not an assembly
    assert rig.explicit("10 05 01 0E " + path(0x67)) == "0A 94 0E FF"  # explicit: no path
    rig.explicit("10 05 02 09 E8 03")
    assert rig.explicit("10 05 02 0E " + path(0x66)) == "0A 94 0C FF"  # established: too late
    rig.image.update_input("rs485/m2/ai0", 0x1234)
    assert rig.send("44D") == [
        "3C9 00 34 12 00 00 00 00 00",
        "3C9 41 00 00 00 00 00 00 00",
        "3C9 82 00 00",
    ]


def test_change_of_state_produces_when_its_own_path_changes():
    rig = i7241d_rig(cos=("di", "none"))
    assert rig.allocate(0x51) == "44B 0A CB 00"  # explicit + COS, ack suppressed
    assert not rig.slave.connections[2].exists  # consumes nothing: no instance 2
    assert rig.send("44C 0A 10 05 04 09 10 27") == ["44B 0A 90 10 27", "349 00"]
    rig.image.update_input("rs485/m2/ai0", 100)
    rig.slave.inputs_changed(rig.now)
    assert rig.slave.flush() == []  # an AI change is not this connection's
    rig.image.update_input("rs485/m1/di0", True)
    rig.slave.inputs_changed(rig.now)
    assert [str(f) for f in rig.slave.flush()] == ["349 [1] 01"]


def test_cos_without_poll_consumes_the_masters_data_on_instance_2_and_acknowledges():
    rig = i7241d_rig(cos=("di", "do"))
    assert rig.allocate(0x11) == "44B 0A CB 00"  # explicit + COS, acknowledged
    assert rig.explicit("0E 03 01 05") == "0A 8E 11 0A"  # allocation: no poll bit
    expected = {
        1: "01",  # configuring
        3: "82",  # server, transport class 2 (acknowledged)
        4: "C9 03",  # the ack on G1/0xF
        5: "4D 04",  # the master's data on G2/5
        6: "01",
        7: "00 00",
        8: "01 00",
        0x0E: "",
        0x10: path(0x64),
    }
    for attribute, value in expected.items():
        assert rig.explicit(f"0E 05 02 {attribute:02X}") == f"0A 8E {value}".strip(), attribute
    assert rig.explicit("0E 05 04 10") == "0A 8E 20 2B 24 01"  # instance 4: the Acknowledge Handler
    # one EPR for both directions: instance 2 is established with instance 4
    assert rig.send("44C 0A 10 05 04 09 E8 03") == ["44B 0A 90 E8 03", "349 00"]
    rig.send("44A")
    assert rig.explicit("0E 05 02 01") == "0A 8E 03"
    assert rig.send("44D 81") == ["3C9"]  # applied like a poll's outputs, acknowledged empty
    assert rig.image.value("rs485/m1/do0") and rig.image.value("rs485/m1/do7")
    assert rig.slave.counters["rx_cos_cyclic_outputs"] == 1
    assert rig.send("44D") == ["3C9"]  # idle: outputs kept, acknowledged
    assert rig.image.value("rs485/m1/do0")
    assert rig.send("44D 01 02") == []  # wrong size: dropped, not acknowledged
    assert rig.allocate(0x02) == "44B 0A 94 02 04"  # poll after COS/cyclic (seed-003 §2.10)
    assert rig.send("44E 0A 4C 03 01 02") == ["44B 0A 94 0B 02"]  # no poll to release
    assert rig.slave.status()["connections"]["cos-cyclic-data"]["consumed"] == 0x64


def test_the_masters_cos_data_times_out_as_master_loss():
    rig = i7241d_rig(cos=("di", "do"))
    rig.allocate(0x51)  # acks suppressed: the master's data is unacknowledged too
    assert rig.explicit("0E 05 02 03") == "0A 8E 80"
    assert rig.explicit("0E 05 02 04") == "0A 8E FF FF"
    assert rig.explicit("0E 05 02 06") == "0A 8E F1"
    rig.send("44C 0A 10 05 04 09 64 00")  # 100 ms
    assert rig.send("44D 01") == []  # no acknowledge
    assert rig.advance(0.39) and rig.master_events == []  # productions, no timeout yet
    rig.send("44D 03")
    rig.advance(0.41)
    assert rig.master_events == [(False, "cos-cyclic-data connection timed out (100 ms x 4)")]
    assert rig.send("44D 07") == []  # timed out: not consumed
    assert rig.image.value("rs485/m1/do1") and not rig.image.value("rs485/m1/do2")
    assert rig.allocate(0x50) == "44B 0A 94 0B 02"  # instance 4 still runs (unacknowledged)
    assert rig.send("44E 0A 4C 03 01 10") == ["44B 0A CC"]  # release COS: instance 2 goes too
    assert not rig.slave.connections[2].exists and not rig.slave.connections[4].exists
    assert rig.allocate(0x50) == "44B 0A CB 00"
    assert rig.slave.connections[2].exists


def test_cyclic_both_ways_with_fragmented_data_and_poll_allocated_together_keeps_instance_2():
    rig = i7241d_rig(cyclic=("ai", "outputs"))
    assert rig.allocate(0x21) == "44B 0A CB 00"
    assert rig.explicit("0E 05 02 08") == "0A 8E 09 00"  # all outputs: 9 bytes
    assert rig.explicit("10 05 02 09 F4 01") == "0A 90 F4 01"  # its own EPR
    assert rig.explicit("0E 05 02 01") == "0A 8E 03"
    assert rig.send("44D 00 5A 01 00 02 00 03 00") == []  # first fragment: no acknowledge yet
    assert rig.send("44D 81 04 00") == ["3C9"]  # last fragment: one acknowledge
    assert rig.image.value("rs485/m3/ao0") == 1 and rig.image.value("rs485/m3/ao3") == 4
    assert rig.image.value("rs485/m1/do1") and not rig.image.value("rs485/m1/do0")
    fresh = i7241d_rig(cyclic=("ai", "outputs"))
    assert fresh.allocate(0x23) == "44B 0A CB 00"  # poll + cyclic in one request
    assert fresh.explicit("0E 05 02 03") == "0A 8E 82" and fresh.explicit("0E 05 02 07") == (
        "0A 8E 11 00"
    )  # instance 2 is the poll (outputs come by poll)
    assert fresh.slave.status()["connections"]["poll"]["consumed"] == 0x68


def test_the_acknowledge_handler_repeats_an_unacknowledged_production():
    rig = i7241d_rig(cos=("di", "none"))
    rig.allocate(0x11)
    assert rig.explicit("0E 2B 01 01") == "0A 8E 10 00"  # acknowledge timer 16 ms
    assert rig.explicit("0E 2B 01 02") == "0A 8E 01"  # retry limit 1
    assert rig.explicit("0E 2B 01 03") == "0A 8E 04 00"  # for connection instance 4
    assert rig.explicit("10 2B 01 01 64 00") == "0A 90"  # 100 ms
    assert rig.explicit("10 2B 01 01 00 00") == "0A 94 09 FF"
    assert rig.explicit("10 2B 01 03 05 00") == "0A 94 0E FF"
    assert rig.send("44C 0A 10 05 04 09 E8 03") == ["44B 0A 90 E8 03", "349 00"]
    assert rig.advance(0.099) == []
    assert rig.advance(0.002) == ["349 00"]  # the timer ran out: sent again
    assert rig.advance(0.2) == []  # the retry limit: no more until the next production
    assert rig.slave.counters["cos_cyclic_ack_failures"] == 1
    assert rig.explicit("10 2B 01 02 00") == "0A 90"  # no retries
    rig.advance(0.8)  # next production at 1 s
    assert rig.advance(0.3) == []
    rig.image.update_input("rs485/m1/di1", True)
    rig.slave.inputs_changed(rig.now)
    assert [str(f) for f in rig.slave.flush()] == ["349 [1] 02"]
    rig.send("44A")  # acknowledged
    assert rig.advance(0.5) == []


@pytest.mark.parametrize(
    ("paths", "message"),
    [
        ({"poll": ("ao", "do")}, "'ao' is an output"),
        ({"cos": ("di", "ai")}, "'ai' is an input"),
        ({"cyclic": ("bits", "none")}, "unknown assembly 'bits'"),
        ({"poll": (0x64, "none")}, "io_paths.poll.produce: assembly 0x64 holds outputs"),
        ({"poll": (0x99, "none")}, "io_paths.poll.produce: no assembly '153' here"),
    ],
)
def test_a_path_that_names_the_wrong_assembly_is_refused(paths, message):
    with pytest.raises(ValueError, match=message):
        i7241d_rig(**paths)


def test_a_front_without_analog_inputs_refuses_an_ai_path():
    image = image_with([(1, {Kind.DI: 8, Kind.DO: 8})])
    with pytest.raises(ValueError) as err:
        Rig(image, io_paths={"cos": ("ai", "none")})
    assert str(err.value) == (
        "io_paths.cos.produce: no assembly 'ai' here (this front serves "
        "DO assembly 0x64 (1 byte), DI assembly 0x65 (1 byte))"
    )


def test_the_status_page_says_where_each_point_travels_on_every_path(tmp_path):
    from fieldgate import load_registry
    from fieldgate.plugin import GatewayContext
    from fieldgate.topology import load_topology

    registry = load_registry()
    topo = load_topology(
        {
            "gateway": {"name": "paths", "state_dir": str(tmp_path)},
            "fronts": [
                {
                    "name": "dnet",
                    "type": "devicenet",
                    "interface": "virtual",
                    "mac_id": 3,
                    "io_paths": {"cos": {"produce": "ai", "consume": "ao"}},
                }
            ],
            "backs": [
                {
                    "name": "io",
                    "type": "loopback",
                    "modules": [{"address": 1, "digital": 8, "analog": 2}],
                }
            ],
        },
        registry,
    )
    front = registry.lookup("front", "devicenet").factory(
        topo.fronts[0], GatewayContext.build(topo)
    )
    front.slave = front.build()
    where = front.point_locations()
    # DO 0x64, AO 0x65, DI 0x66, AI 0x67; the poll carries all (0x68, 0x69), COS AI and AO alone
    assert where["io/m1/di2"] == ["assembly 102 byte 0 bit 2 (poll response byte 0)"]
    assert where["io/m1/ai1"] == [
        "assembly 103 bytes 2-3 (poll response bytes 3-4, COS message bytes 2-3, little-endian)"
    ]
    assert where["io/m1/ao0"] == [
        "assembly 101 bytes 0-1 (poll request bytes 1-2, COS data from the master bytes 0-1, "
        "little-endian)"
    ]


def test_the_masters_cyclic_data_reach_the_image_as_one_batch():
    """COS/cyclic outputs go through the same batched write as a poll's."""
    rig = i7241d_rig(cyclic=("ai", "outputs"))
    batches = []
    rig.image.subscribe_batch(batches.append, ids=[c.id for c in rig.image if c.kind.is_output])
    rig.allocate(0x21)
    assert rig.send("44C 0A 10 05 04 09 F4 01")[0] == "44B 0A 90 F4 01"  # then 16 bytes of AI
    rig.send("44A")
    assert rig.send("44D 00 81 01 00 00 00 00 00") == []
    assert rig.send("44D 81 00 00") == ["3C9"]
    assert [sorted((c.id, c.value) for c in b) for b in batches] == [
        [("rs485/m1/do0", True), ("rs485/m1/do7", True), ("rs485/m3/ao0", 1)]
    ]
