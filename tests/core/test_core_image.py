"""Process image: values, quality transitions, subscriptions, error modes."""

import asyncio

import pytest

from fieldgate import (
    ChannelSpec,
    DataType,
    ErrorMode,
    Kind,
    ProcessImage,
    Quality,
    Source,
    channel_id,
)


class FakeClock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


def make_image(clock=None):
    image = ProcessImage(clock or FakeClock())
    for kind, n in ((Kind.DI, 2), (Kind.DO, 8), (Kind.AI, 1), (Kind.AO, 2)):
        for i in range(n):
            image.add(ChannelSpec(channel_id("rs485", 3, kind, i), kind, Source("rs485", 3, i)))
    return image


def test_channel_id_format():
    assert channel_id("rs485", 3, Kind.DO, 0) == "rs485/m3/do0"


def test_inputs_start_not_read_outputs_start_good():
    image = make_image()
    assert image["rs485/m3/di0"].quality is Quality.NOT_READ
    assert image["rs485/m3/di0"].timestamp is None
    assert image["rs485/m3/do0"].quality is Quality.GOOD
    assert image.value("rs485/m3/ai0") == 0 and image.value("rs485/m3/do0") is False


def test_quality_transitions_and_timestamps():
    clock = FakeClock(10.0)
    image = make_image(clock)
    assert image.update_input("rs485/m3/ai0", 1234) is True
    ch = image["rs485/m3/ai0"]
    assert (ch.value, ch.quality, ch.timestamp) == (1234, Quality.GOOD, 10.0)
    clock.t = 11.0
    image.set_quality(["rs485/m3/ai0"], Quality.STALE)
    assert (ch.value, ch.quality, ch.timestamp) == (
        1234,
        Quality.STALE,
        10.0,
    )  # last good time kept
    image.set_quality(["rs485/m3/ai0"], Quality.COMM_FAULT)
    assert ch.quality is Quality.COMM_FAULT
    clock.t = 12.0
    image.update_input("rs485/m3/ai0", 1234)
    assert (ch.quality, ch.timestamp) == (Quality.GOOD, 12.0)
    image.update_input("rs485/m3/ai0", 0x7FFF, Quality.OVER_RANGE)
    assert ch.quality is Quality.OVER_RANGE and ch.timestamp == 12.0


def test_same_value_refreshes_timestamp_without_notifying():
    clock = FakeClock(1.0)
    image = make_image(clock)
    seen = []
    image.subscribe(seen.append)
    image.update_input("rs485/m3/di0", True)
    clock.t = 2.0
    assert image.update_input("rs485/m3/di0", True) is False
    assert len(seen) == 1 and image["rs485/m3/di0"].timestamp == 2.0


def test_direction_is_enforced():
    image = make_image()
    with pytest.raises(ValueError, match="output"):
        image.update_input("rs485/m3/do0", True)
    with pytest.raises(ValueError, match="input"):
        image.write_output("rs485/m3/di0", True)
    with pytest.raises(KeyError, match="no channel"):
        image.value("rs485/m9/di0")


@pytest.mark.parametrize(
    "dtype,good,bad",
    [
        (DataType.INT16, [-32768, 32767], [32768, -32769, 1.5, "1"]),
        (DataType.UINT16, [0, 65535], [-1, 65536]),
        (DataType.BOOL, [True, 0, 1], [2, "on"]),
        (DataType.UINT32, [0xFFFFFFFF], [-1]),
    ],
)
def test_values_are_range_checked(dtype, good, bad):
    for v in good:
        dtype.check(v)
    for v in bad:
        with pytest.raises(ValueError):
            dtype.check(v)


def test_subscriptions_filter_by_kind_and_id_and_cancel():
    image = make_image()
    outputs, one = [], []
    sub = image.subscribe(outputs.append, kinds=[Kind.DO, Kind.AO])
    image.subscribe(one.append, ids=["rs485/m3/di1"])
    image.write_output("rs485/m3/do2", True, origin="can")
    image.update_input("rs485/m3/di1", True)
    image.update_input("rs485/m3/di0", True)
    assert [c.channel.id for c in outputs] == ["rs485/m3/do2"]
    assert outputs[0].origin == "can" and outputs[0].old_value is False and outputs[0].value_changed
    assert [c.channel.id for c in one] == ["rs485/m3/di1"]
    sub.cancel()
    image.write_output("rs485/m3/do3", True)
    assert len(outputs) == 1


