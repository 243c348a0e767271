"""One north-facing child process, seen from the fieldbus process: start, feed, watch, stop.

:class:`ChildProcess` starts ``python -m fieldgate.isolation.child`` with one end of a socket
pair, sends it what it serves (the topology, its part, a snapshot of the gateway), then
keeps its :class:`~.feed.Outbox` flowing from the gateway's :class:`~.feed.GatewayFeed`
without ever waiting on it. It watches the child three ways:

* liveness: a ping every ``liveness_timeout_s / 4`` on the same channel; no answer from the
  child's event loop for ``liveness_timeout_s`` and it is killed;
* memory: its resident set read from /proc each second; above ``memory_limit_mb`` it is killed;
* the process itself: an exit or a closed channel ends it.
:meth:`wait` returns the reason; the runtime's supervision restarts it with back-off.

What a child asks of the fieldbus process (``{"t": "write", ...}``) is checked field by
field and applied at most ``writes_per_s`` batches a second per child, one at a time; a
child has at most ``MAX_WRITES_WAITING`` batches waiting (it waits for their answers).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from ..plugin import PluginStartError
from ..procstat import cpu_seconds, resident_bytes
from ..topology.model import IsolationSettings
from . import wire
from .cpus import north_set
from .feed import GatewayFeed, Outbox

log = logging.getLogger("fieldgate.isolation")

MAX_WRITES_WAITING = 64
MAX_STATUS_BYTES = 512 * 1024  # a status frame larger than this is dropped unread
WRITE_CHUNK = 256 * 1024  # bytes handed to the socket per wake-up
# a child asked to stop gets this long (its part's own stop is bounded shorter, at
# child.PART_STOP_S, and it exits without the interpreter's teardown) before SIGKILL
STOP_GRACE_S = 1.5

WriteHandler = Callable[[dict[str, bool | int | float | str]], str | None]


class ChildProcess:
    """A north-facing part running in a child process (see the module's docstring)."""

    def __init__(
        self,
        name: str,
        feed: GatewayFeed,
        settings: IsolationSettings,
        init: Callable[[], dict[str, Any]],
        on_write: WriteHandler | None = None,
    ):
        self.name = name
        self.feed = feed
        self.settings = settings
        self._init = init
        self._on_write = on_write
        self.process: Spawned | None = None
        self.outbox = Outbox(settings.feed_buffer_kb * 1024)
        self.status: dict[str, Any] = {}  # the child's last report
        self.ready: dict[str, Any] = {}
        self.rss = 0
        self.peak_rss = 0
        self.cpu_s = 0.0
        self.started_at: float | None = None
        self.writes_applied = 0
        self.writes_refused = 0
        self.protocol_errors = 0
        self.kills: dict[str, int] = {}
        self.state = "stopped"
        self._transport: asyncio.WriteTransport | None = None
        self._paused = False
        self._flush_scheduled = False
        self._detach: Callable[[], None] | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._ready: asyncio.Future[dict[str, Any]] | None = None
        self._ended: asyncio.Future[str] | None = None
        self._reason = ""
        self._last_pong = 0.0
        self._writes: deque[tuple[int, dict[str, bool | int | float | str]]] = deque()
        self._write_wake = asyncio.Event()
        self.fieldbus_lag = 0.0

    # -- life cycle -------------------------------------------------------------------------
    async def start(self) -> dict[str, Any]:
        """Start the child and return its ready report; PluginStartError (one line) when it
        cannot start (its own reason, or why it did not answer)."""
        loop = asyncio.get_running_loop()
        self._reason = ""
        self.outbox = Outbox(self.settings.feed_buffer_kb * 1024)
        self._ready = loop.create_future()
        self._ended = loop.create_future()
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self.process = await Spawned.start(
                [sys.executable, "-m", "fieldgate.isolation.child", str(theirs.fileno())],
                theirs.fileno(),
                north_set(self.settings),
            )
        except OSError as exc:
            ours.close()
            raise PluginStartError(f"cannot start a child process: {exc}") from None
        finally:
            theirs.close()
        self.state = "starting"
        self.started_at = time.monotonic()
        self._last_pong = loop.time()
        transport, _ = await loop.create_unix_connection(lambda: _Link(self), sock=ours)
        self._transport = transport
        transport.set_write_buffer_limits(high=WRITE_CHUNK, low=WRITE_CHUNK // 4)
        # the snapshot in the first message and the feed's first change are one loop turn apart
        self.outbox.resync = False
        init = self._init()
        init["snapshot"] = self.feed.snapshot_message()
        self._detach = self.feed.attach(self.outbox, self._wake)
        transport.write(wire.down(init))
        self._tasks = [
            loop.create_task(self._reap(), name=f"fieldgate:{self.name}:reap"),
            loop.create_task(self._watch(), name=f"fieldgate:{self.name}:watch"),
            loop.create_task(self._apply_writes(), name=f"fieldgate:{self.name}:writes"),
        ]
        try:
            ready = await asyncio.wait_for(
                asyncio.shield(self._ready), self.settings.start_timeout_s
            )
        except TimeoutError:
            self.kill(f"not ready within {self.settings.start_timeout_s:g} s")
            await self._cleanup()
            raise PluginStartError(
                f"child process not ready within {self.settings.start_timeout_s:g} s "
                "(gateway.isolation.start_timeout_s)"
            ) from None
        except PluginStartError:
            await self._cleanup()
            raise
        self.state = "running"
        self.ready = ready
        return ready

    async def wait(self) -> str:
        """Until the child ends; why it ended, in one line."""
        assert self._ended is not None
        return await asyncio.shield(self._ended)

    async def stop(self) -> None:
        """Ask the child to stop; kill it if it has not within STOP_GRACE_S."""
        proc = self.process
        if self.state == "starting" and proc is not None and proc.returncode is None:
            # not serving yet: nothing to close gracefully, and its start (an OPC UA
            # certificate, a broker) could take seconds before it reads the stop
            log.info("%s: stopped while starting (its child process is ended)", self.name)
            self._reason = self._reason or "stopped while starting"
            self.state = "stopping"
            proc.send_signal(signal.SIGKILL)
            await proc.wait()
        elif proc is not None and proc.returncode is None and self._transport is not None:
            self.state = "stopping"
            self.outbox.put_control(wire.down(("stop",)))
            self._flush()
            try:
                await asyncio.wait_for(proc.wait(), STOP_GRACE_S)
            except TimeoutError:
                self.kill(f"still running {STOP_GRACE_S:g} s after it was asked to stop")
                await proc.wait()
        await self._cleanup()
        self.state = "stopped"

    def kill(self, reason: str) -> None:
        """SIGKILL, with the reason :meth:`wait` gives."""
        proc = self.process
        if proc is None or proc.returncode is not None:
            return
        if not self._reason:
            self._reason = reason
            self.kills[reason.split(":")[0]] = self.kills.get(reason.split(":")[0], 0) + 1
            log.error("%s: killing its child process %d: %s", self.name, proc.pid, reason)
        try:
            proc.send_signal(signal.SIGKILL)
        except ProcessLookupError:
            pass

    def channel_closed(self, process: Spawned | None) -> None:
        """``process``'s socket closed a second ago and it is still there: end it (unless it
        is stopping, when :meth:`stop` waits for it, or a restart replaced it)."""
        if process is self.process and self.state not in ("stopping", "stopped"):
            self.kill("its channel to the fieldbus process closed")

    async def _cleanup(self) -> None:
        if self._detach is not None:
            self._detach()
            self._detach = None
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        proc = self.process
        if proc is not None and proc.returncode is None:
            proc.kill()
            await proc.wait()
        self._paused = False
        self._writes.clear()

    def _end(self, reason: str) -> None:
        reason = self._reason or reason
        if self._ready is not None and not self._ready.done():
            self._ready.set_exception(PluginStartError(reason))
            self._ready.exception()  # retrieved: a start that was cancelled meanwhile awaits none
        if self._ended is not None and not self._ended.done():
            self._ended.set_result(reason)
        if self.state == "running":
            self.state = "failed"

    async def _reap(self) -> None:
        assert self.process is not None
        code = await self.process.wait()
        if code < 0:
            how = f"killed by signal {-code} ({signal.Signals(-code).name})"
        else:
            how = f"exited with code {code}"
        self._end(f"child process {how}" + (f": {self._reason}" if self._reason else ""))

    # -- the child's health -------------------------------------------------------------------
    async def _watch(self) -> None:
        loop = asyncio.get_running_loop()
        period = min(0.5, self.settings.liveness_timeout_s / 4)
        seq = 0
        next_sample = loop.time()
        while True:
            before = loop.time()
            await asyncio.sleep(period)
            now = loop.time()
            self.fieldbus_lag = max(0.0, now - before - period)
            seq += 1
            self.outbox.put_control(
                wire.down(("ping", seq, self.fieldbus_lag, time.monotonic())), latest_only=True
            )
            self._wake()
            silent = now - self._last_pong
            if self.state == "starting":  # its start may block its loop; start_timeout_s rules
                self._last_pong = now
            elif silent > self.settings.liveness_timeout_s:
                self.kill(f"liveness: its event loop has not answered for {silent:.1f} s")
            if now >= next_sample:
                next_sample = now + 1.0
                self._sample()

    def _sample(self) -> None:
        proc = self.process
        if proc is None or proc.returncode is not None:
            return
        rss, cpu = resident_bytes(proc.pid), cpu_seconds(proc.pid)
        if rss is None or cpu is None:
            return
        self.rss, self.cpu_s = rss, cpu
        self.peak_rss = max(self.peak_rss, self.rss)
        limit = self.settings.memory_limit_mb * 1024 * 1024
        if self.rss > limit:
            self.kill(
                f"memory limit: {self.rss / 2**20:.0f} MB resident, over "
                f"gateway.isolation.memory_limit_mb {self.settings.memory_limit_mb}"
            )

    # -- to the child ---------------------------------------------------------------------------
    def _wake(self) -> None:
        """Something is queued: write it in a later loop turn (never inside a CAN engine's)."""
        if not self._flush_scheduled and not self._paused and self._transport is not None:
            self._flush_scheduled = True
            asyncio.get_running_loop().call_soon(self._flush)

    def _flush(self) -> None:
        self._flush_scheduled = False
        transport = self._transport
        if transport is None or transport.is_closing():
            return
        while self.outbox.pending and not self._paused:
            frames = self.outbox.take(self.feed.snapshot, WRITE_CHUNK)
            if not frames:
                break
            transport.writelines(frames)

    def pause_writing(self) -> None:
        self._paused = True

    def resume_writing(self) -> None:
        self._paused = False
        self._wake()

    # -- from the child --------------------------------------------------------------------------
    def received(self, body: bytes) -> None:
        if len(body) > MAX_STATUS_BYTES and body.startswith(b'{"t":"status"'):
            self.protocol_errors += 1
            return
        message = wire.read_up(body)
        kind = message["t"]
        if kind == "pong":
            self._last_pong = asyncio.get_running_loop().time()
        elif kind == "status":
            self._report(message)
        elif kind == "write":
            self._write_request(message)
        elif kind == "resync":  # it fell behind in time: what is queued goes, a snapshot comes
            self.outbox.drop_for_snapshot()
            self._wake()
        elif kind == "ready":
            self._report(message)
            if self._ready is not None and not self._ready.done():
                self._ready.set_result(message)
            self._last_pong = asyncio.get_running_loop().time()
        elif kind == "failed":
            error = str(message.get("error", "failed"))[:500]
            if self._ready is not None and not self._ready.done():
                self._ready.set_exception(PluginStartError(error))
            self._reason = self._reason or error
        else:
            raise wire.WireError(f"unknown message {kind!r}")

    status_metrics: Any = None
    status_locations: Any = None

    def _report(self, message: dict[str, Any]) -> None:
        status = message.get("status")
        if isinstance(status, dict):
            self.status = status
            self.status_metrics = message.get("metrics")
            self.status_locations = message.get("locations")

    def _write_request(self, message: dict[str, Any]) -> None:
        request, values = message.get("id"), message.get("values")
        if not isinstance(request, int) or not isinstance(values, dict):
            raise wire.WireError("a write needs an integer id and a values object")
        checked: dict[str, bool | int | float | str] = {}
        for cid, value in values.items():
            # a number (JSON keeps 64-bit integers exact) or text; the image checks the rest
            if not isinstance(value, (bool, int, float, str)) or (
                isinstance(value, float) and not math.isfinite(value)
            ):
                self._ack(request, f"{cid}: {value!r} is neither a number nor text")
                return
            checked[cid] = value
        if len(self._writes) >= MAX_WRITES_WAITING:
            self._ack(request, f"more than {MAX_WRITES_WAITING} write requests waiting")
            return
        self._writes.append((request, checked))
        self._write_wake.set()

    async def _apply_writes(self) -> None:
        """One batch at a time, at most ``writes_per_s`` a second (a token bucket of one
        second's worth): a child whose clients write faster waits for its answers."""
        rate = self.settings.writes_per_s
        tokens, last = rate, time.monotonic()
        while True:
            if not self._writes:
                self._write_wake.clear()
                await self._write_wake.wait()
            now = time.monotonic()
            tokens = min(rate, tokens + (now - last) * rate)
            last = now
            if tokens < 1:
                await asyncio.sleep((1 - tokens) / rate)
                continue
            tokens -= 1
            request, values = self._writes.popleft()
            error = self._on_write(values) if self._on_write is not None else "no writes here"
            if error is None:
                self.writes_applied += 1
            else:
                self.writes_refused += 1
            self._ack(request, error)

    def _ack(self, request: int, error: str | None) -> None:
        self.outbox.put_control(wire.down(("ack", request, error)))
        self._wake()

    def send_latest(self, message: tuple[Any, ...]) -> None:
        """A control message that replaces an unsent one of its kind (the gateway's state)."""
        self.outbox.put_control(wire.down(message), latest_only=True)
        self._wake()

    # -- observability -------------------------------------------------------------------------
    def process_status(self) -> dict[str, Any]:
        proc = self.process
        return {
            "pid": proc.pid if proc is not None and proc.returncode is None else None,
            "state": self.state,
            "rss_mb": round(self.rss / 2**20, 1),
            "peak_rss_mb": round(self.peak_rss / 2**20, 1),
            "memory_limit_mb": self.settings.memory_limit_mb,
            "cpu_s": round(self.cpu_s, 2),
            "uptime_s": None
            if self.started_at is None
            else round(time.monotonic() - self.started_at, 1),
            "feed_frames": self.outbox.frames,
            "feed_bytes": self.outbox.bytes,
            "feed_queued_bytes": self.outbox.size,
            "resyncs": self.outbox.resyncs,
            "writes_applied": self.writes_applied,
            "writes_refused": self.writes_refused,
            "kills": dict(self.kills),
        }


class Spawned:
    """A child process started off the event loop and reaped by a thread of its own: a fork
    and exec from the fieldbus loop (asyncio's or uvloop's subprocess) held that loop 8-12 ms
    per restart of a child on a 70 MB process; subprocess's vfork from a worker thread holds
    it for none of that."""

    def __init__(self, popen: subprocess.Popen[bytes], loop: asyncio.AbstractEventLoop):
        self._popen = popen
        self.pid = popen.pid
        self.returncode: int | None = None
        self._done: asyncio.Future[int] = loop.create_future()
        threading.Thread(
            target=self._reap, args=(loop,), name=f"fieldgate:reap:{self.pid}", daemon=True
        ).start()

    @classmethod
    async def start(cls, args: list[str], fd: int, cpus: list[int] | None = None) -> Spawned:
        """``cpus``: where the child is born (the forking thread's CPUs: its interpreter's start
        and imports never run on the fieldbus process's CPUs)."""
        loop = asyncio.get_running_loop()
        popen = await asyncio.to_thread(_popen_on, cpus, args, fd)
        return cls(popen, loop)

    def _reap(self, loop: asyncio.AbstractEventLoop) -> None:
        code = self._popen.wait()
        try:
            loop.call_soon_threadsafe(self._finish, code)
        except RuntimeError:  # the loop is closed: nobody waits any more
            pass

    def _finish(self, code: int) -> None:
        self.returncode = code
        if not self._done.done():
            self._done.set_result(code)

    async def wait(self) -> int:
        return await asyncio.shield(self._done)

    def send_signal(self, sig: int) -> None:
        self._popen.send_signal(sig)

    def kill(self) -> None:
        self._popen.kill()


class _Link(asyncio.Protocol):
    """The socket to one child: frames in (bounded), flow control out."""

    def __init__(self, child: ChildProcess):
        self.child = child
        self.process = child.process  # this link's process (a restart makes another link)
        self.reader = wire.FrameReader(wire.MAX_UP)

    def data_received(self, data: bytes) -> None:
        try:
            for body in self.reader.feed(data):
                self.child.received(body)
        except wire.WireError as exc:
            self.child.protocol_errors += 1
            self.child.kill(f"protocol: {exc}")

    def pause_writing(self) -> None:
        self.child.pause_writing()

    def resume_writing(self) -> None:
        self.child.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        # the exit (and its code) usually follows at once: the reaper says why it ended
        asyncio.get_running_loop().call_later(1.0, self.child.channel_closed, self.process)


def _popen_on(cpus: list[int] | None, args: list[str], fd: int) -> subprocess.Popen[bytes]:
    """Popen from this (worker) thread moved onto ``cpus`` for the fork, then put back."""
    before = os.sched_getaffinity(0) if cpus else None
    if cpus:
        with contextlib.suppress(OSError):  # not available: the child pins itself or warns
            os.sched_setaffinity(0, cpus)  # this thread only; the child inherits it
    try:
        return subprocess.Popen(args, pass_fds=(fd,), stdin=subprocess.DEVNULL)
    finally:
        if before is not None:
            os.sched_setaffinity(0, before)
