"""Batched process-image writes: one call for a whole message, subscribers told once per batch."""

import pytest

from fieldgate import ChannelSpec, ErrorMode, Kind, ProcessImage, Quality, Source, channel_id


class FakeClock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


def make_image(clock=None):
    image = ProcessImage(clock or FakeClock())
    for kind, n in ((Kind.DI, 8), (Kind.DO, 8), (Kind.AI, 2), (Kind.AO, 2)):
        for i in range(n):
            image.add(ChannelSpec(channel_id("rs485", 3, kind, i), kind, Source("rs485", 3, i)))
    return image


def di(i):
    return f"rs485/m3/di{i}"


def do(i):
    return f"rs485/m3/do{i}"


def test_a_batch_subscriber_sees_each_changed_channel_with_its_own_value_and_time():
    clock = FakeClock(5.0)
    image = make_image(clock)
    image.update_inputs({di(0): True, di(1): False}, timestamp=1.0)  # di1 unchanged from False
    batches = []
    image.subscribe_batch(batches.append)
    changes = image.update_inputs({di(0): False, di(1): True, di(2): True}, timestamp=2.5)
    assert len(batches) == 1
    assert [(c.id, c.old_value, c.value, c.quality, c.timestamp) for c in batches[0]] == [
        (di(0), True, False, Quality.GOOD, 2.5),
        (di(1), False, True, Quality.GOOD, 2.5),
        (di(2), False, True, Quality.GOOD, 2.5),
    ]
    assert [c.id for c in changes] == [di(0), di(1), di(2)]
    assert all(c.origin == "back" for c in changes)
    # each change keeps its own value and time when the channel moves on
    clock.t = 7.0
    image.update_input(di(0), True)
    assert (batches[0][0].value, batches[0][0].timestamp) == (False, 2.5)
    assert (batches[1][0].value, batches[1][0].timestamp) == (True, 7.0)


def test_unchanged_channels_notify_nothing_but_good_values_refresh_their_time():
    clock = FakeClock(1.0)
    image = make_image(clock)
    image.update_inputs({di(0): True, di(1): True, image["rs485/m3/ai0"].id: 10})
    batches, singles = [], []
    image.subscribe_batch(batches.append)
    image.subscribe(singles.append)
    clock.t = 2.0
    assert image.update_inputs({di(0): True, di(1): True, "rs485/m3/ai0": 10}) == []
    assert batches == [] and singles == []  # no call at all for a batch without a change
    assert image[di(0)].timestamp == 2.0 and image["rs485/m3/ai0"].timestamp == 2.0
    image.update_inputs({di(0): True, di(1): False, "rs485/m3/ai0": 10})
    assert [[c.id for c in b] for b in batches] == [[di(1)]]
    assert [c.id for c in singles] == [di(1)]


def test_per_change_subscribers_get_one_call_per_change_after_the_whole_batch_is_written():
    image = make_image()
    seen = []

    def record(change):
        # the whole batch is in the image when the first change is delivered
        seen.append((change.id, change.value, image.value(do(7))))

    image.subscribe(record, kinds=[Kind.DO])
    image.write_outputs({do(0): True, do(3): True, do(7): True}, origin="can")
    assert seen == [(do(0), True, True), (do(3), True, True), (do(7), True, True)]


