"""The store-and-forward replay: journaled samples sent as historical DDATA, in journal
order, one birthed device per message, at most ``replay_messages_per_s`` messages per
second and ``replay_window`` unconfirmed at once. Rows of a device that is offline wait
for its DBIRTH; rows of channels the topology no longer has are dropped."""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable

from .journal import Journal
from .model import NodeModel, Sample

Batch = tuple[str, list[tuple[int, Sample]]]  # a device, its (row id, sample)s


class Replay:
    def __init__(
        self,
        model: NodeModel,
        journal: Journal,
        *,
        batch: int,
        window: int,
        messages_per_s: float,
        on_unknown: Callable[[int], None],
    ):
        self.model = model
        self.journal = journal
        self.batch = batch
        self.window = window
        self.messages_per_s = messages_per_s
        self.on_unknown = on_unknown  # rows of unknown channels deleted: how many
        self.cursor = 0
        self.next_at = 0.0
        self.ids: set[int] = set()  # rows in messages not yet confirmed
        self.blocked = False  # every waiting row belongs to an offline device

    def restart(self) -> None:
        """Search the journal from its start again (a device was born, rows came back)."""
        self.cursor = 0
        self.blocked = False

    def clear(self) -> None:
        """The connection is gone: its messages' rows are waiting again."""
        self.ids.clear()
        self.restart()

    def forget(self, ids: Iterable[int]) -> None:
        self.ids.difference_update(ids)

    def waiting(self, inflight: int) -> bool:
        """Rows wait and the window has room (``inflight``: replayed messages unconfirmed)."""
        return not self.blocked and self.journal.count() > len(self.ids) and inflight < self.window

    def take(self, birthed: Collection[str]) -> Batch | None:
        """The next batch, its rows in flight from now on; None (and blocked) when every
        waiting row belongs to a device not birthed."""
        batch = self._next_batch(birthed)
        if batch is None:
            self.blocked = True
            return None
        self.ids.update(row_id for row_id, _ in batch[1])
        return batch

    def paced(self, mono: float) -> None:
        """One message went out at ``mono``: a burst of at most one second's worth."""
        step = 1.0 / self.messages_per_s
        self.next_at = max(self.next_at, mono - 1.0 + step) + step

    def _next_batch(self, birthed: Collection[str]) -> Batch | None:
        """The next rows of one birthed device, in journal order; rows of unknown channels are dropped."""
        limit = self.batch
        while True:
            rows = self.journal.read(self.cursor, limit * 4)
            if not rows:
                return None
            unknown = []
            dev: str | None = None
            batch: list[tuple[int, Sample]] = []
            for row_id, sample in rows:
                if row_id in self.ids:
                    continue
                m = self.model.by_channel.get(sample.channel_id)
                if m is None:
                    unknown.append(row_id)  # the topology no longer has this channel
                    continue
                if m.device not in birthed:
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
                self.on_unknown(len(unknown))
            if batch:
                # next search starts after the rows skipped before this batch's first
                self.cursor = max(self.cursor, batch[0][0] - 1)
                return dev or "", batch
            last = rows[-1][0]
            if last <= self.cursor:
                return None
            self.cursor = last