def test_failing_subscriber_does_not_break_writer_or_others():
    image = make_image()
    seen = []

    def boom(change):
        raise RuntimeError("bad subscriber")

    image.subscribe(boom)
    image.subscribe(seen.append)
    assert image.write_output("rs485/m3/do0", True) is True
    assert image.value("rs485/m3/do0") is True and len(seen) == 1


async def test_queue_subscription_delivers_on_the_loop_and_drops_when_full():
    image = make_image()
    q, sub = image.queue(kinds=[Kind.DI], maxsize=1)
    image.update_input("rs485/m3/di0", True)
    image.update_input("rs485/m3/di1", True)  # dropped: queue full
    change = await asyncio.wait_for(q.get(), 1)
    assert change.channel.id == "rs485/m3/di0"
    assert q.empty()
    sub.cancel()


def test_error_modes_hold_and_value_tv23():
    """TV-23: mode bits 0x31 with value bits 0xF8 turn DO byte 0x00 into 0x30 and 0xFF into 0xFE."""
    image = make_image()
    dos = [f"rs485/m3/do{i}" for i in range(8)]
    mode, value = 0x31, 0xF8
    for bit, cid in enumerate(dos):
        use = bool(mode >> bit & 1)
        image.set_error_mode(cid, ErrorMode(use, bool(value >> bit & 1)))
    for start, expected in ((0x00, 0x30), (0xFF, 0xFE)):
        for bit, cid in enumerate(dos):
            image.write_output(cid, bool(start >> bit & 1))
        image.apply_error_modes(dos)
        assert sum(1 << b for b, cid in enumerate(dos) if image.value(cid)) == expected


def test_error_mode_value_is_kept_while_holding_and_checked():
    image = make_image()
    image.set_error_mode("rs485/m3/ao0", ErrorMode.hold(-5))
    image.write_output("rs485/m3/ao0", 100)
    assert image.apply_error_modes() == []
    assert image.value("rs485/m3/ao0") == 100
    assert image["rs485/m3/ao0"].error_mode.value == -5
    image.set_error_mode("rs485/m3/ao0", ErrorMode.to(-5))
    assert image.apply_error_modes() == ["rs485/m3/ao0"]
    assert image.value("rs485/m3/ao0") == -5 and image["rs485/m3/ao0"].written_by == "error-mode"
    with pytest.raises(ValueError):
        image.set_error_mode("rs485/m3/ao1", ErrorMode.to(70000))
    with pytest.raises(ValueError, match="outputs"):
        image.set_error_mode("rs485/m3/di0", ErrorMode.to(True))


def test_shutdown_modes_only_touch_configured_outputs():
    image = ProcessImage()
    image.add(ChannelSpec("b/m1/do0", Kind.DO, Source("b", 1, 0), shutdown_mode=ErrorMode.to(True)))
    image.add(ChannelSpec("b/m1/do1", Kind.DO, Source("b", 1, 1)))
    image.add(
        ChannelSpec(
            "b/m1/ao0", Kind.AO, Source("b", 1, 0), initial=7, shutdown_mode=ErrorMode.hold()
        )
    )
    assert image.value("b/m1/ao0") == 7
    assert image.apply_shutdown_modes() == ["b/m1/do0"]
    assert image.value("b/m1/do1") is False and image.value("b/m1/ao0") == 7


def test_match_globs_in_natural_order_and_duplicate_ids_rejected():
    image = ProcessImage()
    for m in (10, 9, 1):
        image.add(ChannelSpec(f"b/m{m}/di0", Kind.DI, Source("b", m, 0)))
    assert [c.id for c in image.match(["b/m*/di0"])] == ["b/m1/di0", "b/m9/di0", "b/m10/di0"]
    assert [c.id for c in image.match(["b/m9/*", "b/m*"])] == ["b/m9/di0", "b/m1/di0", "b/m10/di0"]
    with pytest.raises(ValueError, match="duplicate"):
        image.add(ChannelSpec("b/m1/di0", Kind.DI, Source("b", 1, 0)))
