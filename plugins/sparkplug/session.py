"""The Sparkplug B edge-node session, sans-I/O.

Inputs: connection results (:meth:`Session.on_connack`, :meth:`on_connection_lost`),
acknowledgements (:meth:`on_puback`), incoming messages (:meth:`on_message`: NCMD, DCMD,
STATE), process-image changes (:meth:`on_change`, published at the next :meth:`flush`),
module health (:meth:`on_device_health`) and time (:meth:`tick`). Outputs: lists of
actions (:class:`Connect`, :class:`Subscribe`, :class:`Publish`, :class:`Disconnect`,
:class:`Write`, :class:`SaveBdSeq`) for the adapter, and :meth:`next_deadline`. Every
input takes an :class:`Instant` (monotonic seconds for timers, wall-clock milliseconds for
payload timestamps); tests drive it with a fake clock.

Session rules (Sparkplug B 3.0):

* Every CONNECT carries the NDEATH will (QoS 1, not retained) with an INT64 ``bdSeq``; the
  NBIRTH of that connection carries the same ``bdSeq``. ``bdSeq`` goes up by one (mod 256)
  per CONNECT packet (tck-id-topics-nbirth-bdseq-increment): after a connection, a refused
  or timed-out CONNECT; an attempt whose TCP/TLS connection failed sent no CONNECT and
  keeps its value. The adapter persists the value on :class:`SaveBdSeq` before the CONNECT
  that carries it, so a restarted gateway continues after it even if it died before the
  CONNACK.
* ``seq`` is 0 in NBIRTH, then +1 mod 256 on every DBIRTH/DDATA/DDEATH.
* With ``primary_host_id``, nothing is published until ``spBv1.0/STATE/<id>`` says online;
  an offline STATE (timestamp not older than the last online one) publishes NDEATH,
  disconnects and moves to the next broker. With more than one broker, a node still
  waiting moves on too: at an offline STATE, or when no online STATE came within
  ``primary_host_wait_s`` (it walks the list until it finds the host online).
* NCMD ``Node Control/Rebirth``: NBIRTH and every DBIRTH at once, same ``bdSeq``, no DATA
  (at most one rebirth per ``rebirth_min_interval_s``: requests in between are coalesced
  into one when it has passed)
  in between. ``Node Control/Next Server``: disconnect and move to the next broker.

Store-and-forward: while the session is not publishing (no connection, the primary host
offline, a rebirth due), samples go to the journal. Every DDATA, live or historical, is
sent at ``data_qos`` (0 by default, as Sparkplug 3.0 requires) and stays *unconfirmed*
until the broker has provably read it: at QoS 1 its PUBACK; at QoS 0 a :class:`Sync`
emitted after it (the adapter sends an MQTT UNSUBSCRIBE of a filter nothing matches; the
broker reads a connection's packets in order, so its UNSUBACK comes after it read every
PUBLISH before it). Live samples of a DDATA unconfirmed when the connection drops go to
the journal. After the births, the journal is replayed in order as DDATA with
``is_historical``, at most ``replay_messages_per_s`` messages per second and
``replay_window`` unconfirmed at once, beside live data; a row leaves the journal only
when its message is confirmed. Rows of a device that is offline wait for its DBIRTH.

Rebirth without stale DATA: an accepted Rebirth request first emits
:class:`DiscardQueuedData`; the adapter drops every DATA message it has not yet handed to
the MQTT client (they belong to the old birth sequence) and reports their tokens to
:meth:`Session.on_discarded`, which puts their samples back in the journal (live ones) or
back in the replay (historical ones): they follow the new births as historical data.
"""

from __future__ import annotations

import json
import random
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import StrEnum

from fieldgate.image import Quality

from . import payload as codec
from .journal import Journal
from .model import NEXT_SERVER, REBIRTH, MetricDef, NodeModel, Sample, Value

CONNECT_TIMEOUT_S = 10.0
SEQ_MODULO = 256
BDSEQ_MODULO = 256


@dataclass(frozen=True)
class Instant:
    mono: float  # monotonic seconds: timers
    wall_ms: int  # milliseconds since the epoch: payload timestamps


