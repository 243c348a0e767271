"""What an edge node publishes while its session is up: NBIRTH and the devices' births
and deaths, DATA of their changes (deadbands applied), and the store-and-forward journal
replayed beside live data; ``seq`` counts them all.

The session (:mod:`.session`) decides *when*: it calls :meth:`Publisher.births` once a
connection (and the primary host) allows, :meth:`flush` only while DATA may go out, and
tells it of acknowledgements and of a lost connection. Unconfirmed DATA is
:mod:`.delivery`'s; the replay's pacing :mod:`.replay`'s.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable

from fieldgate.image import Quality

from . import payload as codec
from .actions import Action, Instant, Publish
from .delivery import Delivery, InFlight
from .journal import Journal
from .model import MetricDef, NodeModel, Sample
from .replay import Replay

SEQ_MODULO = 256


class Publisher:
    def __init__(
        self,
        model: NodeModel,
        journal: Journal,
        replay: Replay,
        *,
        data_qos: int,
        sent: Counter[str],
        ignored: Counter[str],
        current: Iterable[Sample] = (),
        online_devices: Iterable[str] | None = None,
    ):
        self.model = model
        self.journal = journal
        self.replay = replay
        self.data_qos = data_qos
        self.sent = sent  # the session's counters: messages by kind, inputs ignored by reason
        self.ignored = ignored
        self.delivery = Delivery()
        self.seq = 0
        self.current: dict[str, Sample] = {s.channel_id: s for s in current}
        self.published: dict[str, Sample] = {}  # last value sent live, for deadbands
        online = set(model.devices) if online_devices is None else set(online_devices)
        self.device_online: dict[str, bool] = {d: d in online for d in model.devices}
        self.birthed: set[str] = set()
        self._birth_pending: set[str] = set()
        self._pending: dict[str, list[Sample]] = {}
        self.dropped = 0
        self.discarded: Counter[str] = Counter()  # DATA messages dropped before the wire, by reason
        self.replayed = 0
        self.journaled = 0

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) % SEQ_MODULO
        return self.seq

    def unknown_rows(self, n: int) -> None:
        """The replay deleted ``n`` journal rows of channels the topology no longer has."""
        self.dropped += n
        self.ignored["journal_unknown_channel"] += n

    def journal_samples(self, samples: list[Sample]) -> None:
        if not samples:
            return
        self.dropped += self.journal.append(samples)
        self.journaled += len(samples)

    # -- births -----------------------------------------------------------------------------
    def births(self, t: Instant, bdseq: int, *, replay: bool) -> list[Action]:
        """NBIRTH and a DBIRTH per online device, nothing else in between; then the replay
        (``replay``: at once; else from the next tick)."""
        self.seq = 0
        actions: list[Action] = [
            Publish(
                self.model.node_topic("NBIRTH"),
                codec.node_birth(t.wall_ms, bdseq),
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
        self.replay.restart()
        if replay:
            actions.extend(self.replay_step(t))  # historical data beside live data from now on
        return actions

    def _device_birth(self, t: Instant, dev: str) -> Publish:
        metrics = [(m, self._current(m, t)) for m in self.model.devices[dev].metrics]
        for m, sample in metrics:
            self.published[m.channel_id] = sample
        self.birthed.add(dev)
        self.sent["dbirth"] += 1
        self.replay.restart()  # its waiting journal rows can go now
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

    # -- live data --------------------------------------------------------------------------
    def on_change(self, sample: Sample, publishing: bool) -> None:
        m = self.model.by_channel.get(sample.channel_id)
        if m is None:
            return
        self.current[m.channel_id] = sample
        if m.deadband > 0 and publishing:
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
        if dev not in self.device_online or self.device_online[dev] == online:
            return
        self.device_online[dev] = online
        if online:
            self._birth_pending.add(dev)
        else:
            self._birth_pending.discard(dev)

    def hold(self, *, stopped: bool) -> None:
        """DATA may not go out: the waiting samples go to the journal (none once stopped)."""
        if not stopped:
            self.journal_samples([s for samples in self._pending.values() for s in samples])
        self._pending.clear()

    def flush(self, t: Instant) -> list[Action]:
        """DDEATH / DBIRTH of devices whose health changed, then DDATA of the waiting
        samples of birthed devices, then the replay's next messages."""
        actions: list[Action] = []
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
        actions.extend(self.replay_step(t))
        return actions

    def _data(self, t: Instant, dev: str, samples: list[Sample]) -> Publish:
        metrics = [(self.model.by_channel[s.channel_id], s) for s in samples]
        for _, s in metrics:
            self.published[s.channel_id] = s
        qos = self.data_qos
        token = self.delivery.track(InFlight(False, samples=list(samples), qos=qos))
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
    def replay_waiting(self) -> bool:
        return self.replay.waiting(self.delivery.historical())

    def replay_step(self, t: Instant) -> list[Action]:
        """The replay's messages due at ``t`` (the caller checked that DATA may go out)."""
        actions: list[Action] = []
        while self.replay_waiting() and t.mono + 1e-9 >= self.replay.next_at:
            batch = self.replay.take(self.birthed)
            if batch is None:
                break
            dev, rows = batch
            qos = self.data_qos
            token = self.delivery.track(InFlight(True, ids=[i for i, _ in rows], qos=qos))
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
            self.replay.paced(t.mono)
        return actions

    # -- confirmations ----------------------------------------------------------------------
    def confirm(self, token: int) -> None:
        """The broker has the message: historical rows leave the journal."""
        flight = self.delivery.pop(token)
        if flight is not None and flight.historical:
            self.journal.delete(flight.ids)
            self.replay.forget(flight.ids)

    def on_puback(self, token: int) -> bool | None:
        """A QoS 1 DATA message confirmed: whether it was historical (None: not one of ours)."""
        flight = self.delivery.inflight.get(token)
        if flight is None or flight.qos != 1:
            return None
        self.confirm(token)
        return flight.historical

    def on_synced(self, token: int) -> bool:
        """The broker read what came before Sync ``token``: False for a stale one."""
        covered = self.delivery.synced(token)
        if covered is None:
            return False
        for each in covered:
            self.confirm(each)
        return True

    def on_discarded(self, tokens: Iterable[int], reason: str) -> None:
        lost: list[Sample] = []
        for token in sorted(tokens):
            flight = self.delivery.pop(token)
            if flight is None:
                continue
            self.discarded[reason] += 1
            if flight.historical:
                self.replay.forget(flight.ids)
                self.replay.restart()
            else:
                lost.extend(flight.samples)
        self.journal_samples(lost)

    def connection_dropped(self) -> None:
        """Unacknowledged live samples back to the journal; historical ones are still there."""
        lost = self.delivery.drop_all()
        self.replay.clear()
        self.birthed.clear()
        self._birth_pending.clear()
        self.journal_samples(lost)

    def stopping(self) -> list[Sample]:
        """The samples waiting for the next flush (the session journals them last)."""
        pending = [s for samples in self._pending.values() for s in samples]
        self._pending.clear()
        return pending
