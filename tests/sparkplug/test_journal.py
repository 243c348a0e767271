"""Both journals behave alike; the SQLite one keeps its rows across a reopen (a restart)."""

from __future__ import annotations

import pytest

from fieldgate.image import Quality
from fieldgate.plugins.sparkplug.journal import JournalError, MemoryJournal, SqliteJournal
from fieldgate.plugins.sparkplug.model import Sample


@pytest.fixture(params=["memory", "sqlite"])
def journal(request, tmp_path):
    if request.param == "memory":
        j = MemoryJournal(max_samples=5)
    else:
        j = SqliteJournal(tmp_path / "j.sqlite", max_samples=5)
    yield j
    j.close()


def samples(*values: object) -> list[Sample]:
    return [Sample("io/m1/ai0", v, Quality.GOOD, 1000 + i) for i, v in enumerate(values)]


def test_rows_come_back_in_order_and_leave_only_when_deleted(journal):
    assert journal.append(samples(1, 2.5, True)) == 0
    rows = journal.read(0, 10)
    assert [s.value for _, s in rows] == [1, 2.5, True]
    assert [type(s.value) for _, s in rows] == [int, float, bool]
    assert journal.read(rows[0][0], 1)[0][1].value == 2.5
    assert journal.count() == 3 and journal.oldest_ts_ms() == 1000
    journal.delete([rows[0][0], rows[0][0]])
    assert journal.count() == 2 and journal.oldest_ts_ms() == 1001


def test_a_full_journal_drops_the_oldest(journal):
    journal.append(samples(1, 2, 3, 4))
    assert journal.append(samples(5, 6, 7)) == 2
    assert [s.value for _, s in journal.read(0, 10)] == [3, 4, 5, 6, 7]
    assert journal.count() == 5


def test_the_sqlite_journal_survives_a_reopen(tmp_path):
    path = tmp_path / "state" / "j.sqlite"
    first = SqliteJournal(path, sync="full")
    first.append(samples(1, 2, 3))
    first.delete([first.read(0, 1)[0][0]])
    # no close(): the process dies with the file open
    second = SqliteJournal(path)
    assert [s.value for _, s in second.read(0, 10)] == [2, 3] and second.count() == 2
    second.close()
    assert second.count() == 2 and second.oldest_ts_ms() == 1001  # still readable for status


def test_an_unusable_journal_file_is_one_error(tmp_path):
    (tmp_path / "j.sqlite").write_bytes(b"this is not a database" * 100)
    with pytest.raises(JournalError, match="j.sqlite"):
        SqliteJournal(tmp_path / "j.sqlite")
