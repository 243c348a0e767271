"""Python hooks of an EDS device: read and write callbacks per index or index range.

A hook module (``hooks: mypkg.battery``, a file ``hooks: ./battery.py``, or the name of an
entry point in the group ``fieldgate.canopen_hooks``) has a ``setup(device)`` function;
``device`` is a :class:`DeviceApi`::

    def setup(device):
        @device.on_read(0x2000, 0x20FF)        # one index, or a range (both ends included)
        def measure(index, sub):
            return read_the_sensor(index, sub)  # the entry's value, of its data type

        @device.on_write(0x2100)
        def limit(index, sub, value):
            if value > 100:
                raise device.Refuse(0x06090031)  # SDO abort "value too high"
            apply_the_limit(value)

        device.set(0x2001, 0, 42)              # from any thread: a new value, TPDO events
        device.raise_emcy(0x5000, 0x81, b"\\x01"); device.clear_emcy(0x5000)

The rule (docs/canopen-device.md, "Hooks"): callbacks never run on the bus's path. They run
on the hook workers (threads, ``hook_workers``), one call per entry at a time:

* an SDO **upload** of a hooked entry waits for its read callback, a **download** for its
  write callback, and the SDO server answers when it returns: the value it read, the write
  taken, or the abort code of its :class:`Refuse` (any other exception: 0800 0020). After
  ``hook_timeout_ms`` the server aborts the transfer (0800 0020 a write, 0800 0024 a read)
  and the value stays as it was. Meanwhile the node serves every other request, SDO channel,
  PDO, SYNC, heartbeat and EMCY as usual;
* **PDOs never wait**: a TPDO carries the entry's current value (what the last read callback
  gave, or :meth:`DeviceApi.set`); an RPDO's value is taken at once and the write callback
  is called with it afterwards (it cannot be refused: PDOs have no answer);
* :meth:`DeviceApi.set`, :meth:`raise_emcy`, :meth:`clear_emcy` and :meth:`trigger` may be
  called from any thread: they are run on the gateway's event loop.

Everything here but :class:`ThreadRunner` is driven by calls (sans-I/O): tests run the
jobs with :class:`ManualRunner`.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import logging
import sys
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from ..cia301.abort import CANNOT_STORE, NO_DATA, Deferred, SdoAbort

log = logging.getLogger("fieldgate.canopen.device.hooks")

ENTRY_POINT_GROUP = "fieldgate.canopen_hooks"
ReadHook = Callable[[int, int], Any]
WriteHook = Callable[[int, int, Any], None]


class Refuse(SdoAbort):
    """Raised by a write (or read) callback: the SDO transfer is aborted with ``code``."""

    def __init__(self, code: int, text: str = "refused by the device's hook"):
        super().__init__(code, text)


class HookError(ValueError):
    """The hook module cannot be loaded or set up (one line: what and where)."""


@dataclass
class _Range:
    first: int
    last: int
    read: ReadHook | None = None
    write: WriteHook | None = None

    def covers(self, index: int) -> bool:
        return self.first <= index <= self.last


class Runner(Protocol):
    """Runs a hook call off the bus path; ``done(outcome)`` is called once it returned."""

    def submit(self, job: Callable[[], Any], done: Callable[[Any], None]) -> None: ...

    def close(self) -> None: ...


class ManualRunner:
    """Jobs wait until the test runs them (:meth:`run`, :meth:`run_all`): deterministic."""

    def __init__(self) -> None:
        self.jobs: list[tuple[Callable[[], Any], Callable[[Any], None]]] = []

    def submit(self, job: Callable[[], Any], done: Callable[[Any], None]) -> None:
        self.jobs.append((job, done))

    def run(self, position: int = 0) -> None:
        job, done = self.jobs.pop(position)
        done(call(job))

    def run_all(self) -> None:
        while self.jobs:
            self.run()

    def close(self) -> None:
        self.jobs.clear()


class ThreadRunner:
    """Hook calls on ``workers`` threads; ``deliver(fn)`` brings ``fn`` back onto the loop."""

    def __init__(self, workers: int, deliver: Callable[[Callable[[], None]], None]):
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="canopen-hook")
        self._deliver = deliver

    def submit(self, job: Callable[[], Any], done: Callable[[Any], None]) -> None:
        future = self._pool.submit(call, job)

        def finished(f: Future[Any]) -> None:
            outcome = f.result()
            self._deliver(lambda: done(outcome))

        future.add_done_callback(finished)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


def call(job: Callable[[], Any]) -> Any:
    """A hook's outcome: its result, its :class:`SdoAbort`, or abort 0800 0020 for a crash."""
    try:
        return job()
    except SdoAbort as exc:
        return exc
    except Exception as exc:
        log.exception("device hook failed")
        return SdoAbort(CANNOT_STORE, f"hook failed: {exc}")


