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

import random
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

from . import commands
from . import payload as codec
from .actions import Action, Connect, DiscardQueuedData, Disconnect, Instant, Publish, SaveBdSeq
from .actions import State as State  # (the session's callers import its inputs and actions here)
from .actions import Subscribe as Subscribe
from .actions import Sync as Sync
from .actions import Write as Write
from .commands import json_depth as json_depth
from .journal import Journal
from .model import NEXT_SERVER, REBIRTH, NodeModel, Sample
from .publisher import Publisher
from .replay import Replay

CONNECT_TIMEOUT_S = 10.0
BDSEQ_MODULO = 256


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


def reconnect_delay(settings: SessionSettings, attempt: int, rng: random.Random) -> float:
    """Doubling from ``reconnect_min_s`` up to ``reconnect_max_s``, less up to a quarter at
    random: a fleet does not reconnect in step."""
    base = min(settings.reconnect_max_s, settings.reconnect_min_s * 2.0**attempt)
    return base * (0.75 + 0.25 * rng.random())


class Session:
    """The connection, the primary host and the commands; what goes out while publishing
    is :class:`~.publisher.Publisher`'s (``self.data``)."""

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
        self._attempt = 0
        self._reconnect_at: float | None = 0.0
        self._connect_deadline: float | None = None
        self._host_ts: int | None = None  # timestamp of the last accepted STATE
        self._host_wait_until: float | None = None  # waiting for the host: next broker then
        # counters
        self.sent: Counter[str] = Counter()
        self.ignored: Counter[str] = Counter()
        self.rebirths: Counter[str] = Counter()
        self._last_rebirth = -1.0  # monotonic time of the last NCMD rebirth
        self._rebirth_at: float | None = None  # a coalesced rebirth is due then
        self.connects = 0
        replay = Replay(
            model,
            journal,
            batch=settings.replay_batch,
            window=settings.replay_window,
            messages_per_s=settings.replay_messages_per_s,
            on_unknown=lambda n: self.data.unknown_rows(n),
        )
        self.data = Publisher(
            model,
            journal,
            replay,
            data_qos=settings.data_qos,
            sent=self.sent,
            ignored=self.ignored,
            current=current,
            online_devices=online_devices,
        )

    @property
    def dropped(self) -> int:
        """Samples dropped from the journal (full, or their channel gone)."""
        return self.data.dropped

    @property
    def replayed(self) -> int:
        """Journaled samples sent as historical DDATA."""
        return self.data.replayed

    # -- helpers ----------------------------------------------------------------------------
    def _advance_bdseq(self) -> None:
        """The current value went out in a CONNECT: the next CONNECT carries the next one."""
        self.bdseq = (self.bdseq + 1) % BDSEQ_MODULO

    @property
    def publishing(self) -> bool:
        return self.state is State.ONLINE

    @property
    def data_allowed(self) -> bool:
        """DATA may go out: online, and no rebirth requested and still due."""
        return self.state is State.ONLINE and self._rebirth_at is None

    def _with_sync(self, actions: list[Action]) -> list[Action]:
        """Append a :class:`Sync` covering the QoS 0 DATA handed out, unless one is awaited."""
        if self.publishing:
            sync = self.data.delivery.sync()
            if sync is not None:
                actions.append(sync)
        return actions

    def _replay(self, t: Instant) -> list[Action]:
        return self.data.replay_step(t) if self.data_allowed else []

    def _schedule_reconnect(
        self, t: Instant, *, next_broker: bool, immediate: bool = False
    ) -> None:
        if next_broker:
            self.broker = (self.broker + 1) % self.settings.brokers
            self._host_ts = None  # STATE timestamps are compared per broker
        delay = 0.0 if immediate else reconnect_delay(self.settings, self._attempt, self.rng)
        if not immediate:
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
        self._rebirth_at = None  # the new connection's births serve it
        self._host_wait_until = None
        self.data.connection_dropped()

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
        pending = self.data.stopping()
        self._drop_connection()  # unacknowledged samples first: they are the older ones
        self.data.journal_samples(pending)
        self.state = State.STOPPED
        self._reconnect_at = None
        actions.append(Disconnect("gateway stopping"))
        return actions

    def _birth(self, t: Instant, *, replay: bool = True) -> list[Action]:
        """NBIRTH and a DBIRTH per online device, nothing else in between; then the replay
        starts (at once after a connect; at the next tick after a rebirth, once the adapter
        has reported the DATA it discarded)."""
        self.state = State.ONLINE
        self._rebirth_at = None
        self._host_wait_until = None
        self._attempt = 0  # a session reached: the reconnect delay starts over
        return self.data.births(t, self.bdseq, replay=replay)

    # -- data -------------------------------------------------------------------------------
    def on_change(self, sample: Sample) -> None:
        """A channel changed; published (or journaled) at the next :meth:`flush`."""
        self.data.on_change(sample, self.publishing)

    def on_device_health(self, dev: str, online: bool) -> None:
        """A back module went offline or came back (DDEATH / DBIRTH at the next flush)."""
        self.data.on_device_health(dev, online)

    def flush(self, t: Instant) -> list[Action]:
        if not self.data_allowed:  # no session, or a rebirth due: the journal keeps them
            self.data.hold(stopped=self.state is State.STOPPED)
            return []
        return self._with_sync(self.data.flush(t))

    def on_puback(self, t: Instant, token: int) -> list[Action]:
        """The PUBACK of a QoS 1 DATA message."""
        historical = self.data.on_puback(token)
        return self._with_sync(self._replay(t)) if historical else []

    def on_synced(self, t: Instant, token: int) -> list[Action]:
        """The broker has read everything handed out before :class:`Sync` ``token``."""
        if not self.data.on_synced(token):
            return []  # of a connection that is gone
        return self._with_sync(self._replay(t))

    def on_discarded(self, t: Instant, tokens: Iterable[int], reason: str = "rebirth") -> None:
        """The adapter dropped these DATA messages before they reached the MQTT client
        (:class:`DiscardQueuedData`, or its outbox over its bound: ``reason``): live samples
        go to the journal, historical rows back to the replay; both follow as historical
        data (from the next :meth:`tick`, which :meth:`next_deadline` asks for)."""
        self.data.on_discarded(tokens, reason)

    # -- incoming ---------------------------------------------------------------------------
    def on_message(self, t: Instant, topic: str, data: bytes) -> list[Action]:
        return self._with_sync(self._on_message(t, topic, data))

    def _on_message(self, t: Instant, topic: str, data: bytes) -> list[Action]:
        parts = topic.split("/")
        if commands.oversized(parts, data, self.settings.max_command_bytes):
            self.ignored["oversized"] += 1
            return []
        if len(parts) == 3 and parts[:2] == ["spBv1.0", "STATE"]:
            return self._state(t, parts[2], data)
        if len(parts) == 4 and parts[2] == "NCMD" and parts[3] == self.model.edge_node_id:
            return self._ncmd(t, data)
        if len(parts) == 5 and parts[2] == "DCMD" and parts[3] == self.model.edge_node_id:
            return self._dcmd(parts[4], data)
        self.ignored["unexpected_topic"] += 1
        return []

    def _ncmd(self, t: Instant, data: bytes) -> list[Action]:
        metrics = commands.decode(data, self.ignored)
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

    def _dcmd(self, dev: str, data: bytes) -> list[Action]:
        if dev not in self.model.devices:
            self.ignored["unknown_device"] += 1
            return []
        metrics = commands.decode(data, self.ignored)
        if metrics is None:
            return []
        return list(commands.device_writes(self.model, dev, metrics, self.ignored))

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
        state = commands.parse_state(data, self.ignored)
        if state is None:
            return []
        online, ts = state
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
        if self.data_allowed and self.data.replay_waiting():
            due.append(self.data.replay.next_at)
        return min(due, default=None)

    # -- status -----------------------------------------------------------------------------
    def status(self, wall_ms: int) -> dict[str, object]:
        oldest = self.journal.oldest_ts_ms()
        data = self.data
        return {
            "state": self.state.value,
            "broker": self.broker,
            "bdseq": self.bdseq,
            "seq": data.seq,
            "connects": self.connects,
            "devices_online": sorted(data.birthed),
            "sent": dict(self.sent),
            "rebirths": dict(self.rebirths),
            "commands_ignored": dict(self.ignored),
            "backlog_messages": self.journal.count(),
            "backlog_oldest_age_s": None if oldest is None else max(0.0, (wall_ms - oldest) / 1000),
            "dropped_messages": data.dropped,
            "discarded_data_messages": dict(data.discarded),
            "replayed_samples": data.replayed,
            "journaled_samples": data.journaled,
            "inflight": len(data.delivery.inflight),
        }
