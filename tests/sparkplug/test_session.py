"""The Sparkplug session, driven deterministically: no broker, no sleeps, a fake clock."""

from __future__ import annotations

import json
import random

import pytest

from fieldgate.image import ChannelSpec, DataType, Kind, ProcessImage, Quality, Scaling, Source
from fieldgate.plugins.sparkplug.journal import MemoryJournal
from fieldgate.plugins.sparkplug.model import NodeModel, Sample
from fieldgate.plugins.sparkplug.session import (
    Connect,
    DiscardQueuedData,
    Disconnect,
    Instant,
    Publish,
    SaveBdSeq,
    Session,
    SessionSettings,
    State,
    Subscribe,
    Sync,
    Write,
)

from . import spb


def image() -> ProcessImage:
    img = ProcessImage(clock=lambda: 0.0)
    for module in (1, 2):
        for i in range(2):
            img.add(ChannelSpec(f"io/m{module}/di{i}", Kind.DI, Source("io", module, i)))
        img.add(ChannelSpec(f"io/m{module}/do0", Kind.DO, Source("io", module, 0)))
    img.add(
        ChannelSpec(
            "io/m3/ai0",
            Kind.AI,
            Source("io", 3, 0),
            scaling=Scaling(0, 32767, 0.0, 10.0, "V"),
        )
    )
    img.add(ChannelSpec("io/m3/ai1", Kind.AI, Source("io", 3, 1), dtype=DataType.FLOAT32))
    img.add(ChannelSpec("io/m3/ao0", Kind.AO, Source("io", 3, 0)))
    return img


class Clock:
    def __init__(self) -> None:
        self.mono = 100.0
        self.wall = 1_700_000_000_000

    def __call__(self, advance: float = 0.0) -> Instant:
        self.mono += advance
        self.wall += int(advance * 1000)
        return Instant(self.mono, self.wall)


def make(
    journal: MemoryJournal | None = None,
    *,
    last_bdseq: int | None = None,
    writable: tuple[str, ...] = ("io/m1/do0", "io/m3/ao0"),
    deadband: dict[str, float] | None = None,
    **settings: object,
) -> Session:
    channels = list(image())
    model = NodeModel.from_channels("plant", "gw1", channels, writable, deadband)
    opts: dict = dict(brokers=2, replay_messages_per_s=10.0, replay_batch=3, replay_window=2)
    opts.update(settings)
    return Session(
        model,
        SessionSettings(**opts),
        journal if journal is not None else MemoryJournal(),
        last_bdseq=last_bdseq,
        current=[Sample(c.id, c.value, c.quality, 1_600_000_000_000) for c in channels],
        rng=random.Random(1),
    )


def publishes(actions: list) -> list[Publish]:
    return [a for a in actions if isinstance(a, Publish)]


def kinds(actions: list) -> list[str]:
    return [a.topic.split("/")[2] for a in publishes(actions)]


def syncs(actions: list) -> list[Sync]:
    return [a for a in actions if isinstance(a, Sync)]


def confirm(session: Session, clock: Clock, actions: list) -> list:
    """What the broker's acknowledgements of ``actions`` release: the PUBACK of each QoS 1
    DATA message, the UNSUBACK of each Sync."""
    out: list = []
    for a in actions:
        if isinstance(a, Publish) and a.token is not None and a.qos == 1:
            out += session.on_puback(clock(), a.token)
        elif isinstance(a, Sync):
            out += session.on_synced(clock(), a.token)
    return out


def connect_of(actions: list) -> Connect:
    """The one Connect of ``actions`` (a SaveBdSeq may come before it)."""
    (connect,) = [a for a in actions if isinstance(a, Connect)]
    assert all(isinstance(a, (Connect, SaveBdSeq)) for a in actions)
    return connect


def online(session: Session, clock: Clock) -> list:
    connect_of(session.tick(clock()))
    return session.on_connack(clock(), True)


def change(session: Session, cid: str, value, clock: Clock, quality=Quality.GOOD) -> None:
    session.on_change(Sample(cid, value, quality, clock().wall_ms))


