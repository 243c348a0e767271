"""The event hub and the event stream's bounds (unit tests: no server, no clock)."""

from __future__ import annotations

import asyncio

from fieldgate.events import EMCY_SENT, MODULE_OFFLINE, EventHub
from fieldgate.http.sse import SseClient


def test_the_hub_keeps_a_bounded_history_and_counts_by_kind():
    hub = EventHub(history=3, wall=lambda: 100.0)
    for i in range(5):
        hub.publish(EMCY_SENT, "can", f"emcy {i}", code="FF00")
    recent = hub.recent()
    assert [e.seq for e in recent] == [3, 4, 5] and hub.counts[EMCY_SENT] == 5
    assert recent[-1].as_dict() == {
        "seq": 5,
        "time": 100.0,
        "kind": EMCY_SENT,
        "level": "info",
        "source": "can",
        "text": "emcy 4",
        "data": {"code": "FF00"},
    }
    assert hub.publish(MODULE_OFFLINE, "rs485/m3", "x").level == "warning"


def test_a_failing_listener_never_stops_the_publisher_and_unsubscribe_works():
    hub = EventHub()
    seen = []

    def bad(event):
        raise RuntimeError("listener bug")

    hub.subscribe(bad)
    cancel = hub.subscribe(seen.append)
    hub.publish("x", "a", "one")
    cancel()
    cancel()  # twice is harmless
    hub.publish("x", "a", "two")
    assert [e.text for e in seen] == ["one"]


def test_a_client_that_does_not_read_keeps_bounded_state():
    async def run():
        hub = EventHub()
        client = SseClient(None, rate_hz=4.0, queue_size=10)
        hub.subscribe(client.push)
        for i in range(1000):
            hub.publish("x", "a", str(i))
            client.mark(f"io/m1/di{i % 16}")
        return client

    client = asyncio.run(run())
    assert len(client.events) == 10 and client.dropped == 990
    assert len(client.dirty) == 16  # each changed point once, however often it changed
    assert list(client.dirty)[:2] == ["io/m1/di0", "io/m1/di1"]


def test_a_filtered_client_ignores_other_points():
    async def run():
        client = SseClient(frozenset({"a"}), rate_hz=1.0, queue_size=1)
        client.mark("b")
        assert not client.wake.is_set()
        client.mark("a")
        return client

    client = asyncio.run(run())
    assert list(client.dirty) == ["a"] and client.wake.is_set()


def test_a_batch_marks_each_changed_point_of_each_client():
    """One poll reply (an image batch) marks every changed point once, per client; the
    point that kept its value is not sent."""
    from types import SimpleNamespace

    from fieldgate.http.sse import EventStreams
    from fieldgate.image import ChannelSpec, Kind, ProcessImage, Source

    async def run():
        image = ProcessImage(clock=lambda: 1.0)
        for i in range(3):
            image.add(ChannelSpec(f"io/m1/di{i}", Kind.DI, Source("io", 1, i)))
        image.update_inputs({"io/m1/di2": True})
        gateway = SimpleNamespace(image=image, context=SimpleNamespace(events=EventHub()))
        streams = EventStreams(gateway, max_clients=4, rate_hz=4.0)  # type: ignore[arg-type]
        every, only_di1 = SseClient(None, 4.0, 10), SseClient(frozenset({"io/m1/di1"}), 4.0, 10)
        streams._add(every)
        streams._add(only_di1)
        image.update_inputs({"io/m1/di0": True, "io/m1/di1": True, "io/m1/di2": True})
        return every, only_di1

    every, only_di1 = asyncio.run(run())
    assert list(every.dirty) == ["io/m1/di0", "io/m1/di1"]
    assert list(only_di1.dirty) == ["io/m1/di1"]