class HookTable:
    """The callbacks of one device and the calls in flight (one per entry at a time)."""

    def __init__(self, timeout_s: float = 0.5):
        self.timeout_s = timeout_s
        self.ranges: list[_Range] = []
        self._tickets = 0
        self._flight: dict[tuple[str, int, int], tuple[int, Any]] = {}  # key -> ticket, argument
        self._ready: dict[int, Any] = {}  # ticket -> outcome, until the replay took it
        self.counters: dict[str, int] = {"calls": 0, "refused": 0, "pdo_writes": 0}
        self.runner: Runner = ManualRunner()
        self.finished: Callable[[int], None] = lambda ticket: None  # set by the front

    def add(
        self, first: int, last: int | None, read: ReadHook | None, write: WriteHook | None
    ) -> None:
        last = first if last is None else last
        if not 0 <= first <= last <= 0xFFFF:
            raise HookError(f"index range 0x{first:04X}..0x{last:04X} is not within 0..0xFFFF")
        self.ranges.append(_Range(first, last, read, write))

    def reader(self, index: int) -> ReadHook | None:
        return next((r.read for r in self.ranges if r.read and r.covers(index)), None)

    def writer(self, index: int) -> WriteHook | None:
        return next((r.write for r in self.ranges if r.write and r.covers(index)), None)

    # -- deferred SDO accesses ---------------------------------------------------------------
    def read(self, index: int, sub: int) -> Any:
        """An SDO upload's value: the read callback's outcome, or Deferred until it is there."""
        hook = self.reader(index)
        assert hook is not None
        return self._outcome(("r", index, sub), None, lambda: hook(index, sub), NO_DATA)

    def write(self, index: int, sub: int, value: Any) -> None:
        """An SDO download: returns when the write callback took ``value`` (Refuse: abort)."""
        hook = self.writer(index)
        if hook is not None:
            self._outcome(("w", index, sub), value, lambda: hook(index, sub, value), CANNOT_STORE)

    def _outcome(
        self, key: tuple[str, int, int], argument: Any, job: Callable[[], Any], code: int
    ) -> Any:
        flight = self._flight.get(key)
        if flight is not None:
            ticket, arg = flight
            if ticket in self._ready and arg == argument:
                del self._flight[key]
                outcome = self._ready.pop(ticket)
                if isinstance(outcome, SdoAbort):
                    self.counters["refused"] += 1
                    raise SdoAbort(outcome.code, str(outcome))
                return outcome
            if ticket in self._ready:  # a finished call for another value: forget it
                del self._flight[key]
                self._ready.pop(ticket)
                flight = None
        if flight is None:
            self._tickets += 1
            ticket = self._tickets
            self._flight[key] = (ticket, argument)
            self.counters["calls"] += 1
            self.runner.submit(job, lambda outcome: self._done(ticket, outcome))
        raise Deferred(ticket, key[1], key[2], self.timeout_s, code)

    def _done(self, ticket: int, outcome: Any) -> None:
        self._ready[ticket] = outcome
        self.finished(ticket)
        # nobody waited for it any more (the SDO client gave up, or the call timed out)
        if ticket in self._ready:
            self._ready.pop(ticket)
            for key, (t, _) in list(self._flight.items()):
                if t == ticket:
                    del self._flight[key]

    # -- PDO writes ---------------------------------------------------------------------------
    def pdo_written(self, index: int, sub: int, value: Any) -> None:
        """An RPDO wrote a hooked entry: its write callback learns of it (not refusable)."""
        hook = self.writer(index)
        if hook is not None:
            self.counters["pdo_writes"] += 1
            self.runner.submit(lambda: hook(index, sub, value), lambda outcome: None)

    def status(self) -> dict[str, Any]:
        return {**self.counters, "in_flight": len(self._flight), "ranges": len(self.ranges)}