def test_connect_carries_the_will_and_the_birth_has_the_same_bdseq():
    clock = Clock()
    session = make(last_bdseq=41)
    first = session.tick(clock())
    assert first[0] == SaveBdSeq(42)  # persisted before the CONNECT that carries it
    connect = connect_of(first)
    assert connect.will_topic == "spBv1.0/plant/NDEATH/gw1"
    will = spb.decode(connect.will_payload)
    assert [(m.name, m.datatype, m.value) for m in will.metrics] == [("bdSeq", spb.INT64, 42)]
    assert will.seq is None  # NDEATH carries no seq
    actions = session.on_connack(clock(), True)
    assert isinstance(actions[0], Subscribe)
    assert set(actions[0].topics) == {"spBv1.0/plant/NCMD/gw1", "spBv1.0/plant/DCMD/gw1/+"}
    assert kinds(actions) == ["NBIRTH", "DBIRTH", "DBIRTH", "DBIRTH"]
    nbirth = spb.decode(publishes(actions)[0].payload)
    assert nbirth.seq == 0
    by_name = {m.name: m for m in nbirth.metrics}
    assert by_name["bdSeq"].value == 42 and by_name["bdSeq"].datatype == spb.INT64
    rebirth = by_name["Node Control/Rebirth"]
    assert rebirth.alias is None and rebirth.datatype == spb.BOOLEAN and rebirth.value is False
    assert by_name["Node Control/Next Server"].alias is None
    assert [spb.decode(p.payload).seq for p in publishes(actions)] == [0, 1, 2, 3]
    assert all(p.qos == 0 and not p.retain for p in publishes(actions))


def test_births_carry_every_metric_with_unique_aliases_datatypes_quality_and_scaling():
    clock = Clock()
    session = make()
    actions = online(session, clock)
    births = {p.topic.rsplit("/", 1)[-1]: spb.decode(p.payload) for p in publishes(actions)[1:]}
    assert sorted(births) == ["io-m1", "io-m2", "io-m3"]
    aliases = [m.alias for b in births.values() for m in b.metrics]
    assert len(aliases) == len(set(aliases)) == 9  # both modules' di0 get distinct aliases
    m1 = {m.name: m for m in births["io-m1"].metrics}
    assert m1["di0"].datatype == spb.BOOLEAN and m1["do0"].datatype == spb.BOOLEAN
    assert m1["di0"].is_null and m1["di0"].quality == 0  # not read yet: BAD, no value
    assert m1["di0"].properties["qualityCause"] == "not-read"
    assert m1["do0"].quality == 192 and m1["do0"].value is False
    m3 = {m.name: m for m in births["io-m3"].metrics}
    assert m3["ai0"].datatype == spb.INT16 and m3["ai1"].datatype == spb.FLOAT
    assert m3["ai0"].properties["engUnit"] == "V"
    assert (m3["ai0"].properties["engLow"], m3["ai0"].properties["engHigh"]) == (0.0, 10.0)
    assert m3["ai0"].property_types["Quality"] == 3  # Int32, as the spec requires


def test_data_by_exception_with_acquisition_timestamps_and_signed_values():
    clock = Clock()
    session = make()
    online(session, clock)
    session.on_change(Sample("io/m3/ai0", -5, Quality.GOOD, 1234))
    session.on_change(Sample("io/m3/ai1", 2.5, Quality.GOOD, 1235))
    session.on_change(Sample("io/m1/di0", True, Quality.STALE, 1236))
    actions = session.flush(clock())
    assert kinds(actions) == ["DDATA", "DDATA"]
    by_dev = {p.topic.rsplit("/", 1)[-1]: spb.decode(p.payload) for p in publishes(actions)}
    ai0, ai1 = by_dev["io-m3"].metrics
    assert ai0.name is None and ai0.datatype is None  # alias only in DATA
    assert spb.value_of(ai0, spb.INT16) == -5 and ai0.timestamp == 1234
    assert ai0.properties == {}  # GOOD needs no Quality property
    assert ai1.value == 2.5 and ai1.timestamp == 1235
    (di0,) = by_dev["io-m1"].metrics
    assert di0.value is True and di0.quality == 500 and not di0.is_historical
    assert session.flush(clock()) == []  # nothing changed since


def test_seq_increments_by_one_modulo_256_over_600_messages():
    clock = Clock()
    session = make(data_qos=0)
    seqs = [spb.decode(p.payload).seq for p in publishes(online(session, clock))]
    for i in range(700):
        change(session, "io/m3/ai0", i % 1000, clock)
        seqs += [spb.decode(p.payload).seq for p in publishes(session.flush(clock(0.01)))]
    assert len(seqs) == 704
    assert all(b == (a + 1) % 256 for a, b in zip(seqs, seqs[1:], strict=False))
    assert seqs.count(0) == 3  # NBIRTH, then two wraps


