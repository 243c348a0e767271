"""RPDOs reach the process image as batches: one per RPDO, one per SYNC for synchronous ones.

The demo bench of seed-000 (io_bench.demo_7232d): RPDO1 0x6200:1 -> the 8 DO of address 3
(looped back to the 8 DI of address 1, TPDO1), RPDO2 0x6411:1 -> AO0 of address 4.
"""

from __future__ import annotations

from io_bench import Bench, Kind, demo_7232d, make_image, wire

from fieldgate.image import DataType

DO = [f"bus/m3/do{i}" for i in range(8)]


def ok(index, sub):
    return f"60 {index & 0xFF:02X} {index >> 8:02X} {sub:02X} 00 00 00 00"


def batches_of(bench, kinds=(Kind.DO, Kind.AO)):
    batches = []
    bench.image.subscribe_batch(
        lambda changes: batches.append([(c.id, c.value, c.origin) for c in changes]), kinds=kinds
    )
    return batches


def test_an_rpdo_is_one_batch_and_its_looped_back_inputs_one_tpdo():
    b = demo_7232d()
    b.start()
    batches = batches_of(b)
    assert b.rx(0x201, "A5") == ["181 [1] A5"]
    assert batches == [[(DO[i], True, "can") for i in (0, 2, 5, 7)]]
    assert b.rx(0x201, "A5") == [] and len(batches) == 1  # nothing changed: no batch, no TPDO
    assert b.rx(0x201, "A4") == ["181 [1] A4"]
    assert batches[1] == [(DO[0], False, "can")]


def test_the_synchronous_rpdos_of_one_sync_are_one_batch():
    b = demo_7232d()
    b.start()
    assert b.write(0x1400, 2, 1, 1) == ok(0x1400, 2)
    assert b.write(0x1401, 2, 1, 1) == ok(0x1401, 2)
    batches = batches_of(b)
    assert b.rx(0x201, "0F") == [] and b.rx(0x301, "3412") == [] and batches == []
    assert b.rx(0x201, "03") == []  # the latest data of RPDO1 counts
    assert b.sync() == ["181 [1] 03"]
    assert batches == [[(DO[0], True, "can"), (DO[1], True, "can"), ("bus/m4/ao0", 0x1234, "can")]]
    assert b.sync() == [] and len(batches) == 1  # nothing latched: nothing written


def test_an_sdo_write_of_an_output_byte_is_one_batch():
    b = demo_7232d()
    b.start()
    batches = batches_of(b)
    frames = b.rx(0x601, "2F 00 62 01 0F 00 00 00")  # 0x6200:1 = 0x0F
    assert frames == ["581 [8] 60 00 62 01 00 00 00 00", "181 [1] 0F"]  # one TPDO
    assert batches == [[(DO[i], True, "can") for i in range(4)]]


def test_an_entry_that_refuses_its_value_leaves_the_rest_of_the_rpdo_in_one_batch():
    """RPDO1 remapped to the DO byte and an AO that takes no negative values (UINT32)."""
    image = make_image(
        [(1, 8, 0, 0, 0), (3, 0, 8, 0, 0), (4, 0, 0, 0, 1)], dtypes={(4, Kind.AO): DataType.UINT32}
    )
    wire(image, 3, 1)
    b = Bench(image)
    b.start()
    assert b.write(0x1600, 0, 0, 1) == ok(0x1600, 0)
    assert b.write(0x1600, 2, 0x64110110, 4) == ok(0x1600, 2)
    assert b.write(0x1600, 0, 2, 1) == ok(0x1600, 0)
    batches = batches_of(b)
    assert b.rx(0x201, "01 FF FF") == ["181 [1] 01"]  # AO -1 refused, DO0 written
    assert batches == [[(DO[0], True, "can")]]
    assert b.io.status()["rpdo_write_refused"] == 1
    assert b.rx(0x201, "03 10 00") == ["181 [1] 03"]
    assert batches[1] == [(DO[1], True, "can"), ("bus/m4/ao0", 16, "can")]


def test_master_lost_drives_the_error_values_in_one_batch():
    b = demo_7232d()
    b.start()
    assert b.write(0x6206, 1, 0xFF, 1) == ok(0x6206, 1)  # every DO: go to its error value
    assert b.write(0x6207, 1, 0x30, 1) == ok(0x6207, 1)  # DO4, DO5 on; the others off
    b.rx(0x201, "0F")
    batches = batches_of(b, kinds=(Kind.DO,))
    b.masters.lost("can", "heartbeat", DO)
    assert batches == [[(DO[i], i in (4, 5), "can:master-lost") for i in range(6)]]


def test_rpdos_latched_for_a_sync_apply_in_rpdo_order_and_an_nmt_change_drops_them():
    """Two synchronous RPDOs mapping the same DO byte: at the SYNC they are applied in RPDO
    order whatever order they came in (RPDO2's data is the last word), as one batch."""
    b = demo_7232d()
    b.start()
    for index, sub, value, size in (
        (0x1601, 0, 0, 1),
        (0x1601, 1, 0x62000108, 4),
        (0x1601, 0, 1, 1),
        (0x1400, 2, 1, 1),
        (0x1401, 2, 1, 1),
    ):
        assert b.write(index, sub, value, size) == ok(index, sub)
    batches = batches_of(b)
    assert b.rx(0x301, "AA") == [] and b.rx(0x201, "55") == []
    assert b.sync() == ["181 [1] AA"]
    assert len(batches) == 1
    assert b.rx(0x201, "0F") == []
    b.nmt(0x02)  # Stopped, then Operational again: what was latched is gone
    b.start()
    assert b.sync() == [] and len(batches) == 1
    assert b.image.value(DO[0]) is False and b.image.value(DO[1]) is True  # still 0xAA


def test_an_input_event_from_outside_is_due_on_the_engines_clock_not_the_images():
    """The adapter runs the node on the event loop's time, which lags the image's monotonic
    clock (uvloop: up to a millisecond); a back's event must still go out at the next
    engine call, not wait until the loop's time catches up with the image's."""
    image = make_image([(1, 8, 0, 0, 0), (3, 0, 8, 0, 0)])
    b = Bench(image)
    b.start()
    b.clock.t = 10.0  # the node's time of its last call, and of the next one
    b.flush()
    image.clock = lambda: 10.0008  # the image's clock, ahead of the loop's
    image.update_inputs({"bus/m1/di0": True, "bus/m1/di1": True})
    assert b.node.next_deadline() <= 10.0
    assert b.flush() == ["181 [1] 03"]
