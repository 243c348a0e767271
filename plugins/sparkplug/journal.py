"""The store-and-forward journal: samples waiting for a broker's acknowledgement, on disk.

Rows are samples in the order they were stored (an increasing id), so a replay in id order
is a replay in acquisition order per channel. A row is deleted only when the message that
carried it was acknowledged (PUBACK). A full journal deletes its oldest rows to make room
and counts them.

:class:`SqliteJournal` is the real one: SQLite in WAL mode, one transaction per append or
delete. ``sync="normal"`` (SQLite ``synchronous=NORMAL``) writes every commit to the WAL
file before returning, so a committed row survives a crash of the process (``kill -9``)
but a power cut may lose the commits since the last checkpoint; ``sync="full"`` fsyncs
every commit (survives a power cut, costs one fsync per flush: one per event-loop turn
with changes while the broker is away). :class:`MemoryJournal` has the same behaviour
without a disk (tests of the session).
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Protocol

from fieldgate.image import Quality

from .model import Sample


class Journal(Protocol):
    max_samples: int

    def append(self, samples: Sequence[Sample]) -> int:
        """Store samples after every existing row; returns how many oldest rows were dropped."""

    def read(self, after_id: int, limit: int) -> list[tuple[int, Sample]]:
        """Up to ``limit`` rows with id > ``after_id``, in id order."""

    def delete(self, ids: Iterable[int]) -> None: ...

    def count(self) -> int: ...

    def oldest_ts_ms(self) -> int | None: ...

    def close(self) -> None: ...


class MemoryJournal:
    def __init__(self, max_samples: int = 1_000_000):
        self.max_samples = max_samples
        self._rows: dict[int, Sample] = {}
        self._next = 1

    def append(self, samples: Sequence[Sample]) -> int:
        for sample in samples:
            self._rows[self._next] = sample
            self._next += 1
        excess = max(0, len(self._rows) - self.max_samples)
        for key in sorted(self._rows)[:excess]:
            del self._rows[key]
        return excess

    def read(self, after_id: int, limit: int) -> list[tuple[int, Sample]]:
        keys = sorted(k for k in self._rows if k > after_id)[:limit]
        return [(k, self._rows[k]) for k in keys]

    def delete(self, ids: Iterable[int]) -> None:
        for key in ids:
            self._rows.pop(key, None)

    def count(self) -> int:
        return len(self._rows)

    def oldest_ts_ms(self) -> int | None:
        return self._rows[min(self._rows)].ts_ms if self._rows else None

    def close(self) -> None:
        pass


class JournalError(Exception):
    """The journal file cannot be opened or used (one-line cause)."""


class SqliteJournal:
    def __init__(self, path: Path, max_samples: int = 1_000_000, sync: str = "normal"):
        self.path = path
        self.max_samples = max_samples
        self._closed = False
        self._oldest_at_close: int | None = None
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._db = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute(f"PRAGMA synchronous={'FULL' if sync == 'full' else 'NORMAL'}")
            self._db.execute(
                "CREATE TABLE IF NOT EXISTS samples (id INTEGER PRIMARY KEY AUTOINCREMENT,"
                " channel TEXT NOT NULL, value TEXT NOT NULL, quality TEXT NOT NULL,"
                " ts_ms INTEGER NOT NULL)"
            )
            self._count: int = int(self._db.execute("SELECT COUNT(*) FROM samples").fetchone()[0])
        except sqlite3.Error as exc:
            raise JournalError(f"journal {path}: {exc}") from None

    def append(self, samples: Sequence[Sample]) -> int:
        if not samples:
            return 0
        rows = [(s.channel_id, json.dumps(s.value), s.quality.value, s.ts_ms) for s in samples]
        dropped = max(0, self._count + len(rows) - self.max_samples)
        with self._transaction():
            self._db.executemany(
                "INSERT INTO samples (channel, value, quality, ts_ms) VALUES (?, ?, ?, ?)", rows
            )
            if dropped:
                self._db.execute(
                    "DELETE FROM samples WHERE id IN (SELECT id FROM samples ORDER BY id LIMIT ?)",
                    (dropped,),
                )
        self._count += len(rows) - dropped
        return dropped

    def read(self, after_id: int, limit: int) -> list[tuple[int, Sample]]:
        rows = self._db.execute(
            "SELECT id, channel, value, quality, ts_ms FROM samples WHERE id > ? ORDER BY id LIMIT ?",
            (after_id, limit),
        ).fetchall()
        out = []
        for row_id, channel, value, quality, ts_ms in rows:
            try:
                sample = Sample(channel, json.loads(value), Quality(quality), ts_ms)
            except ValueError:
                sample = Sample(
                    channel, 0, Quality.CONFIG_ERROR, ts_ms
                )  # unreadable row: sent as BAD
            out.append((row_id, sample))
        return out

    def delete(self, ids: Iterable[int]) -> None:
        keys = [(i,) for i in ids]
        if not keys:
            return
        with self._transaction():
            before = self._db.total_changes
            self._db.executemany("DELETE FROM samples WHERE id = ?", keys)
            self._count -= self._db.total_changes - before

    def count(self) -> int:
        return int(self._count)

    def oldest_ts_ms(self) -> int | None:
        if self._closed:
            return self._oldest_at_close
        row = self._db.execute("SELECT ts_ms FROM samples ORDER BY id LIMIT 1").fetchone()
        return None if row is None else int(row[0])

    def close(self) -> None:
        """Close the file; count and oldest age stay readable (a stopped front's status)."""
        if not self._closed:
            self._oldest_at_close = self.oldest_ts_ms()
            self._closed = True
            self._db.close()

    def _transaction(self) -> _Tx:
        return _Tx(self._db)


class _Tx:
    def __init__(self, db: sqlite3.Connection):
        self.db = db

    def __enter__(self) -> None:
        self.db.execute("BEGIN IMMEDIATE")

    def __exit__(self, exc_type: object, *rest: object) -> None:
        self.db.execute("COMMIT" if exc_type is None else "ROLLBACK")