@pytest.mark.parametrize("qos", [0, 1])
def test_outage_journals_samples_and_replays_them_in_order_as_historical_once_confirmed(qos):
    clock = Clock()
    journal = MemoryJournal()
    session = make(journal, data_qos=qos)
    online(session, clock)
    assert session.on_connection_lost(clock(), "broker gone") == []
    assert session.state is State.DISCONNECTED
    for i in range(10):
        clock(0.1)
        change(session, "io/m3/ai0", i, clock)
        assert session.flush(clock()) == []
    assert journal.count() == 10
    assert session.status(clock().wall_ms)["backlog_oldest_age_s"] == pytest.approx(0.9)
    # reconnect: new bdSeq, births first, then a capped replay beside live data
    when = session.next_deadline()
    assert when is not None
    connect = connect_of(session.tick(Instant(when, clock().wall_ms)))
    assert (
        connect.bdseq == 1 and connect.broker == 0
    )  # a dropped connection retries the same broker
    actions = session.on_connack(clock(), True)
    assert kinds(actions)[:4] == ["NBIRTH", "DBIRTH", "DBIRTH", "DBIRTH"]
    replay = publishes(actions)[4:]
    assert len(replay) == 2  # the window: 2 unconfirmed historical messages
    # QoS 0: one Sync after them (the broker's UNSUBACK confirms both); QoS 1: their PUBACKs
    assert len(syncs(actions)) == (1 if qos == 0 else 0)
    change(session, "io/m3/ai0", 99, clock)
    live = session.flush(clock())
    assert [spb.decode(p.payload).metrics[0].is_historical for p in publishes(live)] == [False]
    assert syncs(live) == []  # one Sync awaited at a time
    assert session.tick(clock(1)) == []  # window full: nothing until confirmed
    assert journal.count() == 10  # nothing dropped before it is confirmed
    seen: list[int] = []
    todo = [a for a in actions if isinstance(a, Sync) or getattr(a, "token", None)] + live
    while todo:
        batch, todo = todo, []
        for p in publishes(batch):
            assert p.qos == qos and not p.retain
            metrics = spb.decode(p.payload).metrics
            if p.kind == "ddata_historical":
                assert all(m.is_historical for m in metrics)
                seen += [spb.value_of(m, spb.INT16) for m in metrics]
        todo += confirm(session, clock, batch)
        deadline = session.next_deadline()
        if deadline is not None:
            todo += session.tick(Instant(deadline, clock().wall_ms))
    assert seen == list(range(10))
    assert journal.count() == 0 and session.dropped == 0
    assert session.status(clock().wall_ms)["inflight"] == 0  # the live one confirmed too


def test_qos0_data_waits_for_the_sync_and_a_sync_of_a_lost_connection_confirms_nothing():
    clock = Clock()
    journal = MemoryJournal()
    session = make(journal)  # data_qos 0: the default
    online(session, clock)
    change(session, "io/m3/ai0", 1, clock)
    first = session.flush(clock())
    assert kinds(first) == ["DDATA"] and publishes(first)[0].qos == 0
    (sync,) = syncs(first)
    assert session.on_puback(clock(), publishes(first)[0].token) == []  # QoS 0 has no PUBACK
    assert session.status(clock().wall_ms)["inflight"] == 1
    change(session, "io/m3/ai0", 2, clock)
    assert syncs(session.flush(clock())) == []  # covered by the next Sync
    follow = session.on_synced(clock(), sync.token)
    assert len(syncs(follow)) == 1  # the second DDATA gets its own
    assert session.status(clock().wall_ms)["inflight"] == 1
    session.on_connection_lost(clock(), "gone")
    assert [s.value for _, s in journal.read(0, 10)] == [2]  # the unconfirmed one
    assert session.on_synced(clock(), syncs(follow)[0].token) == []  # of the old connection
    assert journal.count() == 1


def test_replay_rate_is_capped():
    clock = Clock()
    journal = MemoryJournal()
    session = make(journal, replay_batch=1, replay_window=100, replay_messages_per_s=10.0)
    for i in range(30):
        change(session, "io/m3/ai0", i, clock)
    session.flush(clock())
    assert journal.count() == 30
    session.tick(clock(60))
    burst = publishes(session.on_connack(clock(), True))[4:]
    assert len(burst) == 10  # one second's worth at most
    assert session.tick(clock()) == []
    times = []
    while len(burst) < 30:
        deadline = session.next_deadline()
        assert deadline is not None
        sent = publishes(session.tick(Instant(deadline, clock().wall_ms)))
        assert len(sent) == 1
        burst += sent
        times.append(deadline)
    assert all(b - a == pytest.approx(0.1) for a, b in zip(times, times[1:], strict=False))


@pytest.mark.parametrize("qos", [0, 1])
def test_unconfirmed_live_data_goes_to_the_journal_when_the_connection_drops(qos):
    clock = Clock()
    journal = MemoryJournal()
    session = make(journal, data_qos=qos)
    online(session, clock)
    change(session, "io/m3/ai0", 7, clock)
    acked = session.flush(clock())
    session.on_puback(clock(), publishes(acked)[0].token) if qos else confirm(session, clock, acked)
    change(session, "io/m3/ai0", 8, clock)
    lost = session.flush(clock())
    assert kinds(lost) == ["DDATA"]
    session.on_connection_lost(clock(), "gone")
    assert [s.value for _, s in journal.read(0, 10)] == [8]


