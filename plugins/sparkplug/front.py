"""The ``sparkplug`` front: a Sparkplug B edge node serving the process image over MQTT.

It runs beside a CANopen or DeviceNet front in the same topology. The protocol is in
:mod:`.session` (sans-I/O); this module feeds it the process image's changes, module
health and the clock, and carries out its actions: MQTT I/O through :mod:`.link`,
output writes, the persisted ``bdSeq`` (``<state_dir>/<front>.sparkplug.json``, written
atomically) and the store-and-forward journal (:mod:`.journal`).
"""

from __future__ import annotations

import asyncio
import contextlib
import fnmatch
import time
from typing import Any

from fieldgate.health import HealthEvent, ModuleHealth
from fieldgate.image import Change, Channel, Quality
from fieldgate.metric_samples import Sample as MetricSample
from fieldgate.persist import CorruptStore, read_json, write_json_atomic
from fieldgate.plugin import Front, GatewayContext, PluginStartError

from .actions import (
    Action,
    Connect,
    DiscardQueuedData,
    Disconnect,
    Instant,
    Publish,
    SaveBdSeq,
    State,
    Subscribe,
    Sync,
    Write,
)
from .config import SparkplugFrontConfig
from .journal import JournalError, SqliteJournal
from .link import Link, LinkEvents, LinkStats
from .metrics import Figures, metric_rows
from .model import NodeModel, Sample, Value
from .session import Session, SessionSettings

MAX_OUTBOX_DATA = 1000
CLOSE_TIMEOUT_S = 0.5  # stopping: how long the disconnect may take (docs/sparkplug.md)
"""DATA messages waiting for the MQTT client at once (a stalled socket): beyond, they are
dropped from the outbox, counted, and their samples go to the journal as history."""
MAX_QUEUED_WRITES = 256
"""DCMD write batches waiting for the process image at once; more are refused and counted."""


