"""CiA 401 objects bound to the process image: polarity, filter mask, error modes as the
image's ErrorMode, analog types, analog interrupts, Stopped as an error event (NA-9161)."""

from __future__ import annotations

import pytest
from io_bench import Bench, demo_7232d, make_image, wire

from fieldgate.image import DataType, ErrorMode, Kind
from fieldgate.plugins.canopen.cia401.iodevice import IoSettings


def ok(index, sub):
    return f"60 {index & 0xFF:02X} {index >> 8:02X} {sub:02X} 00 00 00 00"


def test_di_polarity_inverts_what_0x6000_and_the_tpdo_show():
    b = demo_7232d()
    b.start()
    assert b.write(0x6002, 1, 0xF0, 1) == ok(0x6002, 1)
    assert b.rx(0x201, "0F") == ["181 [1] FF"]
    assert b.read(0x6000, 1) == "4F 00 60 01 FF 00 00 00"


def test_do_filter_mask_blocks_bits():
    b = demo_7232d()
    b.start()
    assert b.value(0x6208, 1) == 0xFF
    b.write(0x6208, 1, 0x0F, 1)
    b.rx(0x201, "FF")
    assert b.value(0x6200, 1) == 0x0F
    assert b.write(0x6200, 1, 0xA5, 1) == ok(0x6200, 1)  # SDO writes are filtered too
    assert b.value(0x6200, 1) == 0x05


def test_error_mode_objects_are_the_image_error_modes():
    image = make_image([(3, 0, 8, 0, 1)])
    image["bus/m3/do2"].error_mode = ErrorMode.to(True)
    image["bus/m3/ao0"].error_mode = ErrorMode.to(-5)
    b = Bench(image)
    assert b.value(0x6206, 1) == 0x04 and b.value(0x6207, 1) == 0x04
    assert b.value(0x6443, 1) == 1 and b.value(0x6444, 1) == -5
    b.write(0x6206, 1, 0x41, 1)
    b.write(0x6207, 1, 0x21, 1)
    assert image["bus/m3/do0"].error_mode == ErrorMode(True, True)
    assert image["bus/m3/do6"].error_mode == ErrorMode(True, False)
    assert image["bus/m3/do5"].error_mode == ErrorMode(False, True)
    b.write(0x6443, 1, 0, 1)
    assert image["bus/m3/ao0"].error_mode == ErrorMode(False, -5)
    assert b.write(0x6443, 1, 2, 1) == "80 43 64 01 30 00 09 06"
    assert (
        b.write(0x6444, 1, 70000, 4) == "80 44 64 01 30 00 09 06"
    )  # outside the channel's INTEGER16


@pytest.mark.parametrize("before, after", [(0x00, 0x01), (0xFF, 0xBF), (0x5A, 0x1B)])
def test_na9161_tv16_stopped_is_an_error_event(before, after):
    image = make_image([(1, 0, 8, 0, 0)])
    b = Bench(image, IoSettings(style="na9161"))
    b.write(0x6206, 1, 0x41, 1)
    b.write(0x6207, 1, 0x21, 1)
    b.start()
    b.rx(0x201, bytes([before]))
    b.nmt(0x02)
    assert b.value(0x6200, 1) == after
    assert not b.masters.is_ok("can")
    b.start()
    assert b.masters.is_ok("can") and b.value(0x6200, 1) == after  # outputs stay until new data


def test_icpdas_stopped_is_not_an_error_event():
    b = demo_7232d()
    b.write(0x6206, 1, 0xFF, 1)
    b.start()
    b.rx(0x201, "FF")
    b.nmt(0x02)
    assert b.value(0x6200, 1) == 0xFF and b.masters.is_ok("can")


def test_heartbeat_consumer_loss_applies_error_values():
    b = demo_7232d()
    b.write(0x6206, 1, 0xFF, 1)
    b.write(0x6443, 1, 1, 1)
    b.write(0x6444, 1, 0x123, 4)
    b.write(0x1016, 1, (0x7F << 16) | 100, 4)
    b.start()
    b.rx(0x201, "AA")
    b.rx(0x77F, "05")
    b.advance(0.05)
    b.rx(0x77F, "05")
    frames = b.advance(0.2)
    assert any(f.startswith("081 [8] 30 81") for f in frames), frames
    assert b.value(0x6200, 1) == 0 and b.image.value("bus/m4/ao0") == 0x123