def test_a_replay_interrupted_by_a_disconnect_is_sent_again_whole():
    clock = Clock()
    journal = MemoryJournal()
    session = make(journal, replay_batch=100)
    session.tick(clock())
    session.on_connection_lost(clock(), "refused")  # failed attempt: next broker
    for i in range(5):
        change(session, "io/m3/ai0", i, clock)
    session.flush(clock())
    session.tick(clock(60))
    first = publishes(session.on_connack(clock(), True))[-1]
    assert [m.value for m in spb.decode(first.payload).metrics] == [0, 1, 2, 3, 4]
    session.on_connection_lost(clock(), "gone")
    session.tick(clock(60))
    actions = session.on_connack(clock(), True)
    again = publishes(actions)[-1]
    assert [m.value for m in spb.decode(again.payload).metrics] == [0, 1, 2, 3, 4]
    confirm(session, clock, actions)
    assert journal.count() == 0


def test_bdseq_goes_up_per_connect_packet_is_saved_before_it_and_wraps_at_256():
    clock = Clock()
    session = make(last_bdseq=253)
    first = session.tick(clock())
    assert first[0] == SaveBdSeq(254) and connect_of(first).bdseq == 254
    # the TCP connection failed: no CONNECT carried 254, the next attempt reuses it unsaved
    session.on_connection_lost(clock(), "refused", connect_sent=False)
    again = session.tick(clock(60))
    assert again == [connect_of(again)] and again[0].bdseq == 254 and again[0].broker == 1
    # a refused CONNACK: that CONNECT was sent, so the next one carries 255 (saved first)
    session.on_connack(clock(), False, "not authorized")
    third = session.tick(clock(60))
    assert third[0] == SaveBdSeq(255) and connect_of(third).bdseq == 255
    session.on_connack(clock(), True)
    session.on_connection_lost(clock(), "gone")
    wrapped = session.tick(clock(60))
    assert wrapped[0] == SaveBdSeq(0) and connect_of(wrapped).bdseq == 0
    assert spb.decode(connect_of(wrapped).will_payload).metrics[0].value == 0
    # a gateway restarted from the saved value never reuses it, CONNACK or not
    assert connect_of(make(last_bdseq=0).tick(clock())).bdseq == 1


def test_connect_timeout_gives_up_and_tries_the_next_broker():
    clock = Clock()
    session = make()
    c = connect_of(session.tick(clock()))
    assert session.next_deadline() == pytest.approx(clock().mono + 10)
    assert session.tick(clock(10)) == [Disconnect("no CONNACK in time")]
    c2 = connect_of(session.tick(clock(60)))
    assert c2.broker == 1 and c2.bdseq == c.bdseq + 1  # that CONNECT may have arrived


def test_rebirth_publishes_nbirth_and_every_dbirth_with_no_data_in_between():
    clock = Clock()
    session = make()
    online(session, clock)
    for _ in range(3):
        change(session, "io/m3/ai0", 3, clock)
        session.flush(clock())
    change(session, "io/m1/di0", True, clock)  # pending when the command arrives
    cmd = spb.command(
        spb.command_metric(name="Node Control/Rebirth", datatype=spb.BOOLEAN, value=True)
    )
    actions = session.on_message(clock(), "spBv1.0/plant/NCMD/gw1", cmd)
    assert actions[0] == DiscardQueuedData()  # before the NBIRTH: DATA not yet sent is dropped
    assert kinds(actions) == ["NBIRTH", "DBIRTH", "DBIRTH", "DBIRTH"]
    payloads = [spb.decode(p.payload) for p in publishes(actions)]
    assert [p.seq for p in payloads] == [0, 1, 2, 3]
    assert {m.name: m.value for m in payloads[0].metrics}["bdSeq"] == 0  # same connection
    m1 = {m.name: m for m in payloads[1].metrics}
    assert m1["di0"].value is True  # the births carry the current values
    assert kinds(session.flush(clock())) == ["DDATA"]  # the pending change follows, seq 4
    assert session.rebirths["ncmd"] == 1


def test_data_discarded_for_a_rebirth_follows_the_births_as_historical_data():
    clock = Clock()
    journal = MemoryJournal()
    session = make(journal)
    online(session, clock)
    change(session, "io/m3/ai0", 1, clock)
    sent = session.flush(clock())  # handed to the client before the request
    change(session, "io/m3/ai0", 2, clock)
    change(session, "io/m1/di0", True, clock)
    queued = publishes(session.flush(clock()))  # still in the adapter's outbox
    assert kinds(queued) == ["DDATA", "DDATA"]
    cmd = spb.command(
        spb.command_metric(name="Node Control/Rebirth", datatype=spb.BOOLEAN, value=True)
    )
    actions = session.on_message(clock(), "spBv1.0/plant/NCMD/gw1", cmd)
    assert actions[0] == DiscardQueuedData()
    assert kinds(actions) == ["NBIRTH", "DBIRTH", "DBIRTH", "DBIRTH"]  # no DATA in this step
    session.on_discarded(clock(), [p.token for p in queued])
    assert sorted(s.value for _, s in journal.read(0, 10)) == [True, 2]
    assert session.status(clock().wall_ms)["discarded_data_messages"] == {"rebirth": 2}
    after = session.tick(clock())
    history = publishes(after)
    assert kinds(after) == ["DDATA", "DDATA"] and syncs(after) == []  # the first Sync is awaited
    assert [spb.decode(p.payload).seq for p in history] == [4, 5]  # the new births' sequence
    assert all(m.is_historical for p in history for m in spb.decode(p.payload).metrics)
    more = confirm(session, clock, sent)  # the message sent before the request is confirmed
    assert len(syncs(more)) == 1
    confirm(session, clock, more)
    assert journal.count() == 0 and session.status(clock().wall_ms)["inflight"] == 0


