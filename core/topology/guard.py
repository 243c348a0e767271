"""Limits on a topology file before it is built into objects: no input makes ``validate``
or ``run`` hang, eat memory, or print a traceback.

* the file must be a regular file (not a FIFO that blocks forever, not ``/dev/zero``)
  of at most :data:`MAX_BYTES`;
* one pass over ruamel's event stream (iterative: no recursion, linear in the text)
  checks, before any object is built:

  - nesting depth at most :data:`MAX_DEPTH` (400 nested lists crashed Python's own
    recursion limit in the composer, with a 2,750-line traceback);
  - the size of the document with every alias expanded at most :data:`MAX_NODES` (an
    "alias bomb" of 2 KB expands to billions of nodes: anything that walks it, a
    validator or a ``repr()``, never ends);
  - an alias never refers to a node that contains it (a recursive structure);
  - no key twice in one mapping, reported here as one line naming both places (ruamel
    builds its own duplicate-key message with ``repr()`` of the whole mapping, which
    expands every alias in it).

Every finding is a :class:`~fieldgate.topology.errors.ConfigIssue` with file, line and
column; the loader raises it as a TopologyError (``validate``: one line, exit 1).
"""

from __future__ import annotations

import os
import stat
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.events import (
    AliasEvent,
    CollectionEndEvent,
    CollectionStartEvent,
    MappingStartEvent,
    ScalarEvent,
)

from .errors import ConfigIssue, TopologyError

MAX_BYTES = 2 * 1024 * 1024
"""Largest topology file: 2 MiB is some 50,000 lines, beyond 16 lines of 247 modules."""

MAX_DEPTH = 64
"""Deepest nesting of mappings and lists (a topology needs about 8)."""

MAX_NODES = 200_000
"""Most nodes of the document with every alias expanded (a topology has a few thousand)."""


def read_limited(path: str) -> bytes:
    """The bytes of a regular file of at most MAX_BYTES; TopologyError otherwise (one line)."""
    try:
        info = os.stat(path)  # stat never blocks, opening a FIFO would
    except OSError as exc:
        raise _issue(path, f"cannot read file: {exc.strerror or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        raise _issue(path, f"not a regular file ({_kind(info.st_mode)}); give a topology file")
    if info.st_size > MAX_BYTES:
        raise _issue(path, _too_big(info.st_size))
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise _issue(path, f"cannot read file: {exc.strerror or exc}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced since the stat
            raise _issue(path, "not a regular file; give a topology file")
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(MAX_BYTES + 1)
    except OSError as exc:
        raise _issue(path, f"cannot read file: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(data) > MAX_BYTES:  # grew since the stat
        raise _issue(path, _too_big(len(data)))
    return data


def _too_big(size: int) -> str:
    return (
        f"file of {size:,} bytes is larger than the {MAX_BYTES // (1024 * 1024)} MiB a topology "
        "may have; is this the right file?"
    )


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a plain file"


def _issue(file: str, message: str, mark: Any = None) -> TopologyError:
    line, col = (mark.line + 1, mark.column + 1) if mark is not None else (None, None)
    return TopologyError([ConfigIssue(file, line, col, "", message)])


class _Open:
    """A mapping or list being read: its expanded size so far, its keys (mappings)."""

    __slots__ = ("anchor", "is_mapping", "items", "keys", "size", "start")

    def __init__(self, anchor: str | None, is_mapping: bool, start: Any) -> None:
        self.anchor = anchor
        self.start = start
        self.is_mapping = is_mapping
        self.size = 1
        self.items = 0
        self.keys: dict[str, Any] = {}


def check_structure(text: str, file: str) -> None:
    """Depth, alias expansion, recursive aliases and duplicate keys, from the event stream."""
    sizes: dict[str, int] = {}  # anchor -> expanded size of its node (once it is complete)
    stack: list[_Open] = []
    total = 0
    for event in YAML(typ="rt").parse(text):
        if isinstance(event, CollectionStartEvent):
            _note_key(stack, event, file)
            if len(stack) >= MAX_DEPTH:
                raise _issue(file, f"nested deeper than {MAX_DEPTH} levels", event.start_mark)
            stack.append(
                _Open(event.anchor, isinstance(event, MappingStartEvent), event.start_mark)
            )
        elif isinstance(event, CollectionEndEvent):
            node = stack.pop()
            if node.anchor is not None:
                sizes[node.anchor] = node.size
            total = _add(stack, node.size, total, event, file)
        elif isinstance(event, ScalarEvent):
            _note_key(stack, event, file)
            if event.anchor is not None:
                sizes[event.anchor] = 1
            total = _add(stack, 1, total, event, file)
        elif isinstance(event, AliasEvent):
            _note_key(stack, event, file)
            size = sizes.get(event.anchor)
            if size is None:
                inside = any(n.anchor == event.anchor for n in stack)
                raise _issue(
                    file,
                    f"alias *{event.anchor} refers to a node that contains it"
                    if inside
                    else f"alias *{event.anchor} has no anchor &{event.anchor} before it",
                    event.start_mark,
                )
            total = _add(stack, size, total, event, file)


def _add(stack: list[_Open], size: int, total: int, event: Any, file: str) -> int:
    if stack:
        parent = stack[-1]
        parent.size += size
        parent.items += 1
        if parent.size > MAX_NODES:
            raise _issue(file, _expansion(), event.start_mark)
        return total
    if total + size > MAX_NODES:
        raise _issue(file, _expansion(), event.start_mark)
    return total + size


def _expansion() -> str:
    return (
        f"the document expands to more than {MAX_NODES:,} nodes with its aliases (an alias "
        "bomb?); a topology needs a few thousand"
    )


def _note_key(stack: list[_Open], event: Any, file: str) -> None:
    """A scalar in a key position: refuse a key the mapping has already."""
    if not stack or not stack[-1].is_mapping or stack[-1].items % 2:
        return
    if not isinstance(event, ScalarEvent) or event.value == "<<":
        return
    parent, key = stack[-1], event.value
    first = parent.keys.get(key)
    if first is not None:
        shown = key if len(key) <= 40 else key[:40] + "..."
        raise _issue(
            file,
            f'YAML syntax: duplicate key "{shown}" in the mapping that starts on line '
            f"{parent.start.line + 1} (first at line {first.line + 1}); each key may appear once",
            event.start_mark,
        )
    parent.keys[key] = event.start_mark
