"""I/O connections: poll (with I/O fragmentation), bit-strobe, cyclic, change-of-state, timeouts."""

from dnet_rig import Rig, image_with

from fieldgate.image import Kind


def set_inputs(rig, value: int, bits: int = 16) -> None:
    for i in range(bits):
        rig.image.update_input(f"io/m1/di{i}", bool(value >> i & 1))


def poll_rig(choice=0x07):
    rig = Rig()
    assert rig.allocate(choice) == "44B 0A CB 00"
    assert rig.explicit("10 05 02 09 0A 0E") == "0A 90 10 0E"
    assert (
        rig.explicit("10 05 01 09 00 00") == "0A 90 00 00"
    )  # explicit EPR 0: no explicit watchdog
    return rig


def test_seed_poll():
    rig = poll_rig()
    set_inputs(rig, 0xDFFF)
    assert rig.send("44D FF FF") == ["3C9 FF DF"]  # TV-05 / TV-06
    assert all(rig.image.value(f"io/m1/do{i}") for i in range(16))
    assert rig.send("44D 01 80") == ["3C9 FF DF"]
    assert [rig.image.value(f"io/m1/do{i}") for i in (0, 1, 15)] == [True, False, True]


def test_poll_wrong_size_is_dropped_and_idle_keeps_outputs():
    rig = poll_rig()
    rig.send("44D 03 00")
    assert rig.send("44D 01") == [] and rig.send("44D 01 02 03") == []
    assert rig.slave.counters["rx_poll_wrong_size"] == 2
    assert rig.send("44D") == ["3C9 00 00"]  # zero length: idle, answered, outputs kept
    assert rig.image.value("io/m1/do1") is True


def test_poll_before_epr_is_not_answered():
    rig = Rig()
    rig.allocate(0x03)
    assert rig.send("44D FF FF") == []
    assert rig.slave.counters["rx_poll_without_connection"] == 1


def test_seed_io_fragmentation_of_a_10_byte_poll():
    # 1 module with 16 DO and 4 AO -> 2 + 8 = 10 consumed bytes; 24 DI + 4 AI -> 3 + 8 = 11 produced
    image = image_with([(1, {Kind.DO: 16, Kind.AO: 4, Kind.DI: 24, Kind.AI: 4})])
    rig = Rig(image)
    rig.allocate(0x03)
    rig.explicit("10 05 02 09 E8 03")
    for i in range(4):
        image.update_input(f"io/m1/ai{i}", -1 - i)
    image.update_input("io/m1/di17", True)
    assert rig.send("44D 00 01 02 03 04 05 06 07") == []  # TV-52 first fragment
    assert rig.send("44D 81 08 09 0A") == [
        "3C9 00 00 00 02 FF FF FE FF",
        "3C9 81 FD FF FC FF",
    ]  # TV-53
    assert [image.value(f"io/m1/do{i}") for i in range(16)] == [
        bool(0x0201 >> i & 1) for i in range(16)
    ]
    assert [image.value(f"io/m1/ao{i}") for i in range(4)] == [0x0403, 0x0605, 0x0807, 0x0A09]
    assert rig.send("44D 81 08 09 0A") == []  # final without a first: dropped
    assert rig.slave.counters["rx_io_fragments_dropped"] == 1


def test_seed_bit_strobe_from_the_master_mac():
    rig = poll_rig()
    assert rig.explicit("10 05 03 09 0A 0E") == "0A 90 10 0E"  # TV-07 / TV-08
    set_inputs(rig, 0xDFFF)
    assert rig.send("450 FF FF FF FF FF FF FF FF") == ["389 FF DF"]  # TV-09 (master's MAC) / TV-10
    assert (
        rig.send("448 FF FF FF FF FF FF FF FF") == []
    )  # the seed's printed ID: another master's strobe
    assert rig.send("450 FF FF") == []
    assert rig.slave.counters["rx_strobe_wrong_size"] == 1