def test_next_server_sends_ndeath_disconnects_and_moves_on():
    clock = Clock()
    session = make()
    online(session, clock)
    cmd = spb.command(
        spb.command_metric(name="Node Control/Next Server", datatype=spb.BOOLEAN, value=True)
    )
    actions = session.on_message(clock(), "spBv1.0/plant/NCMD/gw1", cmd)
    assert kinds(actions) == ["NDEATH"] and actions[0].qos == 1
    assert isinstance(actions[-1], Disconnect)
    c = connect_of(session.tick(clock()))
    assert c.broker == 1 and c.bdseq == 1


def test_module_offline_gives_ddeath_and_back_online_a_dbirth_with_current_values():
    clock = Clock()
    session = make()
    online(session, clock)
    session.on_device_health("io-m2", False)
    actions = session.flush(clock())
    assert [p.topic for p in publishes(actions)] == ["spBv1.0/plant/DDEATH/gw1/io-m2"]
    assert spb.decode(actions[0].payload).seq == 4
    change(session, "io/m2/di1", True, clock, Quality.COMM_FAULT)
    assert session.flush(clock()) == []  # a dead device publishes nothing
    session.on_device_health("io-m2", True)
    change(session, "io/m2/di1", False, clock)
    actions = publishes(session.flush(clock()))
    assert actions[0].topic == "spBv1.0/plant/DBIRTH/gw1/io-m2"
    di1 = {m.name: m for m in spb.decode(actions[0].payload).metrics}["di1"]
    assert di1.value is False and di1.quality == 192


def test_dcmd_writes_only_writable_outputs_and_counts_the_rest():
    clock = Clock()
    session = make(max_command_bytes=200)
    online(session, clock)
    alias = session.model.by_channel["io/m3/ao0"].alias
    good = spb.command(spb.command_metric(alias=alias, datatype=spb.INT16, value=-300))
    assert session.on_message(clock(), "spBv1.0/plant/DCMD/gw1/io-m3", good) == [
        Write("io/m3/ao0", -300)
    ]
    by_name = spb.command(spb.command_metric(name="do0", datatype=spb.BOOLEAN, value=True))
    assert session.on_message(clock(), "spBv1.0/plant/DCMD/gw1/io-m1", by_name) == [
        Write("io/m1/do0", True)
    ]
    cases = {
        "not_writable": ("io-m2", spb.command_metric(name="do0", datatype=spb.BOOLEAN, value=True)),
        "unknown_metric": (
            "io-m1",
            spb.command_metric(name="nope", datatype=spb.BOOLEAN, value=True),
        ),
        "bad_value": ("io-m3", spb.command_metric(alias=alias, datatype=spb.INT32, value=70000)),
    }
    for reason, (dev, metric) in cases.items():
        assert (
            session.on_message(clock(), f"spBv1.0/plant/DCMD/gw1/{dev}", spb.command(metric)) == []
        )
        assert session.ignored[reason] == 1, reason
    # an alias of another device's metric is not this device's
    other = spb.command(spb.command_metric(alias=alias, datatype=spb.INT16, value=1))
    assert session.on_message(clock(), "spBv1.0/plant/DCMD/gw1/io-m1", other) == []
    assert session.ignored["unknown_metric"] == 2
    wrong_type = spb.command(spb.command_metric(name="do0", datatype=spb.STRING, value="on"))
    assert session.on_message(clock(), "spBv1.0/plant/DCMD/gw1/io-m1", wrong_type) == []
    assert session.ignored["bad_value"] == 2
    for topic, data, reason in [
        ("spBv1.0/plant/DCMD/gw1/io-m1", b"\xff\xff\xff", "malformed"),
        ("spBv1.0/plant/NCMD/gw1", b"\x12\x05\x0a", "malformed"),
        ("spBv1.0/plant/DCMD/gw1/io-m1", bytes(201), "oversized"),
        ("spBv1.0/plant/DCMD/gw1/nosuch", good, "unknown_device"),
        (
            "spBv1.0/plant/NCMD/gw1",
            spb.command(spb.command_metric(name="x", datatype=spb.BOOLEAN, value=True)),
            "unknown_metric",
        ),
    ]:
        before = session.ignored[reason]
        assert session.on_message(clock(), topic, data) == []
        assert session.ignored[reason] == before + 1, reason
    assert session.state is State.ONLINE


