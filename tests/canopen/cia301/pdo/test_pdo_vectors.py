"""Byte-for-byte PDO vectors: seed-000 TV-08..TV-23 and the seed-001 Step 0-44 walk-through.

The consistent readings of the extracts are used where the manuals misprint (COB-IDs,
DLCs, the 0x1805/0x1A05 "5th" PDO). Analog values are the loopback's exact values.
"""

from __future__ import annotations

from io_bench import Bench, demo_7231d, demo_7232d, make_image, module_health

OK = "60 {:02X} {:02X} {:02X} 00 00 00 00"


def ok(index, sub):
    return OK.format(index & 0xFF, index >> 8, sub)


def do_byte(bench, address=3):
    return sum(int(bench.image.value(f"bus/m{address}/do{i}")) << i for i in range(8))


def test_tv08_to_tv19_i7232d_demo_walk_through():
    b = demo_7232d()
    b.start()
    # TV-08: RxPDO1 (DLC 8 > mapped 1) writes DO; the looped-back DI change sends TxPDO1
    assert b.rx(0x201, "34 00 00 00 00 00 00 00") == ["181 [1] 34"]
    assert do_byte(b) == 0x34
    # TV-09: RxPDO2 writes AO; analog changes send nothing
    assert b.rx(0x301, "FF 1F 00 00 00 00 00 00") == []
    assert b.value(0x6411, 1) == 0x1FFF and b.image.value("bus/m4/ao0") == 0x1FFF
    # TV-10: RTR on TxPDO2 answers the current AI
    assert b.rx(0x281, rtr=True) == ["281 [2] FF 1F"]
    # TV-11: event timer 1000 ms sends TxPDO2 every second; 0 stops it
    assert b.write(0x1801, 5, 1000, 2) == ok(0x1801, 5)
    assert b.advance(3.05) == ["281 [2] FF 1F"] * 3
    assert b.write(0x1801, 5, 0, 2) == ok(0x1801, 5)
    assert b.advance(3.0) == []
    # TV-12: RxPDO1 type 0 latches until SYNC
    assert b.write(0x1400, 2, 0, 1) == ok(0x1400, 2)
    assert b.rx(0x201, "78 00 00 00 00 00 00 00") == []
    assert do_byte(b) == 0x34
    assert b.sync() == ["181 [1] 78"]
    assert b.write(0x1400, 2, 0xFF, 1) == ok(0x1400, 2)
    # TV-13: TxPDO1 type 0: sent at SYNC only after a DI change
    assert b.write(0x1800, 2, 0, 1) == ok(0x1800, 2)
    assert b.rx(0x201, "EA 00 00 00 00 00 00 00") == []
    assert b.sync() == ["181 [1] EA"]
    assert b.sync() == []
    # TV-14: type 3: every third SYNC
    assert b.write(0x1800, 2, 3, 1) == ok(0x1800, 2)
    assert b.rx(0x201, "EF 00 00 00 00 00 00 00") == []
    assert b.sync() == [] and b.sync() == []
    assert b.sync() == ["181 [1] EF"]
    # TV-15: type 252: RTR answers what the last SYNC sampled
    assert b.write(0x1800, 2, 0xFC, 1) == ok(0x1800, 2)
    assert b.rx(0x201, "34 00 00 00 00 00 00 00") == []
    assert b.rx(0x181, rtr=True) == ["181 [1] EF"]
    assert b.sync() == []
    assert b.rx(0x181, rtr=True) == ["181 [1] 34"]
    # TV-16: type 253: RTR answers the current value
    assert b.write(0x1800, 2, 0xFD, 1) == ok(0x1800, 2)
    assert b.rx(0x201, "78 00 00 00 00 00 00 00") == []
    assert b.rx(0x181, rtr=True) == ["181 [1] 78"]
    assert b.write(0x1800, 2, 0xFF, 1) == ok(0x1800, 2)
    # TV-17: a new TxPDO at 0x1805/0x1A05 on 0x182: DI + AI1
    assert b.write(0x1805, 1, 0x182, 4) == ok(0x1805, 1)
    assert b.write(0x1A05, 1, 0x60000108, 4) == ok(0x1A05, 1)
    assert b.write(0x1A05, 2, 0x64010110, 4) == ok(0x1A05, 2)
    assert b.write(0x1A05, 0, 2, 1) == ok(0x1A05, 0)
    # TV-18: a new RxPDO at 0x1405/0x1605 on 0x202: DO + AO1; one DI change fires both TxPDOs
    assert b.write(0x1405, 1, 0x202, 4) == ok(0x1405, 1)
    assert b.write(0x1605, 1, 0x62000108, 4) == ok(0x1605, 1)
    assert b.write(0x1605, 2, 0x64110110, 4) == ok(0x1605, 2)
    assert b.write(0x1605, 0, 2, 1) == ok(0x1605, 0)
    assert b.rx(0x202, "54 00 00 00 00 00 00 00") == ["181 [1] 54", "182 [3] 54 00 00"]
    assert b.image.value("bus/m4/ao0") == 0
    # TV-19: RxPDO1 shorter than its mapping: ignored, EMCY 8210, history, register; cleared by a good one
    assert b.rx(0x201, "") == ["081 [8] 10 82 11 09 00 00 00 00"]
    assert do_byte(b) == 0x54
    assert b.read(0x1003, 1) == "43 03 10 01 10 82 09 00"
    assert b.read(0x1001, 0)[:14] == "4F 01 10 00 11"
    assert b.rx(0x201, "00") == [
        "081 [8] 00 00 00 00 00 00 00 00",
        "181 [1] 00",
        "182 [3] 00 00 00",
    ]
    assert b.read(0x1003, 1) == "43 03 10 01 00 00 00 00"
    assert b.read(0x1003, 2) == "43 03 10 02 10 82 09 00"
    assert b.read(0x1001, 0)[:14] == "4F 01 10 00 00"
    assert b.rx(0x201, "01") == ["181 [1] 01", "182 [3] 01 00 00"]  # no second reset EMCY


