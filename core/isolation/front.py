"""The runtime's handle on a north-facing part: a front in a child, and the HTTP child.

:class:`IsolatedFront` stands in the runtime's list of fronts for a plugin's north-facing
front: ``start()`` starts its child and returns when the front serves (or raises the
front's own start error), ``run()`` returns... never, but raises when the child ends, so
the runtime's supervision restarts it with the front's back-off; ``status()``, ``metrics()``
and ``point_locations()`` are the child's last report, with its process beside them.
Client writes are applied here, in the fieldbus process, under the one-writer rule: only
the outputs the front may write (``written_outputs()``), checked again whatever the child says.

:class:`HttpChild` runs the HTTP status server the same way and sends it the gateway's state
once a second.
"""

from __future__ import annotations

import asyncio
import fnmatch
import logging
from collections.abc import Callable
from typing import Any

from ..metric_samples import Sample, counter, gauge
from ..plugin import Front, GatewayContext
from ..topology.model import FrontConfig, IsolationSettings
from .feed import GatewayFeed
from .supervisor import ChildProcess

log = logging.getLogger("fieldgate.isolation")


class ChildEnded(Exception):
    """A north-facing child ended; the message says why (exit code, signal, liveness, memory)."""


def child_init(
    role: str, name: str, context: GatewayContext, settings: IsolationSettings, loop: str
) -> dict[str, Any]:
    """What every child gets first (the snapshot is added when the feed attaches)."""
    from ..logsetup import current_settings
    from .cpus import north_set

    level, fmt = current_settings()
    return {
        "role": role,
        "name": name,
        "topology": context.topology,
        "locations": context.point_locations(),
        "isolation": settings,
        "cpus": north_set(settings),
        "log_level": level,
        "log_format": fmt,
        "loop": loop,
    }


def loop_kind() -> str:
    try:
        loop = asyncio.get_running_loop()
    except RuntimeError:
        return "asyncio"
    return "uvloop" if type(loop).__module__.startswith("uvloop") else "asyncio"


class IsolatedFront(Front):
    def __init__(
        self,
        config: FrontConfig,
        context: GatewayContext,
        factory: Callable[[Any, GatewayContext], Any],
        feed: GatewayFeed,
        settings: IsolationSettings,
    ):
        super().__init__(config, context)
        self.factory = factory
        self.child = ChildProcess(f"front {self.name}", feed, settings, self._init, self._write)
        self._writable: frozenset[str] | None = None

    def _init(self) -> dict[str, Any]:
        init = child_init("front", self.name, self.context, self.child.settings, loop_kind())
        init.update(factory=self.factory, config=self.config)
        return init

    async def start(self) -> None:
        await self.child.start()

    async def run(self) -> None:
        raise ChildEnded(await self.child.wait())

    async def stop(self) -> None:
        await self.child.stop()

    # -- client writes, applied here ----------------------------------------------------------
    def writable(self) -> frozenset[str]:
        """The outputs this front may write: those it serves that its ``written_outputs()`` name."""
        if self._writable is None:
            served = [c for c in self.context.front_channels(self.config) if c.kind.is_output]
            patterns = self.config.written_outputs()
            self._writable = frozenset(
                c.id
                for c in served
                if patterns is None or any(fnmatch.fnmatchcase(c.id, p) for p in patterns)
            )
        return self._writable

    def _write(self, values: dict[str, bool | int | float | str]) -> str | None:
        allowed = self.writable()
        for cid in values:
            if cid not in allowed:
                return f"{cid} is not an output front {self.name} may write"
        try:
            self.context.image.write_outputs(values, origin=self.name)
        except (KeyError, ValueError) as exc:
            return str(exc.args[0]) if exc.args else str(exc)
        return None

    # -- observability ---------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        return {**self.child.status, "process": self.child.process_status()}

    def metrics(self) -> list[Sample]:
        rows: list[Sample] = []
        for sample in self.child.status_metrics or []:
            if isinstance(sample, list) and len(sample) == 5:
                # the child's samples as it sent them: /metrics checks each (check_sample)
                rows.append(tuple(sample))
        return rows + child_metrics(self.child, front=self.name)

    def point_locations(self) -> dict[str, list[str]]:
        places = self.child.status_locations or self.child.ready.get("locations") or {}
        return places if isinstance(places, dict) else {}