def test_primary_host_gates_the_birth_and_its_offline_state_moves_to_the_next_broker():
    clock = Clock()
    session = make(primary_host_id="scada")
    actions = online(session, clock)
    assert "spBv1.0/STATE/scada" in actions[0].topics
    assert publishes(actions) == []
    change(session, "io/m3/ai0", 5, clock)
    assert session.flush(clock()) == [] and session.journal.count() == 1  # held, not lost

    def state(online_: bool, ts: int) -> list:
        return session.on_message(
            clock(),
            "spBv1.0/STATE/scada",
            json.dumps({"online": online_, "timestamp": ts}).encode(),
        )

    assert session.on_message(clock(), "spBv1.0/STATE/scada", b"ONLINE") == []
    assert session.ignored["bad_state"] == 1
    actions = state(True, 20)
    assert kinds(actions)[:4] == ["NBIRTH", "DBIRTH", "DBIRTH", "DBIRTH"]
    assert state(False, 19) == []  # an old will of the host: ignored
    assert session.ignored["stale_state"] == 1 and session.state is State.ONLINE
    actions = state(False, 30)
    assert kinds(actions) == ["NDEATH"] and isinstance(actions[-1], Disconnect)
    c = connect_of(session.tick(clock()))
    assert c.broker == 1
    session.on_connack(clock(), True)
    # on the next broker, the host's STATE carries that connection's own (older) timestamp
    assert kinds(state(True, 25))[:1] == ["NBIRTH"]


def test_a_waiting_node_walks_the_brokers_until_it_finds_the_primary_host_online():
    clock = Clock()
    session = make(primary_host_id="scada", brokers=2, primary_host_wait_s=10.0)
    online(session, clock)
    assert session.state is State.WAITING_HOST
    assert session.next_deadline() == pytest.approx(clock().mono + 10)

    def state(online_: bool, ts: int) -> list:
        doc = json.dumps({"online": online_, "timestamp": ts}).encode()
        return session.on_message(clock(), "spBv1.0/STATE/scada", doc)

    # broker 0 holds the host's retained offline STATE: NDEATH, leave, try broker 1
    actions = state(False, 5)
    assert kinds(actions) == ["NDEATH"] and isinstance(actions[-1], Disconnect)
    assert session.next_deadline() > clock().mono  # after the reconnect delay, not in a loop
    c = connect_of(session.tick(Instant(session.next_deadline(), clock().wall_ms)))
    assert c.broker == 1
    session.on_connack(clock(), True)
    # broker 1 has no STATE of the host at all: after primary_host_wait_s, back to broker 0
    assert session.tick(clock(9.9)) == []
    actions = session.tick(clock(0.1))
    assert kinds(actions) == ["NDEATH"] and isinstance(actions[-1], Disconnect)
    c = connect_of(session.tick(Instant(session.next_deadline(), clock().wall_ms)))
    assert c.broker == 0
    session.on_connack(clock(), True)
    assert kinds(state(True, 7))[:1] == ["NBIRTH"]  # found it


def test_with_one_broker_a_waiting_node_stays_and_waits_for_the_host():
    clock = Clock()
    session = make(primary_host_id="scada", brokers=1)
    online(session, clock)
    doc = json.dumps({"online": False, "timestamp": 5}).encode()
    assert session.on_message(clock(), "spBv1.0/STATE/scada", doc) == []
    assert session.next_deadline() is None and session.state is State.WAITING_HOST


def test_deadband_suppresses_small_changes_but_never_quality_changes():
    clock = Clock()
    session = make(deadband={"io/m3/ai*": 10})
    online(session, clock)
    change(session, "io/m3/ai0", 5, clock)  # from 0 (not read): a quality change
    assert len(publishes(session.flush(clock()))) == 1
    change(session, "io/m3/ai0", 14, clock)
    assert session.flush(clock()) == []
    change(session, "io/m3/ai0", 15, clock)
    assert len(publishes(session.flush(clock()))) == 1
    change(session, "io/m3/ai0", 16, clock, Quality.STALE)
    assert len(publishes(session.flush(clock()))) == 1


def test_a_full_journal_drops_the_oldest_and_counts_them():
    clock = Clock()
    journal = MemoryJournal(max_samples=5)
    session = make(journal)
    for i in range(8):
        change(session, "io/m3/ai0", i, clock)
    session.flush(clock())
    assert [s.value for _, s in journal.read(0, 10)] == [3, 4, 5, 6, 7]
    assert session.dropped == 3 and session.status(clock().wall_ms)["dropped_messages"] == 3


