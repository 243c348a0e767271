"""Running a gateway: start backs then fronts, supervise, restart with back-off, stop cleanly.

This is also the embedding API::

    gw = Gateway.load("topology.yaml", overrides={"fronts.can.interface": "virtual"})
    await gw.start()          # inside your running event loop
    gw.write("rs485/m3/do0", True)
    print(gw.read("rs485/m1/di0"))
    await gw.stop()

or ``async with Gateway.load(...) as gw: ...``.
"""

from __future__ import annotations

import asyncio
import logging
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from .backoff import Backoff
from .cancellation import raise_if_cancelled
from .events import COMPONENT_FAILED, COMPONENT_RESTARTED
from .image import Quality
from .plugin import Component, GatewayContext, PluginStartError, Registry, load_registry
from .procstat import own_process
from .simulation import SimulationBench
from .topology import Topology, load_topology

if TYPE_CHECKING:
    from .isolation.front import IsolatedFront

log = logging.getLogger("fieldgate.runtime")

# Stopping is bounded (issue 33: a gateway stops as quickly as it starts, and a component
# that does not stop never holds systemd's stop): a cancelled task is cancelled again every
# CANCEL_GRACE_S and left behind after CANCEL_ATTEMPTS; a component's stop() (a north-facing
# child's included: it has its own shorter grace, isolation.supervisor.STOP_GRACE_S) is left
# behind, logged, after STOP_TIMEOUT_S. All tasks are cancelled together, so these bound the
# whole stop, not each component's.
CANCEL_GRACE_S = 0.1
CANCEL_ATTEMPTS = 10
STOP_TIMEOUT_S = 2.0


class GatewayStartError(Exception):
    """A component could not start; the message names it and the cause in one line."""


