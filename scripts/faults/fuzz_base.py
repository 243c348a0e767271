"""The fuzz targets' common parts (scripts/faults/fuzz_targets.py lists the targets).

A target is stateful across inputs (a long-lived gateway sees one frame after another):
``run(data)`` feeds one input; ``check()`` is the invariant after it: the engine still
answers a valid request of its protocol and counted no internal error. Anything that
escapes ``run`` other than the wire's own error type is a crash.

The buffer is read by :class:`Bytes`: structure-aware choices (known COB-IDs, command
specifiers, dictionary indexes, CIP services, valid replies to mutate and re-checksum)
come from its bytes, so the fuzzer spends its inputs on frames the engine cannot reject
at the first byte.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Coroutine, Sequence
from pathlib import Path
from typing import Any, TypeVar

from fieldgate import load_registry
from fieldgate.plugin import Registry

T = TypeVar("T")


class InvariantBroken(AssertionError):
    """The engine took the input without an exception but no longer does its job."""


class Bytes:
    """Reads choices from a fuzz buffer; an exhausted buffer reads zeros."""

    def __init__(self, data: bytes):
        self.data = data
        self.pos = 0

    def more(self) -> bool:
        return self.pos < len(self.data)

    def u8(self) -> int:
        if self.pos >= len(self.data):
            return 0
        self.pos += 1
        return self.data[self.pos - 1]

    def u16(self) -> int:
        return self.u8() | self.u8() << 8

    def take(self, n: int) -> bytes:
        out = self.data[self.pos : self.pos + n]
        self.pos += len(out)
        return out.ljust(n, b"\0") if len(out) < n and self.pos >= len(self.data) else out

    def pick(self, items: Sequence[T]) -> T:
        return items[self.u8() % len(items)]

    def chance(self, one_in: int) -> bool:
        return self.u8() % one_in == 0


def run_sync(coro: Coroutine[Any, Any, T]) -> T:
    """Run a coroutine that never really suspends (fake links answer at once)."""
    try:
        coro.send(None)
    except StopIteration as stop:
        return stop.value  # type: ignore[no-any-return]
    coro.close()
    raise InvariantBroken("a transaction waited for I/O that a fake link never gives")


class Target(ABC):
    name: str
    max_len = 96  # bytes per input

    def __init__(self, work_dir: Path, registry: Registry | None = None):
        self.work_dir = work_dir
        self.registry = registry or load_registry()
        self.setup()

    @abstractmethod
    def setup(self) -> None:
        """Build the engine (again, after a failure)."""

    @abstractmethod
    def run(self, data: bytes) -> None: ...

    @abstractmethod
    def check(self) -> None: ...

    def close(self) -> None:  # noqa: B027  (optional: a target that runs something of its own)
        """Stop what the target started (a gateway on a thread); the campaign calls it last."""


NODE = 5
CO_TOPOLOGY_BACK = {
    "name": "rs485",
    "type": "dcon",
    "port": "/dev/null",  # never opened: the fronts need the channels, not a running back
    "modules": [
        {"address": 1, "model": "I-7055"},
        {"address": 2, "model": "I-7017"},
        {"address": 3, "model": "I-7024"},
    ],
}


def one_front(work_dir: Path, front: dict[str, Any]) -> dict[str, Any]:
    """A topology of one front (on the virtual bus) over the never-started DCON back."""
    return {
        "gateway": {"name": "fuzz", "state_dir": str(work_dir)},
        "fronts": [{"interface": "virtual", **front}],
        "backs": [CO_TOPOLOGY_BACK],
    }