def test_batch_quality_per_channel_quality_and_timestamp_rules():
    clock = FakeClock(10.0)
    image = make_image(clock)
    image.update_inputs({"rs485/m3/ai0": 100, "rs485/m3/ai1": 200}, timestamp=9.0)
    clock.t = 11.0
    changes = image.update_inputs(
        {"rs485/m3/ai0": (0x7FFF, Quality.OVER_RANGE), "rs485/m3/ai1": 201}, timestamp=10.5
    )
    ai0, ai1 = image["rs485/m3/ai0"], image["rs485/m3/ai1"]
    assert (ai0.value, ai0.quality, ai0.timestamp, ai0.last_good) == (
        0x7FFF,
        Quality.OVER_RANGE,
        9.0,  # a value of bad quality is no good update
        100,
    )
    assert (ai1.value, ai1.quality, ai1.timestamp, ai1.last_good) == (201, Quality.GOOD, 10.5, 201)
    assert [(c.quality, c.old_quality) for c in changes] == [
        (Quality.OVER_RANGE, Quality.GOOD),
        (Quality.GOOD, Quality.GOOD),
    ]
    # one quality for the whole batch; a quality change of an unchanged value is a change
    batches = []
    image.subscribe_batch(batches.append)
    stale = image.update_inputs({"rs485/m3/ai1": 201}, Quality.STALE, timestamp=12.0)
    assert [(c.id, c.value, c.quality, c.timestamp) for c in stale] == [
        ("rs485/m3/ai1", 201, Quality.STALE, 10.5)
    ]
    assert len(batches) == 1
    assert image.set_quality(["rs485/m3/ai0", "rs485/m3/ai1"], Quality.COMM_FAULT)
    assert len(batches) == 2 and [c.old_quality for c in batches[1]] == [
        Quality.OVER_RANGE,
        Quality.STALE,
    ]
    assert ai1.timestamp == 10.5  # set_quality keeps the last good time


def test_the_default_timestamp_is_the_image_clock_once_per_batch():
    clock = FakeClock(3.0)
    image = make_image(clock)
    image.update_inputs({di(0): True, di(1): True})
    assert image[di(0)].timestamp == image[di(1)].timestamp == 3.0
    clock.t = 4.0
    image.write_outputs({do(0): True})
    assert image[do(0)].timestamp == 4.0  # a good output is stamped when written


def test_a_wrong_entry_refuses_the_whole_batch_before_anything_is_written():
    image = make_image()
    seen = []
    image.subscribe_batch(seen.append)
    with pytest.raises(ValueError, match="ai0"):
        image.update_inputs({di(0): True, "rs485/m3/ai0": 70000})
    with pytest.raises(KeyError, match="no channel"):
        image.update_inputs({di(0): True, "rs485/m9/di0": True})
    with pytest.raises(ValueError, match="output"):
        image.update_inputs({di(0): True, do(0): True})
    with pytest.raises(ValueError, match="input"):
        image.write_outputs({do(0): True, di(0): True})
    with pytest.raises(ValueError, match="ao1"):
        image.write_outputs({do(1): True, "rs485/m3/ao1": 1.5})
    assert image.value(di(0)) is False and image.value(do(0)) is False
    assert image.value(do(1)) is False and image[di(0)].quality is Quality.NOT_READ
    assert image[do(0)].written_by == ""
    assert seen == []


def test_write_outputs_keeps_quality_records_the_writer_and_returns_only_changes():
    image = make_image()
    image.set_quality([do(0), do(1)], Quality.COMM_FAULT)
    changes = image.write_outputs({do(0): True, do(1): False, "rs485/m3/ao0": -5}, origin="can")
    assert [(c.id, c.value, c.quality, c.origin) for c in changes] == [
        (do(0), True, Quality.COMM_FAULT, "can"),
        ("rs485/m3/ao0", -5, Quality.GOOD, "can"),
    ]
    assert image[do(1)].written_by == "can"  # written, though its value did not change
    assert image.write_output(do(0), True) is False and image.write_output(do(0), False) is True


def test_error_modes_are_one_batch():
    image = make_image()
    for i in range(8):
        image.set_error_mode(do(i), ErrorMode(i % 2 == 0, True))
    image.set_error_mode("rs485/m3/ao0", ErrorMode.to(-7))
    image.write_outputs({do(2): True})  # already at its error value: no change
    batches = []
    image.subscribe_batch(batches.append, kinds=[Kind.DO, Kind.AO])
    changed = image.apply_error_modes(origin="can:master-lost")
    assert changed == [do(0), do(4), do(6), "rs485/m3/ao0"]
    assert len(batches) == 1 and [c.id for c in batches[0]] == changed
    assert {c.origin for c in batches[0]} == {"can:master-lost"}
    assert image[do(0)].written_by == "can:master-lost"
    assert image.apply_error_modes(origin="again") == [] and len(batches) == 1