class SparkplugFront(Front):
    def __init__(self, config: SparkplugFrontConfig, context: GatewayContext):
        super().__init__(config, context)
        self.config: SparkplugFrontConfig = config
        self.session: Session | None = None
        self.model: NodeModel | None = None
        self.journal: SqliteJournal | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._link: Link | None = None
        self._closing: set[asyncio.Future[None]] = set()  # links closing (NDEATH, DISCONNECT)
        self._generation = 0
        self._link_stats = LinkStats()
        self._passwords: list[str | None] = []
        self._wake = asyncio.Event()
        self._flush_scheduled = False
        self._subscription: Any = None
        self._health_subscribed = False
        self._writes = 0
        self._write_errors = 0
        self._write_queue: asyncio.Queue[dict[str, Value]] = asyncio.Queue(MAX_QUEUED_WRITES)
        self._wall_offset = 0.0  # wall clock minus the image's clock, in seconds
        self._logged_state: State | None = None

    # -- paths and clock --------------------------------------------------------------------
    @property
    def bdseq_path(self) -> Any:
        return self.context.state_dir / f"{self.name}.sparkplug.json"

    @property
    def journal_path(self) -> Any:
        path = self.context.state_dir / (self.config.journal_file or f"{self.name}.journal.sqlite")
        return path

    def _now(self) -> Instant:
        return Instant(time.monotonic(), int(time.time() * 1000))

    def _load_bdseq(self) -> int | None:
        try:
            stored = read_json(self.bdseq_path)
        except CorruptStore as exc:
            self.log.warning("%s; bdSeq starts again at 0", exc)
            return None
        if isinstance(stored, dict) and isinstance(stored.get("bdseq"), int):
            return int(stored["bdseq"]) % 256
        return None

    # -- life cycle -------------------------------------------------------------------------
    async def start(self) -> None:
        cfg = self.config
        self._loop = asyncio.get_running_loop()
        self._wall_offset = time.time() - self.context.image.clock()
        self._passwords = []
        base_dir = self.context.topology.base_dir
        for broker in cfg.brokers:
            try:
                self._passwords.append(broker.password(base_dir))
            except ValueError as exc:
                raise PluginStartError(f"broker {broker.label}: {exc}") from None
            if broker.tls is None and not broker.is_loopback:
                self.log.warning(
                    "broker %s without TLS: credentials and data cross the network in clear",
                    broker.label,
                )
        channels = self.context.front_channels(cfg)
        edge = cfg.edge_node_id or self.context.topology.gateway.name
        self.model = NodeModel.from_channels(
            cfg.group_id, edge, channels, cfg.writable, cfg.deadband
        )
        for pattern in cfg.writable:
            if not any(
                m.writable and fnmatch.fnmatchcase(m.channel_id, pattern)
                for m in self.model.by_channel.values()
            ):
                self.log.warning(
                    "writable %r: no output this front serves (expose) matches it; DCMD cannot write it",
                    pattern,
                )
        try:
            self.journal = SqliteJournal(
                self.journal_path, cfg.journal_max_samples, cfg.journal_sync
            )
        except JournalError as exc:
            raise PluginStartError(str(exc)) from None
        online = {
            dev
            for (back, address), dev in self.model.module_device.items()
            if self._module_online(back, address)
        }
        now = self._now()
        self.session = Session(
            self.model,
            SessionSettings(
                brokers=len(cfg.brokers),
                client_id=cfg.client_id or f"fieldgate-{cfg.group_id}-{edge}",
                primary_host_id=cfg.primary_host_id,
                data_qos=cfg.data_qos,
                replay_messages_per_s=cfg.replay_messages_per_s,
                replay_batch=cfg.replay_batch,
                replay_window=cfg.replay_window,
                reconnect_min_s=cfg.reconnect_min_s,
                reconnect_max_s=cfg.reconnect_max_s,
                max_command_bytes=cfg.max_command_bytes,
                rebirth_min_interval_s=cfg.rebirth_min_interval_ms / 1000,
                primary_host_wait_s=cfg.primary_host_wait_s,
            ),
            self.journal,
            last_bdseq=self._load_bdseq(),
            current=[self._sample(c, now) for c in channels],
            online_devices=online,
        )
        self._subscription = self.context.image.subscribe_batch(
            self._on_changes, ids=[c.id for c in channels]
        )
        if not self._health_subscribed:
            self._health_subscribed = True
            self.context.health.subscribe(self._on_health)
        backlog = self.journal.count()
        self.log.info(
            "Sparkplug edge node %s/%s: %d device(s), %d metric(s), brokers %s%s",
            cfg.group_id,
            edge,
            len(self.model.devices),
            len(self.model.by_channel),
            ", ".join(b.label for b in cfg.brokers),
            f", {backlog} sample(s) waiting in the journal" if backlog else "",
        )

    def _module_online(self, back: str, address: int) -> bool:
        try:
            return self.context.health.get(back, address).online
        except KeyError:
            return True

    async def run(self) -> None:
        assert self.session is not None
        writer = asyncio.ensure_future(self._write_outputs())
        try:
            while True:
                self._execute(self.session.tick(self._now()))
                deadline = self.session.next_deadline()
                self._wake.clear()
                timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), timeout)
        finally:
            writer.cancel()

    async def _write_outputs(self) -> None:
        """DCMD writes, one batch (one DCMD) at a time, in arrival order, off the MQTT path:
        the process image applies each (in a front's child process: over its channel)."""
        while True:
            values = await self._write_queue.get()
            try:
                await self.context.set_outputs(values, origin=self.name)
                self._writes += len(values)
            except (KeyError, ValueError) as exc:
                self._write_errors += len(values)
                reason = exc.args[0] if exc.args else exc
                self.log.warning("DCMD write to %s refused: %s", ", ".join(values), reason)
            except Exception:  # the fieldbus side unreachable: this batch fails, the next tries
                self._write_errors += len(values)
                self.log.exception("DCMD write to %s failed", ", ".join(values))

    def _queue_writes(self, values: dict[str, Value]) -> None:
        try:
            self._write_queue.put_nowait(values)
        except asyncio.QueueFull:
            self._write_errors += len(values)
            self.log.warning(
                "DCMD write to %s refused: %d writes already waiting for the process image",
                ", ".join(values),
                MAX_QUEUED_WRITES,
            )

    async def stop(self) -> None:
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        if self.session is not None and self.session.state is not State.STOPPED:
            self._execute(self.session.stop(self._now()))
        self._drop_link()
        closing, self._closing = self._closing, set()
        if closing:  # the NDEATH and DISCONNECT handed over; a broker that does not take them:
            _, late = await asyncio.wait(closing, timeout=CLOSE_TIMEOUT_S)  # its will says it
            if late:
                self.log.warning(
                    "the broker did not take the disconnect within %.1f s; its will (NDEATH) "
                    "tells the host",
                    CLOSE_TIMEOUT_S,
                )
        if self.journal is not None:
            self.journal.close()
            self.journal = None

    # -- inputs ----------------------------------------------------------------------------
    def _sample(self, channel: Channel | Change, now: Instant) -> Sample:
        """A value at its acquisition time (a channel's current one, or the one a change
        carries): the image's clock plus a fixed offset taken at start, so that two samples
        are never swapped by a pause between reading two clocks (a busy host). A quality
        change is stamped when it happened."""
        if channel.quality is Quality.GOOD and channel.timestamp is not None:
            ts = int((channel.timestamp + self._wall_offset) * 1000)
        else:
            ts = int((self.context.image.clock() + self._wall_offset) * 1000)
        return Sample(channel.id, channel.value, channel.quality, ts)

    def _on_changes(self, changes: list[Change]) -> None:
        """One process-image batch (a poll reply): every changed channel, its own value and time."""
        if self.session is None:
            return
        now = self._now()
        for change in changes:
            self.session.on_change(self._sample(change, now))
        self._schedule_flush()

    def _on_health(self, health: ModuleHealth, event: HealthEvent) -> None:
        if self.session is None or self.model is None:
            return
        dev = self.model.module_device.get(health.key)
        if dev is None or event not in (HealthEvent.ONLINE, HealthEvent.OFFLINE):
            return
        self.session.on_device_health(dev, event is HealthEvent.ONLINE)
        self._schedule_flush()

    def _schedule_flush(self) -> None:
        if not self._flush_scheduled and self._loop is not None:
            self._flush_scheduled = True
            self._loop.call_soon(self._flush)

    def _flush(self) -> None:
        self._flush_scheduled = False
        if self.session is not None:
            self._execute(self.session.flush(self._now()))

    # link events (on the loop), each for one connection generation
    def _connack(self, generation: int, ok: bool, reason: str) -> None:
        if generation == self._generation and self.session is not None:
            if not ok:
                self.log.warning("broker refused the connection: %s", reason)
            self._execute(self.session.on_connack(self._now(), ok, reason))

    def _lost(self, generation: int, reason: str, connect_sent: bool = True) -> None:
        if generation != self._generation or self.session is None:
            return
        if self.session.state is State.ONLINE:
            self.log.warning("connection to the broker lost: %s", reason)
        self._drop_link()
        self._execute(
            self.session.on_connection_lost(self._now(), reason, connect_sent=connect_sent)
        )

    def _puback(self, generation: int, token: int) -> None:
        if generation == self._generation and self.session is not None:
            self._execute(self.session.on_puback(self._now(), token))

    def _synced(self, generation: int, token: int) -> None:
        if generation == self._generation and self.session is not None:
            self._execute(self.session.on_synced(self._now(), token))

    def _message(self, generation: int, topic: str, payload: bytes) -> None:
        if generation == self._generation and self.session is not None:
            self._execute(self.session.on_message(self._now(), topic, payload))

    # -- outputs ---------------------------------------------------------------------------
    def _execute(self, actions: list[Action]) -> None:
        writes: dict[str, Value] = {}
        for action in actions:
            if isinstance(action, Publish):
                if self._link is None:  # the connection is gone; its loss reaches the session
                    self._link_stats.dropped["not_connected"] += 1
                    continue
                self._link.publish(action)
                if self._link.queued_data > MAX_OUTBOX_DATA:  # a socket that stopped taking
                    assert self.session is not None
                    tokens = self._link.discard_data("outbox_full")
                    self.session.on_discarded(self._now(), tokens, "outbox_full")
            elif isinstance(action, Sync):
                if self._link is not None:
                    self._link.sync(action.token)
            elif isinstance(action, DiscardQueuedData):
                assert self.session is not None
                tokens = self._link.discard_data() if self._link is not None else []
                self.session.on_discarded(self._now(), tokens)
            elif isinstance(action, Write):
                writes[action.channel_id] = action.value
            elif isinstance(action, SaveBdSeq):
                try:
                    write_json_atomic(self.bdseq_path, {"bdseq": action.bdseq})
                except OSError as exc:
                    self.log.error("cannot persist bdSeq to %s: %s", self.bdseq_path, exc)
            elif isinstance(action, Subscribe):
                if self._link is not None:
                    self._link.subscribe(action.topics)
            elif isinstance(action, Connect):
                self._open(action)
            elif isinstance(action, Disconnect):
                self.log.info("disconnecting: %s", action.reason)
                self._drop_link()
        if writes:  # one DCMD's metrics: one batch, applied whole or refused whole
            self._queue_writes(writes)
        self._log_state()
        self._wake.set()

    def _log_state(self) -> None:
        if self.session is None or self.session.state is self._logged_state:
            return
        state, self._logged_state = self.session.state, self.session.state
        broker = self.config.brokers[self.session.broker].label
        if state is State.ONLINE:
            backlog = self.session.journal.count()
            self.log.info(
                "online on %s, bdSeq %d%s",
                broker,
                self.session.bdseq,
                f", replaying {backlog} journaled sample(s)" if backlog else "",
            )
        elif state is State.WAITING_HOST:
            self.log.info(
                "connected to %s, waiting for primary host %s to be online",
                broker,
                self.config.primary_host_id,
            )

    def _drop_link(self) -> None:
        link, self._link = self._link, None
        self._generation += 1
        if link is not None:
            link.closed = True
            closing = asyncio.ensure_future(link.close())
            self._closing.add(closing)
            closing.add_done_callback(self._closing.discard)

    def _open(self, action: Connect) -> None:
        assert self._loop is not None
        self._drop_link()
        generation = self._generation
        broker = self.config.brokers[action.broker]
        events = LinkEvents(self._connack, self._lost, self._puback, self._message, self._synced)
        link = Link(
            self._loop,
            events,
            generation,
            broker,
            self._passwords[action.broker],
            action.client_id,
            self.config.keepalive_s,
            self._link_stats,
        )
        self._link = link

        async def connect() -> None:
            try:
                await link.open(action.will_topic, action.will_payload)
            except Exception as exc:  # refused, unreachable, TLS failure: next attempt
                self.log.debug("connect to %s failed: %s", broker.label, exc)
                self._lost(generation, f"{type(exc).__name__}: {exc}", connect_sent=False)

        asyncio.ensure_future(connect())

    # -- observability ---------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        if self.session is None:
            return {}
        out = self.session.status(int(time.time() * 1000))
        broker = self.config.brokers[self.session.broker]
        out.update(
            broker_url=broker.label,
            group_id=self.config.group_id,
            edge_node_id=self.model.edge_node_id if self.model else None,
            writes=self._writes,
            write_errors=self._write_errors,
            published=dict(self._link_stats.published),
            publish_dropped=dict(self._link_stats.dropped),
            outbox=self._link.queued if self._link is not None else 0,
        )
        return out

    def metrics(self) -> list[MetricSample]:
        """Metric rows for the gateway's Prometheus endpoint (name without ``fieldgate_``)."""
        if self.session is None:
            return []
        oldest = self.session.journal.oldest_ts_ms()
        age = 0.0 if oldest is None else max(0.0, (time.time() * 1000 - oldest) / 1000)
        figures = Figures(
            self.session,
            age,
            self._link.queued if self._link is not None else 0,
            self._writes,
            self._write_errors,
            self._link_stats.published,
            self._link_stats.dropped,
        )
        return metric_rows(self.name, figures)