class State(StrEnum):
    DISCONNECTED = "disconnected"
    CONNECTING = "connecting"
    WAITING_HOST = "waiting-for-primary-host"
    ONLINE = "online"
    STOPPED = "stopped"


# -- actions --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Connect:
    broker: int  # index into the configured broker list
    client_id: str
    will_topic: str
    will_payload: bytes
    bdseq: int


@dataclass(frozen=True)
class Subscribe:
    topics: tuple[str, ...]


@dataclass(frozen=True)
class Publish:
    topic: str
    payload: bytes
    qos: int = 0
    retain: bool = False
    token: int | None = None  # DATA only: confirmed by on_puback (QoS 1) or a Sync (QoS 0)
    kind: str = ""  # nbirth, dbirth, ddata, ddata_historical, ddeath, ndeath: counters, logs
    seq: int | None = None  # the payload's seq (logs)


@dataclass(frozen=True)
class Sync:
    """Tell :meth:`Session.on_synced` (with this token) once the broker has read every
    message handed to the MQTT client before this action."""

    token: int


@dataclass(frozen=True)
class DiscardQueuedData:
    """Drop every DATA message not yet handed to the MQTT client and report their tokens
    to :meth:`Session.on_discarded` (a Rebirth request: they belong to the old births)."""


@dataclass(frozen=True)
class Disconnect:
    reason: str


@dataclass(frozen=True)
class Write:
    channel_id: str
    value: Value


@dataclass(frozen=True)
class SaveBdSeq:
    bdseq: int


Action = Connect | Subscribe | Publish | Sync | DiscardQueuedData | Disconnect | Write | SaveBdSeq

MAX_STATE_BYTES = 4096
"""A STATE message is ``{"online": true, "timestamp": ...}``: anything much larger is not one."""

MAX_STATE_DEPTH = 4
"""Deepest JSON nesting a STATE may have (it has 1)."""


