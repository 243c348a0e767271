"""Atomic persistence of settings (CANopen 0x1010 store, LSS store, scan results...) and of
files written for other tools (EDS).

``write_atomic`` writes a temporary file in the same directory, fsyncs it, renames it
over the target and fsyncs the directory: a crash at any point leaves either the old
complete copy or the new complete copy, never a torn file.

File mode: the result has the mode an ordinary ``open(path, "w")`` would give it. A new
file gets ``0o666 & ~umask`` (0644 under the usual umask 022), so an EDS is readable by the
configurator or file server that picks it up; a file that already exists keeps its mode
(``chmod 600 store.json`` survives the next save). This holds for the persisted state
files too (CANopen store, LSS store, DeviceNet store): they hold bus settings, no secret,
and an operator may read them without the gateway's account; whoever wants them private
runs the gateway with a stricter umask (systemd ``UMask=0077``) or chmods them once.
(``tempfile.mkstemp`` would make every file 0600 whatever the umask: not used.)

Folders: state files live under ``gateway.state_dir``, which is created when missing
(``make_parents=True``, the default). A file the user named on the command line
(``fieldgate eds -o``) is written with ``make_parents=False``: a mistyped folder is an
error (FileNotFoundError), not a new directory tree.
"""

from __future__ import annotations

import errno
import json
import os
import secrets
import stat
from pathlib import Path

_TEMP_FLAGS = (
    os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0) | getattr(os, "O_CLOEXEC", 0)
)


def write_atomic(path: str | os.PathLike[str], data: bytes, *, make_parents: bool = True) -> None:
    """Replace ``path`` by ``data`` atomically (see the module's docstring for mode and folders).

    Errors are OSError as from ``open``: FileNotFoundError (no such folder, with
    ``make_parents=False``), IsADirectoryError (``path`` is a directory; nothing is left
    behind), PermissionError...
    """
    target = Path(path)
    if make_parents:
        target.parent.mkdir(parents=True, exist_ok=True)
    try:
        current = os.stat(target)
    except FileNotFoundError:
        keep_mode = None
    else:
        if stat.S_ISDIR(current.st_mode):
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(target))
        keep_mode = stat.S_IMODE(current.st_mode) if stat.S_ISREG(current.st_mode) else None
    fd, tmp = _create_temp(target)
    try:
        if keep_mode is not None and hasattr(os, "fchmod"):
            os.fchmod(fd, keep_mode)
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


def _create_temp(target: Path) -> tuple[int, Path]:
    """A new file beside ``target``, created 0666 so the umask alone decides its mode."""
    for _ in range(100):
        tmp = target.parent / f".{target.name}.{secrets.token_hex(4)}.tmp"
        try:
            return os.open(tmp, _TEMP_FLAGS, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(target.parent))


def write_json_atomic(path: str | os.PathLike[str], obj: object) -> None:
    write_atomic(path, json.dumps(obj, indent=1, sort_keys=True).encode())


class CorruptStore(Exception):
    """The stored file exists but cannot be used."""


def read_json(path: str | os.PathLike[str]) -> object | None:
    """The stored object, None when there is no file, CorruptStore when it is unreadable."""
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        return None
    try:
        stored: object = json.loads(raw)
        return stored
    except (ValueError, UnicodeDecodeError) as exc:
        raise CorruptStore(f"{path}: {exc}") from exc