def test_tv20_tv23_life_guarding_drives_outputs_to_their_error_values():
    b = demo_7232d()
    b.start()
    assert b.write(0x6206, 1, 0x31, 1) == ok(0x6206, 1)
    assert b.write(0x6207, 1, 0xF8, 1) == ok(0x6207, 1)
    assert b.write(0x6443, 1, 1, 1) == ok(0x6443, 1)
    assert b.write(0x6444, 1, 0, 4) == ok(0x6444, 1)
    assert b.rx(0x301, "34 12") == []
    assert b.rx(0x201, "00") == []  # DO byte 0x00 (DI already 0)
    assert b.write(0x100C, 0, 250, 2) == ok(0x100C, 0)
    assert b.write(0x100D, 0, 4, 1) == ok(0x100D, 0)
    assert b.rx(0x701, rtr=True) == ["701 [1] 05"]
    assert b.advance(0.9) == []
    frames = b.advance(0.2)
    assert frames[0] == "081 [8] 30 81 11 07 00 00 00 00"
    assert do_byte(b) == 0x30 and b.image.value("bus/m4/ao0") == 0  # TV-23
    assert "181 [1] 30" in frames  # the looped-back DI change still goes out while Operational
    assert b.masters.is_ok("can") is False
    # from 0xFF the same modes give 0xFE
    b2 = demo_7232d()
    b2.start()
    b2.write(0x6206, 1, 0x31, 1)
    b2.write(0x6207, 1, 0xF8, 1)
    b2.rx(0x201, "FF")
    b2.node.service("error_control").bus_state(True, b2.clock.t)
    assert do_byte(b2) == 0xFE


def test_tv22_module_failure_emcy_counter_and_clear():
    image = make_image([(1, 8, 0, 0, 0), (3, 0, 8, 0, 0), (4, 0, 0, 0, 1), (5, 0, 0, 1, 0)])
    from fieldgate.health import ErrorKind, HealthRegistry

    health = HealthRegistry()
    mods = {a: module_health(health, a) for a in (1, 3, 4, 5)}
    b = Bench(image, health=health)
    b.start()
    for _ in range(3):
        mods[5].record_failure(ErrorKind.TIMEOUT, "no answer")
    assert b.flush() == [] and b.value(0x2000, 4) == 3
    mods[5].record_failure(ErrorKind.TIMEOUT, "no answer")
    assert b.flush() == ["081 [8] 00 FF 81 0B 05 00 00 00"]
    assert b.read(0x2000, 4) == "4B 00 20 04 04 00 00 00"
    assert b.read(0x1001, 0)[:14] == "4F 01 10 00 81"
    assert b.read(0x1003, 1) == "43 03 10 01 00 FF 0B 05"
    # seed-001 TV-E04: writing 0 clears the counter and sends the error reset
    assert sorted(b.rx(0x601, "2B 00 20 04 00 00 00 00")) == [
        "081 [8] 00 00 00 00 00 00 00 00",
        "581 [8] 60 00 20 04 00 00 00 00",
    ]
    assert mods[5].error_counter == 0
    assert b.write(0x2000, 4, 7, 2) == "80 00 20 04 30 00 09 06"
    # the counter wraps at 16 bits
    mods[1].error_counter = 0xFFFF
    mods[1].record_failure(ErrorKind.CRC, "bad crc")
    assert b.value(0x2000, 1) == 0