def json_depth(data: bytes) -> int:
    """Deepest nesting of ``[``/``{`` in JSON text, outside strings; linear, no recursion."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in data:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            deepest = max(deepest, depth)
        elif byte in (0x5D, 0x7D):
            depth -= 1
    return deepest


@dataclass
class SessionSettings:
    brokers: int = 1
    client_id: str = "fieldgate"
    primary_host_id: str | None = None
    data_qos: int = 0
    replay_messages_per_s: float = 20.0
    replay_batch: int = 500
    replay_window: int = 8
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 8.0
    max_command_bytes: int = 65536
    rebirth_min_interval_s: float = 1.0
    primary_host_wait_s: float = 10.0


@dataclass
class _InFlight:
    historical: bool
    samples: list[Sample] = field(default_factory=list)  # live: re-journaled when lost
    ids: list[int] = field(default_factory=list)  # historical: journal rows to delete
    qos: int = 0


class Session:
    def __init__(
        self,
        model: NodeModel,
        settings: SessionSettings,
        journal: Journal,
        *,
        last_bdseq: int | None = None,
        current: Iterable[Sample] = (),
        online_devices: Iterable[str] | None = None,
        rng: random.Random | None = None,
    ):
        self.model = model
        self.settings = settings
        self.journal = journal
        self.rng = rng or random.Random(0)
        self.state = State.DISCONNECTED
        self.broker = 0
        self._saved_bdseq = last_bdseq  # persisted: the last value a CONNECT may have carried
        self.bdseq = 0 if last_bdseq is None else (last_bdseq + 1) % BDSEQ_MODULO
        self.seq = 0
        self.current: dict[str, Sample] = {s.channel_id: s for s in current}
        self.published: dict[str, Sample] = {}  # last value sent live, for deadbands
        online = set(model.devices) if online_devices is None else set(online_devices)
        self.device_online: dict[str, bool] = {d: d in online for d in model.devices}
        self.birthed: set[str] = set()
        self._birth_pending: set[str] = set()
        self._pending: dict[str, list[Sample]] = {}
        self._inflight: dict[int, _InFlight] = {}
        self._token = 0
        self._attempt = 0
        self._reconnect_at: float | None = 0.0
        self._connect_deadline: float | None = None
        self._replay_cursor = 0
        self._replay_next_at = 0.0
        self._replay_ids: set[int] = set()
        self._replay_blocked = False  # every waiting row belongs to an offline device
        self._host_ts: int | None = None  # timestamp of the last accepted STATE
        self._host_wait_until: float | None = None  # waiting for the host: next broker then
        self._unsynced: list[int] = []  # QoS 0 DATA tokens handed out since the last Sync
        self._sync_token: int | None = None  # the Sync awaiting on_synced
        self._sync_covers: list[int] = []  # the tokens it confirms
        # counters
        self.sent: Counter[str] = Counter()
        self.ignored: Counter[str] = Counter()
        self.rebirths: Counter[str] = Counter()
        self._last_rebirth = -1.0  # monotonic time of the last NCMD rebirth
        self._rebirth_at: float | None = None  # a coalesced rebirth is due then
        self.dropped = 0
        self.discarded: Counter[str] = Counter()  # DATA messages dropped before the wire, by reason
        self.replayed = 0
        self.journaled = 0
        self.connects = 0

    # -- helpers ----------------------------------------------------------------------------
    def _advance_bdseq(self) -> None:
        """The current value went out in a CONNECT: the next CONNECT carries the next one."""
        self.bdseq = (self.bdseq + 1) % BDSEQ_MODULO

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) % SEQ_MODULO
        return self.seq

    def _new_token(self) -> int:
        self._token += 1
        return self._token

    @property
    def publishing(self) -> bool:
        return self.state is State.ONLINE

    @property
    def data_allowed(self) -> bool:
        """DATA may go out: online, and no rebirth requested and still due."""
        return self.state is State.ONLINE and self._rebirth_at is None

    def _with_sync(self, actions: list[Action]) -> list[Action]:
        """Append a :class:`Sync` covering the QoS 0 DATA handed out, unless one is awaited."""
        if self._unsynced and self._sync_token is None and self.publishing:
            self._sync_token = self._new_token()
            self._sync_covers, self._unsynced = self._unsynced, []
            actions.append(Sync(self._sync_token))
        return actions

    def _track(self, flight: _InFlight) -> int:
        """A token for a DATA message, remembered until confirmed, discarded or lost."""
        token = self._new_token()
        self._inflight[token] = flight
        if flight.qos == 0:
            self._unsynced.append(token)
        return token

    def _confirm(self, token: int) -> None:
        """The broker has the message: historical rows leave the journal."""
        flight = self._inflight.pop(token, None)
        if flight is not None and flight.historical:
            self.journal.delete(flight.ids)
            self._replay_ids.difference_update(flight.ids)

    def _journal(self, samples: list[Sample]) -> None:
        if not samples:
            return
        self.dropped += self.journal.append(samples)
        self.journaled += len(samples)

    def _schedule_reconnect(
        self, t: Instant, *, next_broker: bool, immediate: bool = False
    ) -> None:
        if next_broker:
            self.broker = (self.broker + 1) % self.settings.brokers
            self._host_ts = None  # STATE timestamps are compared per broker
        if immediate:
            delay = 0.0
        else:
            base = min(
                self.settings.reconnect_max_s, self.settings.reconnect_min_s * (2**self._attempt)
            )
            delay = base * (0.75 + 0.25 * self.rng.random())  # a fleet does not reconnect in step
            self._attempt = min(self._attempt + 1, 30)
        self._reconnect_at = t.mono + delay
        self._connect_deadline = None

    # -- connection -------------------------------------------------------------------------
    def _connect(self, t: Instant) -> list[Action]:
        self.state = State.CONNECTING
        self._reconnect_at = None
        self._connect_deadline = t.mono + CONNECT_TIMEOUT_S
        actions: list[Action] = []
        if self._saved_bdseq != self.bdseq:  # persisted before any CONNECT carries it
            self._saved_bdseq = self.bdseq
            actions.append(SaveBdSeq(self.bdseq))
        return actions + [
            Connect(
                self.broker,
                self.settings.client_id,
                self.model.node_topic("NDEATH"),
                codec.node_death(t.wall_ms, self.bdseq),
                self.bdseq,
            )
        ]

    def on_connack(self, t: Instant, ok: bool, reason: str = "") -> list[Action]:
        if self.state is not State.CONNECTING:
            return []
        if not ok:  # a refused CONNECT was a CONNECT all the same
            self.state = State.DISCONNECTED
            self._advance_bdseq()
            self._schedule_reconnect(t, next_broker=True)
            return []
        self.connects += 1
        self._connect_deadline = None
        actions: list[Action] = []
        topics = [self.model.node_topic("NCMD"), self.model.device_topic("DCMD", "+")]
        if self.settings.primary_host_id is not None:
            topics.append(f"spBv1.0/STATE/{self.settings.primary_host_id}")
        actions.append(Subscribe(tuple(topics)))
        if self.settings.primary_host_id is not None:
            self.state = State.WAITING_HOST
            if self.settings.brokers > 1:
                self._host_wait_until = t.mono + self.settings.primary_host_wait_s
            return actions
        self.rebirths["connect"] += 1
        return self._with_sync(actions + self._birth(t))

    def on_connection_lost(
        self, t: Instant, reason: str = "", *, connect_sent: bool = True
    ) -> list[Action]:
        """The connection dropped, or an attempt failed before CONNACK (``connect_sent``
        False: its TCP/TLS connection failed, so no CONNECT carried this bdSeq)."""
        if self.state in (State.DISCONNECTED, State.STOPPED):
            return []
        failed_attempt = self.state is State.CONNECTING
        self._drop_connection()
        if connect_sent or not failed_attempt:
            self._advance_bdseq()
        self.state = State.DISCONNECTED
        self._schedule_reconnect(t, next_broker=failed_attempt)
        return []

    def _drop_connection(self) -> None:
        """Unacknowledged live samples back to the journal; historical ones are still there."""
        lost: list[Sample] = []
        for token in sorted(self._inflight):
            flight = self._inflight[token]
            if not flight.historical:
                lost.extend(flight.samples)
        self._inflight.clear()
        self._unsynced.clear()
        self._sync_covers.clear()
        self._sync_token = None
        self._rebirth_at = None  # the new connection's births serve it
        self._replay_ids.clear()
        self._replay_cursor = 0
        self._replay_blocked = False
        self.birthed.clear()
        self._birth_pending.clear()
        self._host_wait_until = None
        self._journal(lost)

    def _leave(self, t: Instant, reason: str, *, immediate: bool = True) -> list[Action]:
        """Intentional disconnect: NDEATH first, then disconnect, then the next broker (at
        once, or after the reconnect delay: a walk in search of the primary host)."""
        actions: list[Action] = [self._ndeath(t)]
        self._drop_connection()
        self._advance_bdseq()
        self.state = State.DISCONNECTED
        self._schedule_reconnect(t, next_broker=True, immediate=immediate)
        actions.append(Disconnect(reason))
        return actions

    def _ndeath(self, t: Instant) -> Publish:
        self.sent["ndeath"] += 1
        death = codec.node_death(t.wall_ms, self.bdseq)
        return Publish(self.model.node_topic("NDEATH"), death, 1, kind="ndeath")

    def stop(self, t: Instant) -> list[Action]:
        """Gateway shutdown: NDEATH if connected, keep unacknowledged samples in the journal."""
        actions: list[Action] = []
        if self.state in (State.ONLINE, State.WAITING_HOST):
            actions.append(self._ndeath(t))
        pending = [s for samples in self._pending.values() for s in samples]
        self._pending.clear()
        self._drop_connection()  # unacknowledged samples first: they are the older ones
        self._journal(pending)
        self.state = State.STOPPED
        self._reconnect_at = None
        actions.append(Disconnect("gateway stopping"))
        return actions

    # -- births -----------------------------------------------------------------------------
    def _birth(self, t: Instant, *, replay: bool = True) -> list[Action]:
        """NBIRTH and a DBIRTH per online device, nothing else in between; then the replay
        starts (at once after a connect; at the next tick after a rebirth, once the adapter
        has reported the DATA it discarded)."""
        self.state = State.ONLINE
        self._rebirth_at = None
        self._host_wait_until = None
        self._attempt = 0  # a session reached: the reconnect delay starts over
        self.seq = 0
        actions: list[Action] = [
            Publish(
                self.model.node_topic("NBIRTH"),
                codec.node_birth(t.wall_ms, self.bdseq),
                kind="nbirth",
                seq=0,
            )
        ]
        self.sent["nbirth"] += 1
        self.birthed.clear()
        for dev in self.model.devices:
            if self.device_online[dev]:
                actions.append(self._device_birth(t, dev))
        self._birth_pending.clear()
        self._replay_cursor = 0
        self._replay_blocked = False
        if replay:
            actions.extend(self._replay(t))  # historical data goes beside live data from now on
        return actions

    def _device_birth(self, t: Instant, dev: str) -> Publish:
        metrics = [(m, self._current(m, t)) for m in self.model.devices[dev].metrics]
        for m, sample in metrics:
            self.published[m.channel_id] = sample
        self.birthed.add(dev)
        self.sent["dbirth"] += 1
        self._replay_cursor = 0  # its waiting journal rows can go now
        self._replay_blocked = False
        seq = self._next_seq()
        return Publish(
            self.model.device_topic("DBIRTH", dev),
            codec.device_birth(t.wall_ms, seq, metrics),
            kind="dbirth",
            seq=seq,
        )

    def _current(self, m: MetricDef, t: Instant) -> Sample:
        sample = self.current.get(m.channel_id)
        if sample is None:
            sample = Sample(m.channel_id, m.dtype.check(0), Quality.NOT_READ, t.wall_ms)
        return sample

    # -- data -------------------------------------------------------------------------------
    def on_change(self, sample: Sample) -> None:
        """A channel changed; published (or journaled) at the next :meth:`flush`."""
        m = self.model.by_channel.get(sample.channel_id)
        if m is None:
            return
        self.current[m.channel_id] = sample
        if m.deadband > 0 and self.publishing:
            last = self.published.get(m.channel_id)
            if (
                last is not None
                and last.quality is sample.quality
                and not isinstance(sample.value, bool | str)
                and not isinstance(last.value, str)
                and abs(float(sample.value) - float(last.value)) < m.deadband
            ):
                return
        self._pending.setdefault(m.device, []).append(sample)

    def on_device_health(self, dev: str, online: bool) -> None:
        """A back module went offline or came back (DDEATH / DBIRTH at the next flush)."""
        if dev not in self.device_online or self.device_online[dev] == online:
            return
        self.device_online[dev] = online
        if online:
            self._birth_pending.add(dev)
        else:
            self._birth_pending.discard(dev)

    def flush(self, t: Instant) -> list[Action]:
        actions: list[Action] = []
        if not self.data_allowed:  # no session, or a rebirth due: the journal keeps them
            if self.state is not State.STOPPED:
                self._journal([s for samples in self._pending.values() for s in samples])
            self._pending.clear()
            return actions
        for dev in self.model.devices:
            if dev in self.birthed and not self.device_online[dev]:
                self.birthed.discard(dev)
                self._pending.pop(dev, None)
                self.sent["ddeath"] += 1
                seq = self._next_seq()
                actions.append(
                    Publish(
                        self.model.device_topic("DDEATH", dev),
                        codec.device_death(t.wall_ms, seq),
                        kind="ddeath",
                        seq=seq,
                    )
                )
            elif dev in self._birth_pending and self.device_online[dev]:
                actions.append(self._device_birth(t, dev))
        self._birth_pending.clear()
        for dev, samples in self._pending.items():
            if dev not in self.birthed:
                continue  # offline device: its DBIRTH will carry the current values
            actions.append(self._data(t, dev, samples))
        self._pending.clear()
        actions.extend(self._replay(t))
        return self._with_sync(actions)

    def _data(self, t: Instant, dev: str, samples: list[Sample]) -> Publish:
        metrics = [(self.model.by_channel[s.channel_id], s) for s in samples]
        for _, s in metrics:
            self.published[s.channel_id] = s
        qos = self.settings.data_qos
        token = self._track(_InFlight(False, samples=list(samples), qos=qos))
        self.sent["ddata"] += 1
        seq = self._next_seq()
        return Publish(
            self.model.device_topic("DDATA", dev),
            codec.device_data(t.wall_ms, seq, metrics),
            qos,
            token=token,
            kind="ddata",
            seq=seq,
        )

    # -- replay -----------------------------------------------------------------------------
    def _replay_inflight(self) -> int:
        return sum(1 for f in self._inflight.values() if f.historical)

    def _replay(self, t: Instant) -> list[Action]:
        actions: list[Action] = []
        s = self.settings
        while (
            self.data_allowed
            and not self._replay_blocked
            and self.journal.count() > len(self._replay_ids)
            and self._replay_inflight() < s.replay_window
            and t.mono + 1e-9 >= self._replay_next_at
        ):
            batch = self._next_replay_batch()
            if batch is None:
                self._replay_blocked = True
                break
            dev, rows = batch
            ids = [row_id for row_id, _ in rows]
            qos = s.data_qos
            token = self._track(_InFlight(True, ids=ids, qos=qos))
            self._replay_ids.update(ids)
            metrics = [(self.model.by_channel[smp.channel_id], smp) for _, smp in rows]
            self.sent["ddata_historical"] += 1
            self.replayed += len(rows)
            seq = self._next_seq()
            actions.append(
                Publish(
                    self.model.device_topic("DDATA", dev),
                    codec.device_data(t.wall_ms, seq, metrics, historical=True),
                    qos,
                    token=token,
                    kind="ddata_historical",
                    seq=seq,
                )
            )
            step = 1.0 / s.replay_messages_per_s  # a burst of at most one second's worth
            self._replay_next_at = max(self._replay_next_at, t.mono - 1.0 + step) + step
        return actions

    def _next_replay_batch(self) -> tuple[str, list[tuple[int, Sample]]] | None:
        """The next rows of one birthed device, in journal order; rows of unknown channels are dropped."""
        limit = self.settings.replay_batch
        while True:
            rows = self.journal.read(self._replay_cursor, limit * 4)
            if not rows:
                return None
            unknown = []
            dev: str | None = None
            batch: list[tuple[int, Sample]] = []
            for row_id, sample in rows:
                if row_id in self._replay_ids:
                    continue
                m = self.model.by_channel.get(sample.channel_id)
                if m is None:
                    unknown.append(row_id)  # the topology no longer has this channel
                    continue
                if m.device not in self.birthed:
                    continue  # waits for the device's DBIRTH
                if dev is None:
                    dev = m.device
                if m.device != dev:
                    break
                batch.append((row_id, sample))
                if len(batch) >= limit:
                    break
            if unknown:
                self.journal.delete(unknown)
                self.dropped += len(unknown)
                self.ignored["journal_unknown_channel"] += len(unknown)
            if batch:
                # next search starts after the rows skipped before this batch's first
                self._replay_cursor = max(self._replay_cursor, batch[0][0] - 1)
                return dev or "", batch
            last = rows[-1][0]
            if last <= self._replay_cursor:
                return None
            self._replay_cursor = last

    def on_puback(self, t: Instant, token: int) -> list[Action]:
        """The PUBACK of a QoS 1 DATA message."""
        flight = self._inflight.get(token)
        if flight is None or flight.qos != 1:
            return []
        self._confirm(token)
        return self._with_sync(self._replay(t)) if flight.historical else []

    def on_synced(self, t: Instant, token: int) -> list[Action]:
        """The broker has read everything handed out before :class:`Sync` ``token``."""
        if token != self._sync_token:
            return []  # of a connection that is gone
        self._sync_token = None
        for covered in self._sync_covers:
            self._confirm(covered)
        self._sync_covers = []
        return self._with_sync(self._replay(t))

    def on_discarded(self, t: Instant, tokens: Iterable[int], reason: str = "rebirth") -> None:
        """The adapter dropped these DATA messages before they reached the MQTT client
        (:class:`DiscardQueuedData`, or its outbox over its bound: ``reason``): live samples
        go to the journal, historical rows back to the replay; both follow as historical
        data (from the next :meth:`tick`, which :meth:`next_deadline` asks for)."""
        lost: list[Sample] = []
        for token in sorted(tokens):
            flight = self._inflight.pop(token, None)
            if flight is None:
                continue
            self.discarded[reason] += 1
            if flight.historical:
                self._replay_ids.difference_update(flight.ids)
                self._replay_cursor = 0
                self._replay_blocked = False
            else:
                lost.extend(flight.samples)
        self._journal(lost)

    # -- incoming ---------------------------------------------------------------------------
    def on_message(self, t: Instant, topic: str, data: bytes) -> list[Action]:
        return self._with_sync(self._on_message(t, topic, data))

    def _on_message(self, t: Instant, topic: str, data: bytes) -> list[Action]:
        parts = topic.split("/")
        limit = MAX_STATE_BYTES if parts[1:2] == ["STATE"] else self.settings.max_command_bytes
        if len(data) > limit:  # every inbound payload, STATE too (it is retained: it comes back)
            self.ignored["oversized"] += 1
            return []
        if len(parts) == 3 and parts[:2] == ["spBv1.0", "STATE"]:
            return self._state(t, parts[2], data)
        if len(parts) == 4 and parts[2] == "NCMD" and parts[3] == self.model.edge_node_id:
            return self._ncmd(t, data)
        if len(parts) == 5 and parts[2] == "DCMD" and parts[3] == self.model.edge_node_id:
            return self._dcmd(t, parts[4], data)
        self.ignored["unexpected_topic"] += 1
        return []

    def _decode(self, data: bytes) -> list[codec.CommandMetric] | None:
        try:
            return codec.decode_command(data)
        except (codec.PayloadError, RecursionError):  # nesting beyond protobuf's own limit
            self.ignored["malformed"] += 1
            return None

    def _ncmd(self, t: Instant, data: bytes) -> list[Action]:
        metrics = self._decode(data)
        if metrics is None:
            return []
        actions: list[Action] = []
        for cmd in metrics:
            if cmd.name == REBIRTH:
                if cmd.field != "boolean_value":
                    self.ignored["bad_value"] += 1
                elif cmd.raw and self.publishing:
                    actions.extend(self._rebirth_request(t))
            elif cmd.name == NEXT_SERVER:
                if cmd.field != "boolean_value":
                    self.ignored["bad_value"] += 1
                elif cmd.raw and self.state in (State.ONLINE, State.WAITING_HOST):
                    return actions + self._leave(t, "NCMD Next Server")
            else:
                self.ignored["unknown_metric"] += 1
        return actions

    def _dcmd(self, t: Instant, dev: str, data: bytes) -> list[Action]:
        if dev not in self.model.devices:
            self.ignored["unknown_device"] += 1
            return []
        metrics = self._decode(data)
        if metrics is None:
            return []
        actions: list[Action] = []
        for cmd in metrics:
            m = None
            if cmd.alias is not None:
                m = self.model.by_alias.get(cmd.alias)
            elif cmd.name is not None:
                m = self.model.by_device_name.get((dev, cmd.name))
            if m is None or m.device != dev:
                self.ignored["unknown_metric"] += 1
                continue
            if not m.writable:
                self.ignored["not_writable"] += 1
                continue
            try:
                value = codec.command_value(cmd, m.dtype)
                m.dtype.check(value)
                if m.engineering is not None:  # a setpoint outside its range is refused here
                    m.engineering.check_output(value)
            except ValueError:
                self.ignored["bad_value"] += 1
                continue
            actions.append(Write(m.channel_id, value))
        return actions

    def _rebirth_request(self, t: Instant) -> list[Action]:
        """NCMD Rebirth: at once, unless one was done less than ``rebirth_min_interval_s``
        ago; then the requests in between are coalesced into one rebirth when it is over
        (a host, or a loop of hosts, asking in a burst costs one set of births)."""
        due = self._last_rebirth + self.settings.rebirth_min_interval_s
        discard: list[Action] = [DiscardQueuedData()]  # DATA of the old births: not sent
        if self._last_rebirth < 0 or t.mono >= due:
            self.rebirths["ncmd"] += 1
            self._last_rebirth = t.mono
            return discard + self._birth(t, replay=False)
        self.rebirths["coalesced"] += 1
        already_due = self._rebirth_at is not None
        self._rebirth_at = due  # no DATA until then: changes go to the journal
        return [] if already_due else discard

    def _state(self, t: Instant, host: str, data: bytes) -> list[Action]:
        if host != self.settings.primary_host_id:
            self.ignored["unexpected_topic"] += 1
            return []
        if json_depth(data) > MAX_STATE_DEPTH:  # json.loads would recurse into it
            self.ignored["bad_state"] += 1
            return []
        try:
            doc = json.loads(data)
            online, ts = doc["online"], doc["timestamp"]
            if not isinstance(online, bool) or not isinstance(ts, int) or isinstance(ts, bool):
                raise ValueError
        except (ValueError, KeyError, TypeError, UnicodeDecodeError, RecursionError):
            self.ignored["bad_state"] += 1
            return []
        if self._host_ts is not None and ts < self._host_ts:
            self.ignored["stale_state"] += 1  # an old will of a previous host session
            return []
        self._host_ts = ts
        if online and self.state is State.WAITING_HOST:
            self.rebirths["primary_host"] += 1
            return self._birth(t)
        if not online and self.state is State.ONLINE:
            return self._leave(t, f"primary host {host} offline")
        if not online and self.state is State.WAITING_HOST and self.settings.brokers > 1:
            return self._leave(t, f"primary host {host} offline here", immediate=False)
        return []

    # -- time -------------------------------------------------------------------------------
    def start(self, t: Instant) -> list[Action]:
        return self.tick(t)

    def tick(self, t: Instant) -> list[Action]:
        if self.state is State.DISCONNECTED and self._reconnect_at is not None:
            if t.mono >= self._reconnect_at:
                return self._connect(t)
            return []
        if (
            self.state is State.CONNECTING
            and self._connect_deadline is not None
            and t.mono >= self._connect_deadline
        ):
            self.state = State.DISCONNECTED
            self._advance_bdseq()  # the CONNECT may have reached the broker
            self._schedule_reconnect(t, next_broker=True)
            return [Disconnect("no CONNACK in time")]
        if (
            self.state is State.WAITING_HOST
            and self._host_wait_until is not None
            and t.mono >= self._host_wait_until
        ):
            wait = self.settings.primary_host_wait_s
            return self._leave(
                t, f"primary host not online here within {wait:g} s", immediate=False
            )
        actions: list[Action] = []
        if self._rebirth_at is not None and t.mono >= self._rebirth_at:
            self._rebirth_at = None
            if self.publishing:
                self.rebirths["ncmd"] += 1
                self._last_rebirth = t.mono
                actions += self._birth(t, replay=False)
        if self.publishing:
            return self._with_sync(actions + self._replay(t))
        return actions

    def next_deadline(self) -> float | None:
        if self.state is State.DISCONNECTED:
            return self._reconnect_at
        if self.state is State.CONNECTING:
            return self._connect_deadline
        if self.state is State.WAITING_HOST:
            return self._host_wait_until
        due: list[float] = []
        if self._rebirth_at is not None and self.publishing:
            due.append(self._rebirth_at)
        if (
            self.data_allowed
            and not self._replay_blocked
            and self.journal.count() > len(self._replay_ids)
            and self._replay_inflight() < self.settings.replay_window
        ):
            due.append(self._replay_next_at)
        return min(due, default=None)

    # -- status -----------------------------------------------------------------------------
    def status(self, wall_ms: int) -> dict[str, object]:
        oldest = self.journal.oldest_ts_ms()
        return {
            "state": self.state.value,
            "broker": self.broker,
            "bdseq": self.bdseq,
            "seq": self.seq,
            "connects": self.connects,
            "devices_online": sorted(self.birthed),
            "sent": dict(self.sent),
            "rebirths": dict(self.rebirths),
            "commands_ignored": dict(self.ignored),
            "backlog_messages": self.journal.count(),
            "backlog_oldest_age_s": None if oldest is None else max(0.0, (wall_ms - oldest) / 1000),
            "dropped_messages": self.dropped,
            "discarded_data_messages": dict(self.discarded),
            "replayed_samples": self.replayed,
            "journaled_samples": self.journaled,
            "inflight": len(self._inflight),
        }