def test_uint16_and_float_analog_channels():
    image = make_image(
        [(1, 0, 0, 1, 1)], dtypes={(1, Kind.AI): DataType.UINT16, (1, Kind.AO): DataType.UINT16}
    )
    b = Bench(image)
    b.start()
    image.update_input("bus/m1/ai0", 0xFFF0)
    assert b.read(0x6401, 1) == "4B 01 64 01 F0 FF 00 00"
    assert b.rx(0x301, "FE FF") == []
    assert image.value("bus/m1/ao0") == 0xFFFE
    assert b.value(0x6411, 1) == -2


def test_analog_interrupts_fire_tpdos_only_when_enabled():
    image = make_image([(1, 0, 0, 2, 0), (2, 0, 0, 0, 2)])
    wire(image, 2, 1, Kind.AO)
    b = Bench(image)
    b.start()
    assert b.rx(0x301, "10 00 00 00") == []  # default: analog changes fire nothing
    b.write(0x6423, 0, 1, 1)
    assert b.rx(0x301, "20 00 00 00") == ["281 [4] 20 00 00 00"]
    b.write(0x6421, 1, 0x04, 1)  # delta only
    b.write(0x6426, 1, 0x10, 4)
    assert b.rx(0x301, "28 00 00 00") == []  # |0x28 - 0x20| <= 0x10
    assert b.rx(0x301, "31 00 00 00") == ["281 [4] 31 00 00 00"]
    b.write(0x6421, 2, 0x01, 1)  # channel 2: upper limit only
    b.write(0x6424, 2, 100, 4)
    assert b.rx(0x301, "31 00 64 00") == []
    assert b.rx(0x301, "31 00 65 00") == ["281 [4] 31 00 65 00"]
    assert b.read(0x6422, 1) == "43 22 64 01 03 00 00 00"  # both channels interrupted
    assert b.read(0x6422, 1) == "43 22 64 01 00 00 00 00"  # cleared by reading
    b.write(0x6423, 0, 0, 1)
    assert b.rx(0x301, "00 10 00 10") == []


def test_bus_off_applies_error_values_and_recovery_reports_the_master_back():
    b = demo_7232d()
    b.write(0x6206, 1, 0x31, 1)
    b.write(0x6207, 1, 0xF8, 1)
    b.start()
    b.rx(0x201, "FF")
    b.node.service("error_control").bus_state(True, b.clock.t)
    assert b.value(0x6200, 1) == 0xFE and not b.masters.is_ok("can")
    b.node.service("error_control").bus_state(False, b.clock.t)
    assert b.masters.is_ok("can") and b.value(0x6200, 1) == 0xFE


def test_float_analog_input_is_rounded_clamped_and_never_breaks_a_tpdo():
    image = make_image([(1, 0, 0, 2, 0)], dtypes={(1, Kind.AI): DataType.FLOAT32})
    b = Bench(image)
    b.start()
    image.update_input("bus/m1/ai0", 12.6)
    image.update_input("bus/m1/ai1", 1e9)
    assert b.rx(0x281, rtr=True) == ["281 [4] 0D 00 FF 7F"]
    image.update_input("bus/m1/ai0", float("nan"))
    assert b.rx(0x281, rtr=True) == ["281 [4] 00 00 FF 7F"]


def test_pdo_frames_that_cannot_be_served_are_counted():
    b = demo_7232d()
    b.start()
    engine = b.io.engine
    assert b.rx(0x181, "01 02") == []  # data on our own TPDO1's COB-ID: another node's frame
    assert b.rx(0x201, rtr=True) == []  # a remote request for an RPDO
    assert engine.counters.frames_ignored == 2 and b.io.status()["frames_ignored"] == 2