def test_i7231d_walk_through_steps_0_to_44():
    b = demo_7231d()
    # P00: NMT start with DLC 8: "No reply. The node goes to OPERATIONAL"
    assert b.rx(0x000, "01 01 00 00 00 00 00 00") == []
    # P01
    assert b.rx(0x201, "34 12 00 00 00 00 00 00") == ["181 [3] CB ED 01"]
    # P02: AO -> AI, no TxPDO2 by itself; RTR reads it
    assert b.rx(0x301, "FF 07 00 00 00 00 00 00") == []
    assert b.rx(0x281, rtr=True) == ["281 [2] FF 07"]
    # P03: event timer 1000 ms on TxPDO2
    assert b.rx(0x601, "2B 01 18 05 E8 03 00 00") == ["581 [8] 60 01 18 05 00 00 00 00"]
    assert b.advance(1.0) == ["281 [2] FF 07"]
    assert b.advance(1.0) == ["281 [2] FF 07"]
    assert b.rx(0x601, "2B 01 18 05 00 00 00 00") == ["581 [8] 60 01 18 05 00 00 00 00"]
    assert b.advance(2.5) == []
    # P04: RxPDO1 type 0
    assert b.write(0x1400, 2, 0, 1) == ok(0x1400, 2)
    assert b.rx(0x201, "78 56 00 00 00 00 00 00") == []
    assert b.sync() == ["181 [3] 87 A9 01"]
    assert b.write(0x1400, 2, 0xFF, 1) == ok(0x1400, 2)
    # P05: TxPDO1 type 0
    assert b.write(0x1800, 2, 0, 1) == ok(0x1800, 2)
    assert b.rx(0x201, "AB 90 00 00 00 00 00 00") == []
    assert b.sync() == ["181 [3] 54 6F 01"]
    assert b.sync() == []
    # P06: type 3
    assert b.write(0x1800, 2, 3, 1) == ok(0x1800, 2)
    assert b.rx(0x201, "EF CD 00 00 00 00 00 00") == []
    assert b.sync() + b.sync() == []
    assert b.sync() == ["181 [3] 10 32 01"]
    # P07: type 252
    assert b.write(0x1800, 2, 0xFC, 1) == ok(0x1800, 2)
    assert b.rx(0x201, "34 12 00 00 00 00 00 00") == []
    assert b.rx(0x181, rtr=True) == ["181 [3] 10 32 01"]
    assert b.sync() == []
    assert b.rx(0x181, rtr=True) == ["181 [3] CB ED 01"]
    # P08: type 253
    assert b.write(0x1800, 2, 0xFD, 1) == ok(0x1800, 2)
    assert b.rx(0x201, "78 56 00 00 00 00 00 00") == []
    assert b.rx(0x181, rtr=True) == ["181 [3] 87 A9 01"]
    assert b.write(0x1800, 2, 0xFF, 1) == ok(0x1800, 2)
    # P09: dynamic TxPDO 0x1805/0x1A05 on 0x182
    assert b.rx(0x601, "23 05 18 01 82 01 00 00") == ["581 [8] 60 05 18 01 00 00 00 00"]
    assert b.read(0x1A05, 0) == "4F 05 1A 00 00 00 00 00"
    assert b.rx(0x601, "23 05 1A 01 08 01 00 60") == ["581 [8] 60 05 1A 01 00 00 00 00"]
    assert b.rx(0x601, "23 05 1A 02 08 02 00 60") == ["581 [8] 60 05 1A 02 00 00 00 00"]
    assert b.rx(0x601, "23 05 1A 03 10 01 01 64") == ["581 [8] 60 05 1A 03 00 00 00 00"]
    assert b.rx(0x601, "2F 05 1A 00 03 00 00 00") == ["581 [8] 60 05 1A 00 00 00 00 00"]
    # P10: dynamic RxPDO 0x1405/0x1605 on 0x202, and the combined exchange
    assert b.rx(0x601, "23 05 14 01 02 02 00 00") == ["581 [8] 60 05 14 01 00 00 00 00"]
    assert b.rx(0x601, "23 05 16 01 08 01 00 62") == ["581 [8] 60 05 16 01 00 00 00 00"]
    assert b.rx(0x601, "23 05 16 02 08 02 00 62") == ["581 [8] 60 05 16 02 00 00 00 00"]
    assert b.rx(0x601, "23 05 16 03 10 01 11 64") == ["581 [8] 60 05 16 03 00 00 00 00"]
    assert b.rx(0x601, "2F 05 16 00 03 00 00 00") == ["581 [8] 60 05 16 00 00 00 00 00"]
    assert b.rx(0x202, "AB 90 00 00 00 00 00 00") == ["181 [3] 54 6F 01", "182 [4] 54 6F 00 00"]