def child_metrics(child: ChildProcess, **labels: str) -> list[Sample]:
    """The child process's own series, as one component's samples (with ``labels``)."""
    rows = [
        gauge("child_resident_bytes", "resident memory of a north-facing child", child.rss),
        gauge(
            "child_memory_limit_bytes",
            "memory limit of a north-facing child (gateway.isolation.memory_limit_mb)",
            child.settings.memory_limit_mb * 2**20,
        ),
        counter("child_cpu_seconds_total", "CPU time of a north-facing child", child.cpu_s),
        counter(
            "child_resyncs_total",
            "times a north-facing child fell behind the image and got a fresh snapshot",
            child.outbox.resyncs,
        ),
        counter(
            "child_feed_bytes_total", "bytes of gateway state sent to a child", child.outbox.bytes
        ),
        counter(
            "child_writes_applied_total",
            "client write batches a child sent that the image applied",
            child.writes_applied,
        ),
        counter(
            "child_writes_refused_total",
            "client write batches a child sent that were refused",
            child.writes_refused,
        ),
    ] + [
        counter("child_kills_total", "times a child was killed, by cause", n, cause=cause)
        for cause, n in sorted(child.kills.items())
    ]
    return [(name, kind, text, value, {**tags, **labels}) for name, kind, text, value, tags in rows]


class HttpChild:
    """The HTTP status server in a child process, restarted with back-off when it ends."""

    def __init__(self, gateway: Any, feed: GatewayFeed, settings: IsolationSettings):
        self.gateway = gateway
        self.child = ChildProcess("http", feed, settings, self._init, None)
        self.restarts = 0
        self.url = ""
        self._task: asyncio.Task[None] | None = None

    def _init(self) -> dict[str, Any]:
        init = child_init("http", "http", self.gateway.context, self.child.settings, loop_kind())
        if self.url:  # a restart listens where the first one did (port 0 picked one)
            init["listen"] = self.url.split("://", 1)[1].rstrip("/")
        return init

    async def start(self) -> None:
        await self._start()
        self._task = asyncio.get_running_loop().create_task(
            self._keep(), name="fieldgate:http-child"
        )

    async def _start(self) -> None:
        ready = await self.child.start()
        self.url = str(ready.get("status", {}).get("url", ""))

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
            self._task = None
        await self.child.stop()

    def push(self) -> None:
        """Send the gateway's state now (readiness or a component changed)."""
        if self.child.state == "running":
            self._push()

    def _push(self) -> None:
        from .remote import gateway_state

        try:
            state = gateway_state(self.gateway, self.gateway.children_status())
        except Exception:  # never the fieldbus side's failure
            log.exception("http: the gateway's state could not be gathered")
            return
        self.child.send_latest(("gw", state))

    async def _keep(self) -> None:
        from ..backoff import Backoff
        from .remote import PERIOD_S

        backoff = Backoff(1.0)
        while True:
            ended = asyncio.ensure_future(self.child.wait())
            while not ended.done():
                await asyncio.wait({ended}, timeout=PERIOD_S)
                if not ended.done():
                    self._push()
            log.error("the HTTP status server's %s; restarting it", ended.result())
            await self.child.stop()
            while True:
                await asyncio.sleep(backoff.next())
                try:
                    await self._start()
                    self.restarts += 1
                    break
                except Exception as exc:  # noqa: BLE001  (one line, try again later)
                    log.error("the HTTP status server could not restart: %s", exc)
