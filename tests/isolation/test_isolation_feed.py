"""The mirror's data path without processes: the feed encodes each change once, a slow child's
outbox is bounded and resyncs, and a MirrorContext rebuilt from the frames equals the source."""

from __future__ import annotations

import pytest

from fieldgate import Gateway, Quality
from fieldgate.health import ErrorKind, HealthEvent
from fieldgate.isolation import wire
from fieldgate.isolation.feed import GatewayFeed, Outbox
from fieldgate.isolation.mirror import MirrorContext

from .test_isolation_children import topology


def decode(frames: list[bytes]) -> list[tuple]:
    reader = wire.FrameReader(wire.MAX_DOWN)
    return [wire.read_down(body) for body in reader.feed(b"".join(frames))]


@pytest.fixture
def gateway(registry) -> Gateway:
    topo = topology()
    topo["fronts"] = [{"name": "plc", "type": "memory"}]  # no child: the feed alone
    return Gateway.load(topo, registry=registry)


def test_a_snapshot_then_changes_rebuild_the_same_image_health_masters_and_events(gateway):
    ctx = gateway.context
    from fieldgate.health import ModuleHealth

    module = ctx.health.add(ModuleHealth("lb", 1, model="loop"))
    feed = GatewayFeed(ctx)
    outbox = Outbox(1 << 20)
    feed.attach(outbox, lambda: None)
    ups: list[dict] = []
    mirror = MirrorContext(ctx.topology, ups.append, {"lb/m1/ai0": ["here"]})
    for message in decode(outbox.take(feed.snapshot, 1 << 20)):
        mirror.apply(message)
    assert mirror.snapshots == 1

    heard: list[tuple[str, HealthEvent]] = []
    mirror.health.subscribe(lambda m, e: heard.append((f"{m.back}/{m.address}", e)))
    batches: list[list[str]] = []
    mirror.image.subscribe_batch(lambda changes: batches.append([c.id for c in changes]))
    ctx.image.update_inputs({"lb/m1/ai0": 42, "lb/m1/di1": True})
    ctx.image.write_outputs({"lb/m1/ao1": 7}, origin="plc")
    for _ in range(4):
        module.record_failure(ErrorKind.TIMEOUT, "no answer")
    ctx.masters.lost("plc", "heartbeat")
    ctx.events.publish("nmt-state", "plc", "operational")
    for message in decode(outbox.take(feed.snapshot, 1 << 20)):
        mirror.apply(message)

    for cid in ("lb/m1/ai0", "lb/m1/di1", "lb/m1/ao1", "lb/m1/ao0"):
        src, dst = ctx.image[cid], mirror.image[cid]
        assert (dst.value, dst.quality, dst.timestamp) == (src.value, src.quality, src.timestamp)
    assert mirror.image["lb/m1/ao1"].written_by == "plc"
    assert batches[0] == ["lb/m1/ai0", "lb/m1/di1"]  # one batch as in the source
    copy = mirror.health.get("lb", 1)
    assert (copy.online, copy.consecutive_failures, copy.last_error) == (False, 4, "no answer")
    assert ("lb/1", HealthEvent.OFFLINE) in heard
    assert mirror.masters.is_ok("plc") is False
    assert [e.text for e in mirror.events.recent()][-1] == "operational"
    assert mirror.point_locations() == {"lb/m1/ai0": ["here"]}


def test_a_child_that_does_not_read_costs_a_bounded_queue_and_then_one_snapshot(gateway):
    ctx = gateway.context
    feed = GatewayFeed(ctx)
    outbox = Outbox(4096)
    feed.attach(outbox, lambda: None)
    outbox.take(feed.snapshot, 1 << 20)  # the first snapshot went out
    for i in range(2000):  # the child reads nothing meanwhile
        ctx.image.update_inputs({"lb/m1/ai0": i % 30000})
        assert outbox.size <= 4096
    assert outbox.resyncs >= 1 and outbox.resync
    ctx.image.update_inputs({"lb/m1/ai0": 12345})
    messages = decode(outbox.take(feed.snapshot, 1 << 20))
    assert messages[0][0] == "snap"  # first a fresh snapshot, with the latest value
    state = {c[0]: c for c in messages[0][1]}
    assert state["lb/m1/ai0"][1] == 12345 and state["lb/m1/ai0"][2] == Quality.GOOD.value


def test_control_frames_are_never_dropped_and_come_first(gateway):
    outbox = Outbox(100)
    outbox.resync = False
    outbox.put(b"x" * 80)
    outbox.put(b"y" * 80)  # over the budget: the data goes, a snapshot is due
    outbox.put_control(b"ping")
    assert outbox.take(lambda: b"SNAP", 1000) == [b"ping", b"SNAP"]
    assert outbox.resyncs == 1 and not outbox.pending


def test_each_change_is_encoded_once_for_every_child(gateway, monkeypatch):
    ctx = gateway.context
    feed = GatewayFeed(ctx)
    boxes = [Outbox(1 << 20) for _ in range(3)]
    for box in boxes:
        feed.attach(box, lambda: None)
        box.resync = False
    calls = []
    real = wire.down
    monkeypatch.setattr(wire, "down", lambda m: calls.append(m[0]) or real(m))
    ctx.image.update_inputs({"lb/m1/ai0": 5})
    assert calls == ["chg"]
    assert boxes[0].data[0] is boxes[1].data[0] is boxes[2].data[0]


def test_frames_over_the_limit_are_refused_from_their_header():
    reader = wire.FrameReader(1000)
    assert reader.feed(wire.HEADER.pack(3) + b"abc" + wire.HEADER.pack(2)) == [b"abc"]
    assert reader.feed(b"de") == [b"de"]
    with pytest.raises(wire.WireError, match="over the 1000-byte limit"):
        reader.feed(wire.HEADER.pack(1_000_000_000))
    assert reader.buffered < 16  # nothing of the announced body was held


@pytest.mark.parametrize(
    "body",
    [b"[1,2]", b"not json", b'{"t": 5}', b"\xff\xfe", b'{"x": "write"}'],
)
def test_what_a_child_sends_is_json_with_a_kind_or_refused(body):
    with pytest.raises(wire.WireError):
        wire.read_up(body)


def test_read_times_that_move_without_a_change_reach_the_mirror(gateway):
    ctx = gateway.context
    feed = GatewayFeed(ctx)
    outbox = Outbox(1 << 20)
    feed.attach(outbox, lambda: None)
    mirror = MirrorContext(ctx.topology, [].append, {})
    ctx.image.update_inputs({"lb/m1/ai0": 5}, timestamp=100.0)
    for message in decode(outbox.take(feed.snapshot, 1 << 20)):
        mirror.apply(message)
    ctx.image.update_inputs({"lb/m1/ai0": 5}, timestamp=107.5)  # the same value read again
    assert not outbox.data  # no change, no batch
    feed.refresh()
    messages = decode(outbox.take(feed.snapshot, 1 << 20))
    assert [m[0] for m in messages] == ["ts"]
    for message in messages:
        mirror.apply(message)
    assert mirror.image["lb/m1/ai0"].timestamp == 107.5
    feed.refresh()
    assert not outbox.pending  # nothing moved since
