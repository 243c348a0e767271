"""Atomic persistence of settings (CANopen 0x1010 store, LSS store, scan results...).

``write_atomic`` writes a temporary file in the same directory, fsyncs it, renames it
over the target and fsyncs the directory: a crash at any point leaves either the old
complete copy or the new complete copy, never a torn file.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path


def write_atomic(path: str | os.PathLike, data: bytes) -> None:
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    dir_fd = os.open(target.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def write_json_atomic(path: str | os.PathLike, obj: object) -> None:
    write_atomic(path, json.dumps(obj, indent=1, sort_keys=True).encode())


class CorruptStore(Exception):
    """The stored file exists but cannot be used."""


def read_json(path: str | os.PathLike) -> object | None:
    """The stored object, None when there is no file, CorruptStore when it is unreadable."""
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        return None
    try:
        return json.loads(raw)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CorruptStore(f"{path}: {exc}") from exc