def test_seed_cyclic_with_acknowledge():
    rig = Rig()
    assert rig.allocate(0x21) == "44B 0A CB 00"  # TV-11
    rig.explicit("10 05 01 09 00 00")
    set_inputs(rig, 0xDFFF)
    assert rig.send("44C 0A 10 05 04 09 0A 0E") == ["44B 0A 90 10 0E", "349 FF DF"]  # TV-13..15
    assert rig.explicit("0E 05 04 05") == "0A 8E 4A 04"  # consumes the ack on 0x44A
    rig.send("44A")  # TV-16, within the Acknowledge Handler's 16 ms
    for _ in range(3):
        assert rig.advance(3.6) == ["349 FF DF"]
        rig.send("44A")  # TV-16
    assert rig.master_events == []
    assert rig.advance(3.6 * 4 + 0.01)[-1] == "349 FF DF"  # no more acks: the watchdog fires
    assert (
        rig.slave.counters["cos_cyclic_retries"] == 3
    )  # the 3 unacked ones once more, 16 ms later
    assert rig.master_events == [(False, "cos-cyclic connection timed out (3600 ms x 4)")]
    assert rig.advance(10) == []  # timed out: production stops


def test_seed_cyclic_with_ack_suppression_never_times_out():
    rig = Rig()
    assert rig.allocate(0x61) == "44B 0A CB 00"  # TV-17
    rig.explicit("10 05 01 09 00 00")
    assert rig.send("44C 0A 10 05 04 09 0A 0E") == ["44B 0A 90 10 0E", "349 00 00"]
    assert rig.explicit("0E 05 04 05") == "0A 8E FF FF"
    assert rig.advance(36.0).count("349 00 00") == 10  # TV-20: no acks needed
    assert rig.master_events == []


def test_change_of_state_produces_on_change_with_inhibit_time():
    rig = Rig()
    assert rig.allocate(0x11) == "44B 0A CB 00"
    assert rig.explicit("10 05 04 11 64 00") == "0A 90"  # inhibit 100 ms
    assert rig.send("44C 0A 10 05 04 09 E8 03") == ["44B 0A 90 E8 03", "349 00 00"]
    rig.advance(0.05)
    set_inputs(rig, 0x0001)
    rig.slave.inputs_changed(rig.now)
    assert rig.advance(0.0) == []  # inhibited until 100 ms after the last production
    assert rig.advance(0.05) == ["349 01 00"]
    rig.advance(0.2)
    set_inputs(rig, 0x0003)
    rig.slave.inputs_changed(rig.now)
    assert [str(f) for f in rig.slave.flush()] == ["349 [2] 03 00"]
    rig.send("44A")
    assert rig.advance(1.0) == ["349 03 00"]  # EPR heartbeat without change


def test_poll_timeout_is_master_lost_and_reallocation_is_ok():
    rig = poll_rig(0x03)
    rig.send("44D 01 00")
    assert rig.advance(4 * 3.6 - 0.01) == [] and rig.master_events == []
    rig.send("44D 01 00")  # kicks the watchdog
    rig.advance(4 * 3.6 - 0.01)
    assert rig.master_events == []
    rig.advance(0.02)
    assert rig.master_events == [(False, "poll connection timed out (3600 ms x 4)")]
    assert rig.explicit("0E 05 02 01") == "0A 8E 04"  # timed out
    assert rig.send("44D 01 00") == []
    assert rig.allocate(0x02) == "44B 0A CB 00"  # re-allocation re-opens it
    assert rig.master_events[-1] == (True, "connection set allocated")
    rig.explicit("10 05 02 09 0A 0E")
    assert rig.send("44D 01 00") == ["3C9 00 00"]


def test_auto_delete_timeout_and_release_of_running_io_are_master_lost():
    rig = poll_rig(0x03)
    assert rig.explicit("10 05 02 0C 01") == "0A 90"
    rig.advance(15.0)
    assert not rig.slave.connections[2].exists and rig.slave.allocation_choice & 0x02 == 0
    assert rig.master_events == [(False, "poll timed out (deleted)")]
    rig.allocate(0x02)
    rig.explicit("10 05 02 09 0A 0E")
    assert rig.send("44E 0A 4C 03 01 02") == ["44B 0A CC"]
    assert rig.master_events[-1] == (False, "poll connection released")