def test_rows_of_an_offline_device_wait_for_its_birth():
    clock = Clock()
    journal = MemoryJournal()
    session = make(journal, replay_batch=10)
    session.tick(clock())
    session.on_connection_lost(clock(), "refused")
    change(session, "io/m2/di0", True, clock)
    change(session, "io/m3/ai0", 1, clock)
    session.flush(clock())
    session.on_device_health("io-m2", False)
    session.tick(clock(60))
    actions = session.on_connack(clock(), True)
    assert kinds(actions) == ["NBIRTH", "DBIRTH", "DBIRTH", "DDATA"]
    confirm(session, clock, actions)
    assert session.next_deadline() is None  # the io-m2 row waits; no busy loop
    session.on_device_health("io-m2", True)
    actions = publishes(session.flush(clock(1)))
    assert kinds(actions) == ["DBIRTH", "DDATA"]
    assert spb.decode(actions[-1].payload).metrics[0].is_historical


def test_stop_sends_ndeath_and_keeps_what_was_not_acknowledged():
    clock = Clock()
    journal = MemoryJournal()
    session = make(journal)
    online(session, clock)
    change(session, "io/m3/ai0", 1, clock)
    session.flush(clock())
    change(session, "io/m3/ai0", 2, clock)
    actions = session.stop(clock())
    assert kinds(actions) == ["NDEATH"] and isinstance(actions[-1], Disconnect)
    assert [s.value for _, s in journal.read(0, 10)] == [1, 2]
    assert session.tick(clock(100)) == [] and session.next_deadline() is None


def test_random_and_mutated_commands_never_raise_and_are_all_accounted_for():
    """A seeded fuzz of the command path: random bytes, truncations and bit flips of valid
    NCMD/DCMD/STATE payloads. Each message either acts (a write, a rebirth, a move) or is
    counted as ignored; nothing raises."""
    rng = random.Random(15)
    clock = Clock()
    session = make(primary_host_id="scada", max_command_bytes=512)
    online(session, clock)
    session.on_message(clock(), "spBv1.0/STATE/scada", b'{"online": true, "timestamp": 1}')
    alias = session.model.by_channel["io/m3/ao0"].alias
    valid = [
        (
            "spBv1.0/plant/DCMD/gw1/io-m3",
            spb.command(spb.command_metric(alias=alias, datatype=spb.INT16, value=5)),
        ),
        (
            "spBv1.0/plant/DCMD/gw1/io-m1",
            spb.command(spb.command_metric(name="do0", datatype=spb.BOOLEAN, value=True)),
        ),
        (
            "spBv1.0/plant/NCMD/gw1",
            spb.command(
                spb.command_metric(name="Node Control/Rebirth", datatype=spb.BOOLEAN, value=True)
            ),
        ),
        ("spBv1.0/STATE/scada", b'{"online": true, "timestamp": 2}'),
    ]
    acted = 0
    for _ in range(3000):
        topic, payload = rng.choice(valid)
        data = bytearray(payload)
        mode = rng.randrange(4)
        if mode == 0:
            data = bytearray(rng.randbytes(rng.randrange(0, 700)))
        elif mode == 1 and data:
            del data[rng.randrange(len(data)) :]
        elif mode == 2 and data:
            for _ in range(rng.randrange(1, 4)):
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        actions = session.on_message(clock(0.001), topic, bytes(data))
        if session.state is not State.ONLINE:  # a mutated Next Server or STATE offline
            session.tick(clock(60))
            session.on_connack(clock(), True)
            session.on_message(
                clock(),
                "spBv1.0/STATE/scada",
                json.dumps({"online": True, "timestamp": 10**12}).encode(),
            )
        acted += bool(actions)
    assert acted > 100 and sum(session.ignored.values()) > 1000
    assert set(session.ignored) <= {
        "malformed", "oversized", "unknown_metric", "not_writable", "bad_value",
        "unknown_device", "unexpected_topic", "bad_state", "stale_state",
    }  # fmt: skip


def test_every_data_type_of_the_image_has_a_sparkplug_type():
    from fieldgate.plugins.sparkplug.model import SPARKPLUG_TYPE

    assert set(SPARKPLUG_TYPE) == set(DataType)  # a new image type must get one here