def test_a_failing_subscriber_does_not_stop_the_batch_or_the_others():
    image = make_image()
    seen_batches, seen_singles, calls = [], [], []

    def boom_batch(changes):
        calls.append("batch")
        raise RuntimeError("bad batch subscriber")

    def boom_first(change):
        calls.append(change.id)
        if change.id == do(0):
            raise RuntimeError("bad subscriber")
        seen_singles.append(change.id)

    image.subscribe_batch(boom_batch)
    image.subscribe(boom_first)
    image.subscribe_batch(seen_batches.append)
    changes = image.write_outputs({do(0): True, do(1): True, do(2): True})
    assert len(changes) == 3
    assert [image.value(do(i)) for i in range(3)] == [True, True, True]
    assert calls == ["batch", do(0), do(1), do(2)]
    assert seen_singles == [do(1), do(2)]  # the change after the one that raised is delivered
    assert [[c.id for c in b] for b in seen_batches] == [[do(0), do(1), do(2)]]


def test_subscribers_get_only_what_they_asked_for_in_subscription_order():
    image = make_image()
    order = []
    image.subscribe_batch(lambda cs: order.append(("outputs", [c.id for c in cs])), kinds=[Kind.DO])
    image.subscribe_batch(lambda cs: order.append(("di1", [c.id for c in cs])), ids=[di(1)])
    image.subscribe_batch(lambda cs: order.append(("all", [c.id for c in cs])))
    image.update_inputs({di(0): True, di(1): True})
    assert order == [("di1", [di(1)]), ("all", [di(0), di(1)])]
    order.clear()
    image.write_outputs({do(5): True})
    assert order == [("outputs", [do(5)]), ("all", [do(5)])]
    order.clear()  # channels wanted by different subscribers, interleaved: write order kept
    image.update_inputs({di(2): True, "rs485/m3/ai0": 5, di(1): False, "rs485/m3/ai1": 6})
    assert order == [
        ("di1", [di(1)]),
        ("all", [di(2), "rs485/m3/ai0", di(1), "rs485/m3/ai1"]),
    ]


def test_a_batch_written_by_a_subscriber_is_delivered_before_the_next_subscriber():
    """The loopback wiring: outputs echoed to inputs from inside the output batch."""
    image = make_image()
    order = []

    def echo(changes):
        order.append("echo")
        image.update_inputs({c.id.replace("do", "di"): c.value for c in changes})

    image.subscribe_batch(echo, kinds=[Kind.DO])
    image.subscribe_batch(lambda cs: order.append(("di", [c.id for c in cs])), kinds=[Kind.DI])
    image.subscribe_batch(lambda cs: order.append(("do", [c.id for c in cs])), kinds=[Kind.DO])
    image.write_outputs({do(0): True, do(1): True})
    assert order == ["echo", ("di", [di(0), di(1)]), ("do", [do(0), do(1)])]
    assert image.value(di(1)) is True


def test_subscriptions_made_or_cancelled_around_a_batch_take_effect_at_once():
    image = make_image()
    first, second = [], []
    sub_second = None

    def cancel_second(changes):
        first.append(changes)
        sub_second.cancel()

    image.subscribe_batch(cancel_second)
    sub_second = image.subscribe_batch(second.append)
    image.update_inputs({di(0): True})
    assert len(first) == 1 and second == []  # cancelled by the subscriber before it
    late = []
    image.subscribe_batch(late.append, ids=[di(0)])
    image.update_inputs({di(0): False, di(1): True})
    assert [[c.id for c in b] for b in late] == [[di(0)]]


async def test_a_queue_gets_each_change_of_a_batch():
    image = make_image()
    q, sub = image.queue(kinds=[Kind.DI], maxsize=2)
    image.update_inputs({di(0): True, di(1): True, di(2): True})  # di2 dropped: queue full
    assert [q.get_nowait().id, q.get_nowait().id] == [di(0), di(1)]
    assert q.empty()
    sub.cancel()