class DeviceApi:
    """What a hook module's ``setup(device)`` gets (see the module's docstring)."""

    Refuse = Refuse

    def __init__(
        self,
        table: HookTable,
        node_id: Callable[[], int],
        run: Callable[[Callable[[], None]], None],
        actions: DeviceActions,
    ):
        self._table = table
        self._node_id = node_id
        self._run = run
        self._actions = actions
        self.log = logging.getLogger("fieldgate.canopen.device.hook")

    @property
    def node_id(self) -> int:
        return self._node_id()

    def on_read(self, first: int, last: int | None = None) -> Callable[[ReadHook], ReadHook]:
        def register(hook: ReadHook) -> ReadHook:
            self._table.add(first, last, hook, None)
            return hook

        return register

    def on_write(self, first: int, last: int | None = None) -> Callable[[WriteHook], WriteHook]:
        def register(hook: WriteHook) -> WriteHook:
            self._table.add(first, last, None, hook)
            return hook

        return register

    def get(self, index: int, sub: int = 0) -> Any:
        """The entry's current value (as a TPDO would carry it)."""
        return self._actions.get(index, sub)

    def set(self, index: int, sub: int, value: Any) -> None:
        """A new value from the application: TPDOs that map it and are event-driven are sent."""
        self._run(lambda: self._actions.set(index, sub, value))

    def trigger(self, index: int, sub: int = 0) -> None:
        """An application event on the entry without a new value: its event-driven TPDOs go."""
        self._run(lambda: self._actions.trigger(index, sub))

    def raise_emcy(self, code: int, register: int = 0x01, data: bytes = b"") -> None:
        self._run(lambda: self._actions.raise_emcy(code, register, data))

    def clear_emcy(self, code: int, data: bytes | None = None) -> None:
        self._run(lambda: self._actions.clear_emcy(code, data))


class DeviceActions(Protocol):
    def get(self, index: int, sub: int) -> Any: ...
    def set(self, index: int, sub: int, value: Any) -> None: ...
    def trigger(self, index: int, sub: int) -> None: ...
    def raise_emcy(self, code: int, register: int, data: bytes) -> None: ...
    def clear_emcy(self, code: int, data: bytes | None) -> None: ...


def load_setup(spec: str, base: Path | None = None) -> Callable[[DeviceApi], None]:
    """The ``setup`` function ``hooks:`` names: a file (``*.py`` or a path), an entry point of
    ``fieldgate.canopen_hooks``, or an importable module."""
    if spec.endswith(".py") or "/" in spec:
        path = Path(spec)
        if not path.is_absolute() and base is not None:
            path = base / path
        name = f"fieldgate_canopen_hooks_{path.stem}"
        module_spec = importlib.util.spec_from_file_location(name, path)
        if module_spec is None or module_spec.loader is None or not path.is_file():
            raise HookError(f"hooks: no Python file {path}")
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[name] = module
        try:
            module_spec.loader.exec_module(module)
        except Exception as exc:
            raise HookError(f"hooks: {path} failed to load: {exc}") from None
        target: Any = module
    else:
        points = [
            e for e in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP) if e.name == spec
        ]
        try:
            target = points[0].load() if points else importlib.import_module(spec)
        except Exception as exc:
            raise HookError(f"hooks: cannot import {spec!r}: {exc}") from None
    setup = (
        target
        if callable(target) and not hasattr(target, "setup")
        else getattr(target, "setup", None)
    )
    if not callable(setup):
        raise HookError(f"hooks: {spec!r} has no setup(device) function")
    return setup  # type: ignore[no-any-return]  # a user's module: checked callable above