def test_special_bytes_are_uint8_metrics_and_a_dcmd_writes_one_byte():
    img = ProcessImage(clock=lambda: 0.0)
    for n in range(2):
        img.add(ChannelSpec(f"io/m4/si{n}", Kind.SI, Source("io", 4, n), dtype=DataType.UINT8))
    img.add(ChannelSpec("io/m4/so0", Kind.SO, Source("io", 4, 0), dtype=DataType.UINT8))
    channels = list(img)
    model = NodeModel.from_channels("plant", "gw1", channels, ("io/m4/so0",), None)
    session = Session(
        model,
        SessionSettings(brokers=1),
        MemoryJournal(),
        last_bdseq=None,
        current=[Sample(c.id, 200, Quality.GOOD, 1_600_000_000_000) for c in channels],
        rng=random.Random(1),
    )
    clock = Clock()
    actions = online(session, clock)
    (birth,) = [spb.decode(p.payload) for p in publishes(actions) if "/DBIRTH/" in p.topic]
    metrics = {m.name: m for m in birth.metrics}
    assert {m.datatype for m in metrics.values()} == {spb.UINT8}
    assert metrics["si1"].value == 200
    alias = session.model.by_channel["io/m4/so0"].alias
    write = spb.command(spb.command_metric(alias=alias, datatype=spb.UINT8, value=0x5A))
    assert session.on_message(clock(), "spBv1.0/plant/DCMD/gw1/io-m4", write) == [
        Write("io/m4/so0", 0x5A)
    ]
    too_big = spb.command(spb.command_metric(alias=alias, datatype=spb.UINT8, value=256))
    assert session.on_message(clock(), "spBv1.0/plant/DCMD/gw1/io-m4", too_big) == []
    assert session.ignored["bad_value"] == 1


def test_a_deeply_nested_state_is_counted_and_ignored_never_a_recursion_error():
    # a retained STATE comes back at every reconnect: raising on it stopped the node for good
    clock = Clock()
    session = make(primary_host_id="scada")
    online(session, clock)
    deep = b'{"online": true, "timestamp": 1, "x": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    assert session.on_message(clock(), "spBv1.0/STATE/scada", deep[:4000]) == []
    assert session.ignored["bad_state"] == 1  # 4000 bytes, 1960 levels deep
    assert session.on_message(clock(), "spBv1.0/STATE/scada", deep) == []
    assert session.ignored["oversized"] == 1  # STATE has its own small size limit
    nested = b'{"online": true, "timestamp": 2, "x": [[[[[[1]]]]]]}'
    assert session.on_message(clock(), "spBv1.0/STATE/scada", nested) == []
    assert session.ignored["bad_state"] == 2
    # and the node still works: a sound STATE births it
    good = b'{"online": true, "timestamp": 3, "note": "[[[[[[[[ in a string"}'
    assert kinds(session.on_message(clock(), "spBv1.0/STATE/scada", good))[:1] == ["NBIRTH"]


def test_json_depth_counts_brackets_outside_strings():
    from fieldgate.plugins.sparkplug.session import json_depth

    assert json_depth(b'{"a": [1, {"b": 2}]}') == 3
    assert json_depth(b'{"a": "[[[[\\"[["}') == 1
    assert json_depth(b"") == 0


def test_a_burst_of_rebirth_requests_is_coalesced_into_one_more_rebirth():
    clock = Clock()
    session = make(rebirth_min_interval_s=1.0)
    online(session, clock)
    cmd = spb.command(
        spb.command_metric(name="Node Control/Rebirth", datatype=spb.BOOLEAN, value=True)
    )
    assert kinds(session.on_message(clock(), "spBv1.0/plant/NCMD/gw1", cmd))[0] == "NBIRTH"
    # the first request within the interval stops DATA at once; the others change nothing
    assert session.on_message(clock(0.01), "spBv1.0/plant/NCMD/gw1", cmd) == [DiscardQueuedData()]
    for _ in range(49):  # a host (or a loop of them) asking over and over
        assert session.on_message(clock(0.01), "spBv1.0/plant/NCMD/gw1", cmd) == []
    assert session.rebirths["coalesced"] == 50
    change(session, "io/m3/ai0", 5, clock)
    assert session.flush(clock()) == []  # no DATA until the births: journaled
    assert session.journal.count() == 1
    due = session.next_deadline()
    assert due == pytest.approx(clock().mono - 0.5 + 1.0)  # one interval after the first
    assert session.tick(clock(0.1)) == []  # not yet
    actions = session.tick(Instant(due, clock().wall_ms))
    assert kinds(actions) == ["NBIRTH", "DBIRTH", "DBIRTH", "DBIRTH", "DDATA"]  # one, for all 50
    assert spb.decode(publishes(actions)[-1].payload).metrics[0].is_historical  # the held change
    assert session.rebirths["ncmd"] == 2 and session.next_deadline() is None
    # a request after the interval is served at once again
    later = session.on_message(clock(2.0), "spBv1.0/plant/NCMD/gw1", cmd)
    assert kinds(later)[0] == "NBIRTH"


def test_an_oversized_ncmd_is_counted_and_dropped():
    clock = Clock()
    session = make(max_command_bytes=256)
    online(session, clock)
    assert session.on_message(clock(), "spBv1.0/plant/NCMD/gw1", b"\x00" * 257) == []
    assert session.ignored["oversized"] == 1
