"""The child side: ``python -m fieldgate.isolation.child FD``.

Reads its first message (what to serve: the topology, its part, the gateway's snapshot,
the isolation settings) from the socket the fieldbus process passed as ``FD``, lowers its
own priority, dies with its parent, logs within a budget, and serves its part against a
:class:`~.mirror.MirrorContext` until the fieldbus process says stop or goes away:

* ``front``: a north-facing front built by its plugin's factory, unchanged;
* ``http``: the HTTP status server on a mirror of the gateway (:mod:`.remote`).

Every second it reports its part's status, metrics and point locations.
"""

from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import json
import logging
import os
import signal
import socket
import sys
import time
from typing import Any

from ..logsetup import LogBudget, setup_logging
from ..plugin import one_line
from . import wire
from .cpus import apply_north
from .mirror import MirrorContext
from .parts import Part, make_part

log = logging.getLogger("fieldgate.isolation.child")

STATUS_PERIOD_S = 1.0
PART_STOP_S = 1.0  # how long the part's stop() may take (supervisor.STOP_GRACE_S is longer)
STATUS_LIMIT = 256 * 1024  # bytes of one status report (the fieldbus process drops larger ones)
PR_SET_PDEATHSIG = 1


def _read_frame(sock: socket.socket) -> bytes:
    def exactly(n: int) -> bytes:
        data = bytearray()
        while len(data) < n:
            chunk = sock.recv(n - len(data))
            if not chunk:
                raise EOFError("the fieldbus process closed the channel")
            data += chunk
        return bytes(data)

    (size,) = wire.HEADER.unpack(exactly(wire.HEADER.size))
    return exactly(size)


