"""Atomic persistence: a crash mid-write keeps the previous complete copy."""

import os

import pytest

from fieldgate import persist


def test_write_and_read_back(tmp_path):
    path = tmp_path / "sub" / "store.json"
    persist.write_json_atomic(path, {"0x1017": 1000})
    assert persist.read_json(path) == {"0x1017": 1000}
    assert [p.name for p in path.parent.iterdir()] == ["store.json"]  # no temporary left behind


def test_crash_before_rename_keeps_previous_copy(tmp_path, monkeypatch):
    path = tmp_path / "store.json"
    persist.write_json_atomic(path, {"v": 1})

    def crash(*args):
        raise OSError("power lost")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="power lost"):
        persist.write_json_atomic(path, {"v": 2})
    assert persist.read_json(path) == {"v": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["store.json"]


def test_crash_during_write_keeps_previous_copy(tmp_path, monkeypatch):
    path = tmp_path / "store.json"
    persist.write_json_atomic(path, {"v": 1})
    real_fsync = os.fsync

    def crash(fd):
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", crash)
    with pytest.raises(OSError):
        persist.write_json_atomic(path, {"v": 2})
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert persist.read_json(path) == {"v": 1}


def test_missing_is_none_and_corrupt_is_reported(tmp_path):
    assert persist.read_json(tmp_path / "none.json") is None
    bad = tmp_path / "bad.json"
    bad.write_bytes(b'{"v": 1')  # torn by something other than us
    with pytest.raises(persist.CorruptStore, match="bad.json"):
        persist.read_json(bad)