class Gateway:
    def __init__(
        self,
        topology: Topology,
        registry: Registry,
        clock: Callable[[], float] = time.monotonic,
        *,
        simulate: bool = False,
        animate: bool = False,
    ):
        self.topology = topology
        self.bench = SimulationBench(topology, registry, animate) if simulate else None
        self.registry = registry
        # a back that finds its modules at start adds their channels then (what the topology
        # knew of them, a scan file's, is for offline tools)
        found_later = {b.name for b in topology.backs if b.finds_modules_at_start()}
        topology.channel_specs[:] = [
            s for s in topology.channel_specs if s.source.back not in found_later
        ]
        self.context = GatewayContext.build(topology, clock)
        self.image = self.context.image
        self.health = self.context.health
        self.masters = self.context.masters
        self.backs: list[Component] = []
        self.fronts: list[Component] = []
        self._tasks: dict[str, asyncio.Task[None]] = {}
        self._restarts: dict[str, int] = {}
        self.down: dict[str, str] = {}  # components waiting for a restart, with the cause
        self.running = False
        self.http: Any = (
            None  # fieldgate.isolation.front.HttpChild while gateway.http is configured
        )
        self._feed: Any = None  # fieldgate.isolation.feed.GatewayFeed, once a child needs it
        self.fieldbus_up = False  # the backs and the fieldbus fronts run
        self._on_fieldbus_up: Callable[[], None] | None = None

    @classmethod
    def load(
        cls,
        source: str | Path | dict[str, Any],
        overrides: dict[str, Any] | None = None,
        registry: Registry | None = None,
        **options: Any,
    ) -> Gateway:
        """Load a topology; ``simulate=True`` serves every back from its plugin's simulator."""
        registry = registry or load_registry()
        return cls(load_topology(source, registry, overrides), registry, **options)

    # -- life cycle -----------------------------------------------------------
    async def start(self, on_fieldbus_up: Callable[[], None] | None = None) -> None:
        """Start every back, then every fieldbus front, then the north-facing fronts (each in
        a child process, together). On any failure, stop what started and raise.

        ``on_fieldbus_up`` is called as soon as the backs and the fieldbus fronts run (the
        CANopen boot-up is on the bus), before the north-facing children are up: `fieldgate
        run` tells systemd READY then, so a restart's fieldbus downtime never waits for an
        OPC UA certificate or a broker. The HTTP server (``gateway.http``, a child process
        too) starts beside them and answers /readyz 503 until everything runs.
        """
        self._on_fieldbus_up = on_fieldbus_up
        self._ask_priority()
        for text in self.topology.warnings():
            log.warning("%s", text)
        http_started: asyncio.Future[None] | None = None
        if self.topology.gateway.http is not None and self.http is None:
            from .isolation.front import HttpChild

            self.http = HttpChild(self, self.feed(), self.topology.gateway.isolation)
            http_started = asyncio.ensure_future(self.http.start())
        try:
            await self._start_components()
        except (GatewayStartError, asyncio.CancelledError):
            if http_started is not None:
                http_started.cancel()
                await asyncio.gather(http_started, return_exceptions=True)
            await self._stop_http()
            raise
        if http_started is not None:
            try:
                await http_started
            except Exception as exc:
                await self.stop()
                raise GatewayStartError(f"HTTP status server: {exc}") from None
        self._state_changed()
        log.info(
            "gateway %s running: %d back(s), %d front(s)",
            self.topology.gateway.name,
            len(self.backs),
            len(self.fronts),
        )

    async def _start_components(self) -> None:
        if self.bench is not None:
            try:
                await self.bench.start()
            except PluginStartError as exc:
                await self.bench.stop()
                raise GatewayStartError(str(exc)) from None
        try:
            for cfg in self.topology.backs:
                self.backs.append(self._create("back", cfg))
                self.context.backs[cfg.name] = self.backs[-1]
            for front in self.topology.fronts:
                self.masters.register(front.name)
                self.fronts.append(self._create("front", front))
            for comp in self.backs + self.fronts:
                if not self._north(comp):
                    await self._start_one(comp)
            self.fieldbus_up = True
            north = sum(1 for c in self.fronts if self._north(c))
            if north:
                log.info("fieldbus side running; starting %d north-facing front(s)", north)
            if self._on_fieldbus_up is not None:
                self._on_fieldbus_up()
            # the fieldbus is up; the north-facing children start together
            results = await asyncio.gather(
                *(self._start_one(c) for c in self.fronts if self._north(c)),
                return_exceptions=True,
            )
            for result in results:
                if isinstance(result, BaseException):
                    raise result
        except GatewayStartError:
            await self._stop_components()
            if self.bench is not None:
                await self.bench.stop()
            raise
        self.running = True
        for comp in self.backs + self.fronts:
            self._tasks[comp.name] = asyncio.create_task(
                self._supervise(comp), name=f"fieldgate:{comp.name}"
            )

    def _state_changed(self) -> None:
        """Readiness or a component's state changed: the HTTP child hears it now, not at its
        next once-a-second report."""
        push = getattr(self.http, "push", None)
        if push is not None:
            push()

    def feed(self) -> Any:
        """The gateway's changes for north-facing children (created when the first needs it)."""
        if self._feed is None:
            from .isolation.feed import GatewayFeed

            self._feed = GatewayFeed(self.context)
        return self._feed

    @staticmethod
    def _north(comp: Component) -> bool:
        """A front in a child process (the isolation modules load only for a topology that
        has one: a fieldbus-only gateway does not pay their memory)."""
        front = sys.modules.get(f"{__package__}.isolation.front")
        return front is not None and isinstance(comp, front.IsolatedFront)

    def _ask_priority(self) -> None:
        from .isolation.cpus import apply_fieldbus

        apply_fieldbus(self.topology.gateway.isolation)
        nice = self.topology.gateway.isolation.fieldbus_nice
        if nice is None:
            return
        import os

        try:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
            log.info("fieldbus process runs at niceness %d", nice)
        except OSError as exc:
            log.warning(
                "gateway.isolation.fieldbus_nice %d: not allowed here (%s); running at %d",
                nice,
                exc.strerror or exc,
                os.getpriority(os.PRIO_PROCESS, 0),
            )

    def _create(self, role: str, cfg: Any) -> Component:
        ctype = self.registry.lookup(role, cfg.type)
        if ctype is None:
            raise GatewayStartError(f"{role} {cfg.name}: no plugin provides type '{cfg.type}'")
        if ctype.north:
            from .isolation.front import IsolatedFront

            return IsolatedFront(
                cfg, self.context, ctype.factory, self.feed(), self.topology.gateway.isolation
            )
        try:
            return ctype.factory(cfg, self.context)
        except PluginStartError as exc:
            raise GatewayStartError(f"{role} {cfg.name} ({cfg.type}): {exc}") from None

    async def _start_one(self, comp: Component) -> None:
        try:
            await comp.start()
        except PluginStartError as exc:
            raise GatewayStartError(
                f"{comp.kind} {comp.name} ({comp.config.type}): {exc}"
            ) from None
        except Exception as exc:
            raise GatewayStartError(
                f"{comp.kind} {comp.name} ({comp.config.type}): {type(exc).__name__}: {exc}"
            ) from exc
        comp.started = True  # type: ignore[attr-defined]

    async def _supervise(self, comp: Component) -> None:
        backoff = Backoff(comp.config.restart_backoff_s)
        loop = asyncio.get_running_loop()
        while True:
            started = loop.time()
            try:
                await comp.run()
                raise_if_cancelled()  # a run() that ended because it swallowed our cancellation
                cause = "run() returned while the gateway was running"
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                cause = f"{type(exc).__name__}: {exc}"
                log.debug("%s %s failed", comp.kind, comp.name, exc_info=True)
            self._restarts[comp.name] = self._restarts.get(comp.name, 0) + 1
            backoff.ran(loop.time() - started)
            delay = backoff.next()
            log.error("%s %s failed: %s; restarting in %.1f s", comp.kind, comp.name, cause, delay)
            self.down[comp.name] = cause
            self.context.events.publish(
                COMPONENT_FAILED, comp.name, f"{comp.kind} {comp.name} failed: {cause}"
            )
            self.image.set_quality(comp.channel_ids(), Quality.COMM_FAULT, origin=comp.name)
            self._state_changed()
            await stop_component(comp)
            while True:
                await asyncio.sleep(delay)
                try:
                    await comp.start()
                    log.info("%s %s restarted", comp.kind, comp.name)
                    self.down.pop(comp.name, None)
                    self.context.events.publish(
                        COMPONENT_RESTARTED, comp.name, f"{comp.kind} {comp.name} restarted"
                    )
                    self._state_changed()
                    break
                except asyncio.CancelledError:
                    raise
                except Exception as exc:
                    delay = backoff.next()
                    self.down[comp.name] = str(exc)
                    log.error(
                        "%s %s restart failed: %s; next try in %.1f s",
                        comp.kind,
                        comp.name,
                        exc,
                        delay,
                    )
                    await stop_component(comp)

    async def _cancel_and_stop(self, comp: Component) -> None:
        await self._cancel(comp)
        await stop_component(comp)

    async def stop(self) -> None:
        """Fronts stop, outputs go to their shutdown values, backs flush and close."""
        self.running = False  # not ready from here on (/readyz)
        self._state_changed()
        # the north-facing children stop together, beside the fieldbus fronts (each waits
        # for its child's own stop; one after the other they took seconds)
        north = [c for c in self.fronts if self._north(c)]
        stopping = asyncio.gather(*(self._cancel_and_stop(c) for c in north))
        await asyncio.gather(*(self._cancel(c) for c in self.fronts if c not in north))
        for comp in self.fronts:
            if comp not in north:
                await stop_component(comp)
        await stopping
        changed = self.image.apply_shutdown_modes()
        if changed:
            log.info("shutdown values applied to %d output(s)", len(changed))
        flushing = [
            c
            for c in self.backs
            if getattr(c, "flush_outputs", None) is not None and getattr(c, "started", False)
        ]
        await asyncio.gather(*(self._cancel(c) for c in flushing))
        await asyncio.gather(*(flush_back(c) for c in flushing))
        await self._stop_components()
        if self.bench is not None:
            await self.bench.stop()
        self.running = False
        await self._stop_http()
        log.info("gateway %s stopped", self.topology.gateway.name)

    async def _stop_http(self) -> None:
        if self.http is not None:
            http, self.http = self.http, None
            await http.stop()
        if self._feed is not None:
            self._feed.close()
            self._feed = None

    async def _cancel(self, comp: Component) -> None:
        task = self._tasks.pop(comp.name, None)
        if task is not None:
            await cancel_task(comp, task)

    async def _stop_components(self) -> None:
        await asyncio.gather(*(self._cancel(c) for c in self.fronts + self.backs))
        for comp in reversed(self.fronts + self.backs):
            if getattr(comp, "started", False):
                await stop_component(comp)
                comp.started = False  # type: ignore[attr-defined]

    async def __aenter__(self) -> Gateway:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # -- embedding API --------------------------------------------------------
    def read(self, channel_id: str) -> bool | int | float | str:
        return self.image.value(channel_id)

    def write(self, channel_id: str, value: bool | int | float | str) -> None:
        self.image.write_output(channel_id, value, origin="api")

    def restarts(self, name: str) -> int:
        """How often a front or back was restarted after a run-time failure."""
        return self._restarts.get(name, 0)

    def component(self, name: str) -> Component:
        for comp in self.fronts + self.backs:
            if comp.name == name:
                return comp
        raise KeyError(f"no front or back named {name!r}")

    def status(self) -> dict[str, Any]:
        return {
            "gateway": self.topology.gateway.name,
            "running": self.running,
            "fronts": {
                c.name: {
                    **c.status(),
                    "master_ok": self.masters.is_ok(c.name),
                    "restarts": self._restarts.get(c.name, 0),
                }
                for c in self.fronts
            },
            "backs": {
                c.name: {**c.status(), "restarts": self._restarts.get(c.name, 0)}
                for c in self.backs
            },
            "modules": [m.as_dict() for m in self.health.modules()],
            "back_errors": dict(self.health.back_errors),
            "process": own_process(),
            "children": self.children_status(),
        }

    def children_status(self) -> dict[str, dict[str, Any]]:
        """The north-facing child processes: pid, memory, CPU, feed, writes, kills."""
        children = {
            c.name: cast("IsolatedFront", c).child.process_status()
            for c in self.fronts
            if self._north(c)
        }
        child = getattr(self.http, "child", None)  # tests may run the service in this process
        if child is not None:
            children["http"] = {**child.process_status(), "restarts": self.http.restarts}
        return children