def _die_with_parent(parent: int) -> None:
    """SIGKILL when the fieldbus process dies (Linux), however it dies."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # it died before prctl
        os._exit(0)


def main(argv: list[str]) -> int:
    parent = os.getppid()
    sock = socket.socket(fileno=int(argv[0]))
    init: dict[str, Any] = wire.read_down(_read_frame(sock))
    _die_with_parent(parent)
    settings = init["isolation"]
    apply_north(init.get("cpus"))
    try:
        os.nice(settings.nice)
    except OSError:
        pass
    # Ctrl-C on a terminal, or systemd's SIGTERM to the whole control group: the fieldbus
    # process stops us through the channel (and PR_SET_PDEATHSIG when it dies)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    budget = LogBudget(settings.log_lines_per_minute)
    setup_logging(
        init["log_level"],
        init["log_format"],
        budget=budget,
        prefix=f"{init['name']}[{os.getpid()}] ",
    )
    runner = asyncio.Runner(loop_factory=_loop_factory(init.get("loop", "asyncio")))
    code = runner.run(Child(sock, init, budget).serve())
    # The part has stopped and said its last word on the channel. Exit now: the runner's
    # close would join worker threads (paho's blocking connect to a broker that does not
    # answer: seconds) and the interpreter's teardown of a large heap took 100-500 ms
    # (asyncua's) on a busy host, while the fieldbus process waits for this exit.
    logging.shutdown()  # the log's last lines are written
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _loop_factory(name: str) -> Any:
    if name == "uvloop":
        try:
            import uvloop

            return uvloop.new_event_loop
        except ImportError:
            pass
    return asyncio.new_event_loop


class Child:
    def __init__(self, sock: socket.socket, init: dict[str, Any], budget: LogBudget):
        self.sock = sock
        self.init = init
        self.budget = budget
        self.writer: asyncio.StreamWriter | None = None
        self.context: MirrorContext | None = None
        self.part: Part | None = None
        self.stopping = asyncio.Event()
        self.max_lag_s = float(init["isolation"].feed_max_lag_ms) / 1000
        self.behind = False  # asked for a snapshot, skipping changes until it comes
        self.skipped = 0
        self.resyncs_asked = 0

    def send(self, message: dict[str, Any]) -> None:
        if self.writer is not None and not self.writer.is_closing():
            self.writer.write(wire.up(message))

    async def serve(self) -> int:
        reader, self.writer = await asyncio.open_unix_connection(sock=self.sock)
        init = self.init
        context = self.context = MirrorContext(init["topology"], self.send, init["locations"])
        context.apply(init["snapshot"])
        listen = asyncio.create_task(self._listen(reader), name="fieldgate:child:listen")
        try:
            part = self.part = make_part(init, context)
            await part.start()
        except Exception as exc:
            log.debug("cannot start", exc_info=True)
            self.send({"t": "failed", "error": _start_error(exc)})
            await self._drain()
            listen.cancel()
            return 1
        self.send({"t": "ready", **self._report()})
        run = asyncio.create_task(part.run(), name="fieldgate:child:run")
        report = asyncio.create_task(self._report_loop(), name="fieldgate:child:status")
        stop = asyncio.create_task(self.stopping.wait())
        done, _ = await asyncio.wait({run, listen, stop}, return_when=asyncio.FIRST_COMPLETED)
        code = 0
        if run in done and not run.cancelled() and run.exception() is not None:
            error = run.exception()
            assert error is not None
            log.error("stopped: %s", one_line(error))
            self.send({"t": "failed", "error": one_line(error)})
            code = 1
        for task in (run, report, stop, listen):
            task.cancel()
        try:
            await asyncio.wait_for(part.stop(), PART_STOP_S)
        except Exception as exc:  # noqa: BLE001  (stopping: say it, exit anyway)
            log.warning("error while stopping: %s", one_line(exc))
        context.fail_writes("the child is stopping")
        await self._drain()
        return code

    async def _drain(self) -> None:
        if self.writer is not None:
            try:
                await asyncio.wait_for(self.writer.drain(), 1.0)
            except (Exception, asyncio.CancelledError):
                pass

    async def _listen(self, reader: asyncio.StreamReader) -> None:
        assert self.context is not None
        try:
            while True:
                header = await reader.readexactly(wire.HEADER.size)
                (size,) = wire.HEADER.unpack(header)
                body = await reader.readexactly(size)
                if self.behind and body[0] in wire.DATA_KINDS:
                    self.skipped += 1  # a snapshot is on its way: this change is in it
                    continue
                message = wire.read_down(body)
                kind = message[0]
                if kind == "ping":
                    self._pinged(message)
                elif kind == "stop":
                    self.stopping.set()
                    return
                elif kind == "gw" and self.part is not None:
                    self.part.gateway_state(message[1])
                else:
                    if kind == "snap":
                        self.behind = False
                    self.context.apply(message)
                    if kind == "chg":
                        # one batch, one loop turn, as in the fieldbus process: a front that
                        # publishes once per turn (Sparkplug) sends each batch on its own
                        await asyncio.sleep(0)
        except (asyncio.IncompleteReadError, ConnectionError):
            log.info("the fieldbus process closed the channel: stopping")
            self.stopping.set()

    def _pinged(self, message: tuple[Any, ...]) -> None:
        """A ping carries the time the fieldbus process sent it: a child that reads it more
        than ``max_lag_s`` later is behind, asks for a snapshot and skips the changes queued
        before it (the snapshot holds them)."""
        _, seq, lag, sent = message
        assert self.context is not None
        now = time.monotonic()
        self.context.fieldbus_lag = lag
        self.context.last_ping = now
        self.send({"t": "pong", "seq": seq})
        if not self.behind and now - sent > self.max_lag_s:
            self.behind = True
            self.resyncs_asked += 1
            self.send({"t": "resync", "lag_s": round(now - sent, 3)})

    async def _report_loop(self) -> None:
        while True:
            await asyncio.sleep(STATUS_PERIOD_S)
            try:
                self.send({"t": "status", **self._report()})
            except Exception:  # a report that cannot be made: say it once a minute at most
                log.exception("status report failed")

    def _report(self) -> dict[str, Any]:
        assert self.part is not None
        report = self.part.report()
        status = report.setdefault("status", {})
        status["log_lines_left_out"] = self.budget.suppressed_total
        status["feed_changes_skipped"] = self.skipped
        body = json.dumps(report, default=str)
        if len(body) > STATUS_LIMIT:  # many clients with long names: keep the counters
            report["status"].pop("clients", None)
            report["status"]["clients_left_out"] = "report too large"
            report["locations"] = {}
        return report


def _start_error(exc: BaseException) -> str:
    from ..plugin import PluginStartError

    return str(exc) if isinstance(exc, PluginStartError) else one_line(exc)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
