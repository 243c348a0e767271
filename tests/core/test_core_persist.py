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


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_a_new_file_follows_the_umask_and_an_existing_one_keeps_its_mode(tmp_path, umask_022):
    path = tmp_path / "out.eds"
    persist.write_atomic(path, b"one")
    assert path.stat().st_mode & 0o777 == 0o644  # not mkstemp's 0600
    os.umask(0o027)
    persist.write_atomic(tmp_path / "other", b"x")
    assert (tmp_path / "other").stat().st_mode & 0o777 == 0o640
    path.chmod(0o600)
    persist.write_atomic(path, b"two")
    assert path.read_bytes() == b"two" and path.stat().st_mode & 0o777 == 0o600
    persist.write_json_atomic(tmp_path / "state" / "store.json", {"v": 1})  # state files: same rule
    assert (tmp_path / "state" / "store.json").stat().st_mode & 0o777 == 0o640


def test_without_make_parents_a_missing_folder_is_an_error_and_nothing_is_created(tmp_path):
    path = tmp_path / "no" / "such" / "x.eds"
    with pytest.raises(FileNotFoundError):
        persist.write_atomic(path, b"x", make_parents=False)
    assert list(tmp_path.iterdir()) == []


def test_a_directory_target_is_refused_and_leaves_nothing_behind(tmp_path):
    (tmp_path / "outdir").mkdir()
    with pytest.raises(IsADirectoryError):
        persist.write_atomic(tmp_path / "outdir", b"x")
    assert [p.name for p in tmp_path.iterdir()] == ["outdir"] and not any(
        (tmp_path / "outdir").iterdir()
    )


def test_a_temporary_file_left_by_a_killed_write_is_removed_by_the_next_write(tmp_path):
    """A SIGKILL between creating the temporary file and the rename leaves it behind; without
    step 0 every such kill would leave one more file in the state folder."""
    path = tmp_path / "plc.canopen.json"
    persist.write_json_atomic(path, {"v": 1})
    leftover = tmp_path / ".plc.canopen.json.0badf00d.tmp"
    leftover.write_bytes(b'{"v": 2')  # torn: the process died while writing it
    other = tmp_path / ".other.json.0badf00d.tmp"  # another file's temporary is not ours
    other.write_bytes(b"x")
    assert persist.temp_files(path) == [leftover]
    assert persist.read_json(path) == {"v": 1}  # the leftover is never read
    persist.write_json_atomic(path, {"v": 3})
    assert persist.temp_files(path) == [] and not leftover.exists()
    assert other.exists() and persist.read_json(path) == {"v": 3}