# -- stopping (module functions: bounded by the constants above) --------------------------
async def cancel_task(comp: Component, task: asyncio.Task[None]) -> None:
    """Cancel a component's task and wait for it, cancelling again while it goes on.

    A cancellation can be lost inside a library (Python 3.11's ``asyncio.wait_for``
    drops one that arrives together with the awaited result; pymodbus waits that way),
    and a stop must never hang on it: the task is cancelled again every
    ``CANCEL_GRACE_S`` and, after ``CANCEL_ATTEMPTS``, left behind with an error.
    """
    for attempt in range(1, CANCEL_ATTEMPTS + 1):
        task.cancel()
        done, _ = await asyncio.wait({task}, timeout=CANCEL_GRACE_S)
        if done:
            if not task.cancelled():
                task.exception()  # retrieved: a failure while stopping is not worth a warning at exit
            return
        log.warning(
            "%s %s: still running %.1f s after being cancelled (attempt %d); cancelling again",
            comp.kind,
            comp.name,
            CANCEL_GRACE_S * attempt,
            attempt,
        )
    log.error("%s %s does not stop when cancelled; leaving its task behind", comp.kind, comp.name)


async def stop_component(comp: Component) -> None:
    """``comp.stop()``, logged with its duration; left behind after STOP_TIMEOUT_S."""
    started = time.monotonic()
    stopping = asyncio.ensure_future(comp.stop())
    done, _ = await asyncio.wait({stopping}, timeout=STOP_TIMEOUT_S)
    if not done:
        stopping.cancel()  # not awaited: it may not end either
        log.error(
            "%s %s: still stopping after %.1f s; left behind",
            comp.kind,
            comp.name,
            STOP_TIMEOUT_S,
        )
        return
    exc = stopping.exception() if not stopping.cancelled() else None
    if exc is not None:
        log.error("%s %s: error while stopping: %s", comp.kind, comp.name, exc)
    log.debug("%s %s stopped in %.0f ms", comp.kind, comp.name, (time.monotonic() - started) * 1000)


async def flush_back(back: Component) -> None:
    """A back writes its shutdown values (each back bounds its own flush; STOP_TIMEOUT_S
    bounds one that does not)."""
    flush = getattr(back, "flush_outputs")  # noqa: B009  (not every back has it)
    try:
        await asyncio.wait_for(flush(), STOP_TIMEOUT_S)
    except TimeoutError:
        log.error("back %s: shutdown values not written within %.1f s", back.name, STOP_TIMEOUT_S)
    except Exception as exc:
        log.error("back %s: could not write shutdown values: %s", back.name, exc)
