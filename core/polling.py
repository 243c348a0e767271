"""The polling engine every RS-485 back end shares (Modbus RTU, DCON, third parties).

A back-end plugin supplies only its codec and module profiles:

* a :class:`PolledModule` subclass per module kind, whose ``read_inputs`` and
  ``send_outputs`` perform transactions over the plugin's link and raise
  :class:`CommError` on failure;
* a :class:`SerialBack` subclass that opens and closes the link and makes the modules.

Core does the rest, once for all protocols: one :class:`LineScheduler` per serial line
(one transaction at a time, writes ahead of reads, per-module poll periods,
write-on-change with optional cyclic rewrite, periodic line jobs such as a host
watchdog), the module health model (error counters, offline after consecutive
failures, slow re-probe of offline modules, recovery), input quality (stale after a
failed read, comm fault while offline) and per-line statistics.

Port loss: a link raises :class:`LineLost` when the port itself is gone (a USB-RS485
adapter pulled out, a pseudo-terminal hung up: reads fail with EIO, writes fail). The
scheduler then marks every module of the line offline at once (COMM_FAULT, the health
OFFLINE event fronts turn into EMCY / DeviceNet status) instead of letting each module
time out ``fail_threshold`` times, and :class:`SerialBack` closes the port and re-opens
the same path with back-off (:data:`REOPEN_FIRST_S` doubling up to the back's
``offline_probe_ms``); once open, every module is probed at once and comes back online
with its first good answer. No gateway restart, no component restart.

A port missing at start (:class:`~fieldgate.plugin.PortUnavailable`: no such device, busy)
is the same loss, from the start: the back starts without it (its modules offline,
COMM_FAULT), so the fronts start and the CAN node boots; the port is re-opened with the
same back-off. While a port is missing the back reports it in ``context.health``'s port
state (``port_state``, a CANopen front's EMCY "COM port access error") and publishes
``port-lost`` / ``port-back`` events.
"""

from __future__ import annotations

import asyncio
import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from .cancellation import raise_if_cancelled
from .events import PORT_BACK, PORT_LOST
from .health import ErrorKind, LineStats, ModuleHealth
from .image import Change, ChannelSpec, ProcessImage, Quality, Subscription
from .plugin import Back, GatewayContext, PortUnavailable
from .topology.model import ModuleConfig, SerialBackConfig

log = logging.getLogger("fieldgate.polling")

Reading = Any  # a value, or (value, Quality) for module-reported quality

NOTHING_DUE: dict[str, Any] = {}
"""Returned by ``read_inputs`` when it made no transaction (none of its groups was due):
the scheduler then records neither a success nor a request. Compared by identity."""


class CommError(Exception):
    """A transaction failed. ``kind`` says how; the text is for logs and status."""

    def __init__(self, kind: ErrorKind, text: str):
        super().__init__(text)
        self.kind = kind


class LineLost(CommError):
    """The serial port itself is gone (device node removed, hang-up, EIO): no module on the
    line can answer until the port is re-opened."""

    def __init__(self, text: str):
        super().__init__(ErrorKind.IO, text)


REOPEN_FIRST_S = 0.1
"""First delay before re-opening a lost port; doubles up to the back's offline_probe_ms."""


class PolledModule(ABC):
    """One module on a line, as its back-end plugin speaks to it."""

    def __init__(self, config: ModuleConfig, specs: list[ChannelSpec]):
        self.config = config
        self.address = config.address
        self.specs = specs
        self.inputs = [s.id for s in specs if not s.kind.is_output]
        self.outputs = [s.id for s in specs if s.kind.is_output]

    @abstractmethod
    async def read_inputs(self) -> dict[str, Reading]:
        """Read the input channels that are due; returns {channel id: value or (value, Quality)},
        or :data:`NOTHING_DUE` when no transaction was made."""

    async def send_outputs(self, values: dict[str, Any]) -> None:
        """Send the given output channels to the module (their current process-image values)."""
        if values:
            raise NotImplementedError(f"{type(self).__name__} has outputs but no send_outputs()")

    async def probe(self) -> None:
        """Check the module answers (used while it is offline). Default: read its inputs."""
        await self.read_inputs()

    async def on_online(self) -> None:  # noqa: B027  (an optional hook: by default nothing to do)
        """Called after the first successful contact and after each recovery (configure watchdogs...)."""

    def output_quality(self) -> Quality:
        """Quality of this module's outputs after a good poll (WATCHDOG while the module ignores writes)."""
        return Quality.GOOD


@dataclass
class LineJob:
    """A periodic transaction that is not a module poll (DCON ``~**`` host-OK, ...)."""

    name: str
    period: float
    action: Callable[[], Awaitable[None]]
    enabled: Callable[[], bool] = lambda: True
    due: float = 0.0


class _ModuleState:
    def __init__(self, module: PolledModule, health: ModuleHealth, period: float):
        self.module = module
        self.health = health
        self.period = period
        self.due = 0.0
        self.dirty: set[str] = set()
        self.contacted = False  # on_online() ran since the last loss of contact
        self.burst_logged = False


class LineScheduler:
    """Runs the transactions of one serial line, one at a time."""

    def __init__(
        self,
        name: str,
        modules: list[PolledModule],
        image: ProcessImage,
        health: dict[int, ModuleHealth],
        *,
        poll_period: float = 0.1,
        offline_probe_period: float = 5.0,
        write_period: float | None = None,
        retries: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.name = name
        self.image = image
        self.clock = clock
        self.offline_probe_period = offline_probe_period
        self.write_period = write_period
        self.retries = retries
        self.stats = LineStats(name)
        self.jobs: list[LineJob] = []
        self._states = [
            _ModuleState(
                m, health[m.address], (m.config.poll_ms / 1000) if m.config.poll_ms else poll_period
            )
            for m in modules
        ]
        self._by_output = {cid: st for st in self._states for cid in st.module.outputs}
        self._wake = asyncio.Event()
        self._subscription: Subscription | None = None
        self._cycle_start: float | None = None
        self._cycle_seen: set[int] = set()
        self._next_rewrite = 0.0

    # -- outputs --------------------------------------------------------------
    def attach(self) -> None:
        """Subscribe to output changes (write-on-change)."""
        if self._subscription is None and self._by_output:
            self._subscription = self.image.subscribe_batch(
                self._on_output_changes, ids=self._by_output
            )

    def detach(self) -> None:
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None

    def _on_output_changes(self, changes: list[Change]) -> None:
        dirty = False
        for change in changes:
            if change.value_changed:
                cid = change.id
                self._by_output[cid].dirty.add(cid)
                dirty = True
        if dirty:
            self._wake.set()

    def mark_all_outputs_dirty(self) -> None:
        for st in self._states:
            st.dirty.update(st.module.outputs)
        self._wake.set()

    def rewrite_outputs(self, module: PolledModule) -> None:
        """Queue a rewrite of the module's outputs that a front (or the config) has set,
        e.g. after the module was reset behind the poller's back."""
        for st in self._states:
            if st.module is module:
                st.dirty.update(
                    cid
                    for cid in module.outputs
                    if self.image[cid].written_by or self.image[cid].spec.initial is not None
                )
        self._wake.set()

    @property
    def pending_writes(self) -> int:
        return sum(len(st.dirty) for st in self._states)

    # -- scheduling -----------------------------------------------------------
    def add_job(self, job: LineJob) -> None:
        self.jobs.append(job)
        self._wake.set()

    def wake(self) -> None:
        """Re-evaluate what is due now (a job became enabled, a one-shot request was queued)."""
        self._wake.set()

    async def run(self) -> None:
        self.attach()
        try:
            while True:
                deadline = await self.step()
                raise_if_cancelled()  # pymodbus may have swallowed ours (see fieldgate.cancellation)
                if deadline is None:
                    await asyncio.sleep(0)  # a step that did no real I/O must not starve the loop
                    continue
                delay = deadline - self.clock()
                if delay > 0:
                    self._wake.clear()
                    try:
                        async with asyncio.timeout(delay):  # not wait_for: see AsyncSerial._wait
                            await self._wake.wait()
                    except TimeoutError:
                        pass
        finally:
            self.detach()

    async def step(self) -> float | None:
        """Do the one most urgent transaction, if any is due.

        Returns None after doing work (call again at once), else the time of the next
        due work. Tests call it directly with a fake clock.
        """
        now = self.clock()
        if self.write_period is not None and now >= self._next_rewrite:
            self._next_rewrite = now + self.write_period
            for st in self._states:
                if st.health.online:
                    st.dirty.update(st.module.outputs)
        for st in self._states:  # writes ahead of reads, for modules that answer
            if st.dirty and (st.health.online or st.due <= now):
                await self._send_dirty_outputs(st)
                return None
        for job in self.jobs:
            if job.due <= now and job.enabled():
                await self._job(job)
                return None
        due_state = min(self._states, key=lambda s: s.due, default=None)
        if due_state is not None and due_state.due <= now:
            await self._poll(due_state)
            return None
        candidates = [s.due for s in self._states] + [j.due for j in self.jobs if j.enabled()]
        if self.write_period is not None:
            candidates.append(self._next_rewrite)
        return min(candidates, default=now + 1.0)

    # -- transactions ---------------------------------------------------------
    async def _attempt(
        self, st: _ModuleState, action: Callable[[], Awaitable[Any]]
    ) -> tuple[bool, Any]:
        """Run one transaction with retries; record health. Returns (ok, result)."""
        for _attempt in range(self.retries + 1):
            started = self.clock()
            self.stats.requests += 1
            try:
                result = await action()
            except LineLost as exc:
                self.line_lost(str(exc))
                raise
            except CommError as exc:
                self._failed(st, exc.kind, str(exc))
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # codec bug or port failure: count it, never stop the line
                log.debug(
                    "line %s module %d: unexpected error",
                    self.name,
                    st.module.address,
                    exc_info=True,
                )
                self._failed(st, ErrorKind.IO, f"{type(exc).__name__}: {exc}")
            else:
                if result is NOTHING_DUE:
                    self.stats.requests -= 1
                    return True, result
                came_back = st.health.record_success(self.clock() - started, self.clock())
                if st.burst_logged:
                    log.info("line %s module %d answers again", self.name, st.module.address)
                st.burst_logged = False
                if came_back or not st.contacted:
                    st.contacted = True
                    await self._on_online(st)
                return True, result
            if not st.health.online:
                break  # no retries for a module already offline
        return False, None

    async def _on_online(self, st: _ModuleState) -> None:
        try:
            await st.module.on_online()
        except LineLost as exc:
            self.line_lost(str(exc))
            raise
        except CommError as exc:
            self._failed(st, exc.kind, f"on_online: {exc}")
        except Exception as exc:
            self._failed(st, ErrorKind.IO, f"on_online: {type(exc).__name__}: {exc}")
        if st.health.online:  # bring the module up to date with what fronts (or the config) set
            st.dirty.update(
                cid
                for cid in st.module.outputs
                if self.image[cid].written_by or self.image[cid].spec.initial is not None
            )

    def line_lost(self, text: str) -> None:
        """The port is gone: every module of the line is offline now, whatever its count."""
        self.stats.errors[ErrorKind.IO] += 1
        self.stats.port_losses += 1
        log.warning("line %s: port lost (%s): all modules COMM_FAULT", self.name, text)
        for st in self._states:
            st.contacted = False
            st.burst_logged = True  # one line for the whole line, not one per module
            if st.health.record_line_loss(text):
                self.image.set_quality(st.module.inputs, Quality.COMM_FAULT)
                self.image.set_quality(st.module.outputs, Quality.COMM_FAULT)

    def line_reopened(self) -> None:
        """The port is open again: probe every module and run every job now."""
        now = self.clock()
        for st in self._states:
            st.due = now
        for job in self.jobs:
            job.due = now
        self._wake.set()

    def _failed(self, st: _ModuleState, kind: ErrorKind, text: str) -> None:
        self.stats.errors[kind] += 1
        if not st.burst_logged:
            log.warning("line %s module %d: %s: %s", self.name, st.module.address, kind, text)
            st.burst_logged = True
        else:
            log.debug("line %s module %d: %s: %s", self.name, st.module.address, kind, text)
        went_offline = st.health.record_failure(kind, text)
        if went_offline:
            st.contacted = False
            self.image.set_quality(st.module.inputs, Quality.COMM_FAULT)
            self.image.set_quality(st.module.outputs, Quality.COMM_FAULT)
        elif st.health.online:
            stale = [cid for cid in st.module.inputs if self.image[cid].quality is Quality.GOOD]
            self.image.set_quality(stale, Quality.STALE)

    async def _poll(self, st: _ModuleState) -> None:
        started = self.clock()
        if st.health.online:
            ok, readings = await self._attempt(st, st.module.read_inputs)
        else:
            ok, _ = await self._attempt(st, st.module.probe)
            readings = None
            if ok and st.module.inputs:
                ok, readings = await self._attempt(st, st.module.read_inputs)
        if ok and readings:
            self.image.update_inputs(readings, timestamp=self.clock())
        if ok and st.module.outputs:
            quality = st.module.output_quality()
            self.image.set_quality(
                [c for c in st.module.outputs if self.image[c].quality is not quality], quality
            )
        st.due = started + (st.period if st.health.online else self.offline_probe_period)
        self._count_cycle(st)

    async def _send_dirty_outputs(self, st: _ModuleState) -> None:
        ids, st.dirty = st.dirty, set()
        values = {cid: self.image.value(cid) for cid in st.module.outputs if cid in ids}
        try:
            ok, _ = await self._attempt(st, lambda: st.module.send_outputs(values))
        except LineLost:
            st.dirty |= ids  # written once the port is back
            raise
        self.stats.writes += 1
        if not ok:
            st.dirty |= ids  # keep them for the next chance
            if not st.health.online:
                st.due = max(st.due, self.clock() + self.offline_probe_period)

    async def _job(self, job: LineJob) -> None:
        job.due = self.clock() + job.period
        self.stats.requests += 1
        try:
            await job.action()
        except asyncio.CancelledError:
            raise
        except LineLost as exc:
            self.line_lost(str(exc))
            raise
        except Exception as exc:
            self.stats.errors[ErrorKind.IO] += 1
            log.debug("line %s job %s failed: %s", self.name, job.name, exc)

    def _count_cycle(self, st: _ModuleState) -> None:
        now = self.clock()
        if self._cycle_start is None:
            self._cycle_start = now
        self._cycle_seen.add(st.module.address)
        online = {s.module.address for s in self._states if s.health.online}
        if online <= self._cycle_seen:
            self.stats.cycles += 1
            self.stats.last_cycle_time = now - self._cycle_start
            self._cycle_start, self._cycle_seen = now, set()

    def status(self) -> dict[str, Any]:
        return {
            **self.stats.as_dict(),
            "pending_writes": self.pending_writes,
            "modules": [s.health.as_dict() for s in self._states],
        }


class SerialBack(Back):
    """A back end that polls modules over one serial line with the shared scheduler.

    Subclasses implement :meth:`open_link`, :meth:`close_link` and :meth:`make_module`.
    """

    config: SerialBackConfig

    def __init__(self, config: SerialBackConfig, context: GatewayContext):
        super().__init__(config, context)
        self.link: Any = None
        self.scheduler: LineScheduler | None = None
        self.port: dict[str, Any] = {
            "lost": False,
            "losses": 0,
            "reopen_attempts": 0,
            "last_outage_s": None,
        }
        self.health: dict[int, ModuleHealth] = {}
        self._missing_at_start: str | None = None
        for module in config.modules:
            self.register_health(module)

    def register_health(self, module: ModuleConfig) -> None:
        """The module's health entry (a back that finds its modules at start calls it then)."""
        self.health[module.address] = self.context.health.add(
            ModuleHealth(self.name, module.address, module.model or "", self.config.fail_threshold)
        )

    @abstractmethod
    async def open_link(self) -> Any:
        """Open the serial port (or URL). Raise PluginStartError with the cause on failure."""

    @abstractmethod
    async def close_link(self) -> None: ...

    @abstractmethod
    def make_module(self, config: ModuleConfig, specs: list[ChannelSpec]) -> PolledModule: ...

    def line_jobs(self) -> list[LineJob]:
        """Periodic line-level transactions (host watchdog...). Default: none."""
        return []

    def unopened_link(self) -> Any:
        """The link while the port is missing at start, for :meth:`make_module` (a back whose
        modules keep a link object returns one to open later). Default: None."""
        return None

    async def start(self) -> None:
        try:
            self.link = await self.open_link()
        except PortUnavailable as exc:  # start anyway: the modules offline, the port re-tried
            self._missing_at_start = str(exc)
            self.link = self.unopened_link()
        specs = [s for s in self.context.topology.channel_specs if s.source.back == self.name]
        modules = [
            self.make_module(m, [s for s in specs if s.source.module == m.address])
            for m in self.config.modules
        ]
        cfg = self.config
        self.scheduler = LineScheduler(
            self.name,
            modules,
            self.context.image,
            self.health,
            poll_period=cfg.poll_ms / 1000,
            offline_probe_period=cfg.offline_probe_ms / 1000,
            write_period=None if cfg.write_period_ms is None else cfg.write_period_ms / 1000,
            retries=cfg.retries,
            clock=self.context.clock,
        )
        for job in self.line_jobs():
            self.scheduler.add_job(job)
        self.scheduler.attach()  # outputs written by fronts from now on are queued
        if self._missing_at_start is not None:
            log.warning(
                "line %s: %s; started without it: its modules are offline until it opens "
                "(re-tried every %.1f s at most)",
                self.name,
                self._missing_at_start,
                max(REOPEN_FIRST_S, cfg.offline_probe_ms / 1000),
            )
            self.port["lost"] = True
            self.scheduler.line_lost(self._missing_at_start)
            self._report_port(False, self._missing_at_start)

    async def reopen_link(self) -> None:
        """Open the port again after a loss (the link was closed). Default: a new
        :meth:`open_link`; a back whose modules keep a reference to the link re-opens it
        in place instead."""
        self.link = await self.open_link()

    async def run(self) -> None:
        assert self.scheduler is not None
        if self._missing_at_start is not None:
            cause, self._missing_at_start = self._missing_at_start, None
            await self._recover_line(cause, opened=False)
        while True:
            try:
                await self.scheduler.run()
            except LineLost as exc:
                await self._recover_line(str(exc))

    def _report_port(self, ok: bool, text: str) -> None:
        self.context.health.port_state(self.name, ok, text)
        self.context.events.publish(
            PORT_BACK if ok else PORT_LOST,
            self.name,
            f"port {self.config.port} {'open again' if ok else 'missing'}: {text}",
            port=self.config.port,
        )

    async def _recover_line(self, cause: str, opened: bool = True) -> None:
        """Close the lost port (``opened``), re-open the same path with back-off, then probe
        every module."""
        assert self.scheduler is not None
        lost_at = self.context.clock()
        self.port["losses"] += 1
        self.port["lost"] = True
        if opened:
            self._report_port(False, cause)
            try:
                await self.close_link()
            except Exception as exc:  # a port that is gone may fail to close: it is closed anyway
                log.debug("line %s: closing the lost port: %s", self.name, exc)
        delay, cap = REOPEN_FIRST_S, max(REOPEN_FIRST_S, self.config.offline_probe_ms / 1000)
        while True:
            await self.sleep(delay)
            self.port["reopen_attempts"] += 1
            try:
                await self.reopen_link()
                break
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                log.debug("line %s: re-open failed: %s; next try in %.1f s", self.name, exc, delay)
                delay = min(delay * 2, cap)
        self.port["lost"] = False
        self.port["last_outage_s"] = round(self.context.clock() - lost_at, 3)
        self._report_port(True, f"after {self.port['last_outage_s']:.1f} s")
        log.warning(
            "line %s: port %s re-opened after %.1f s (%s)",
            self.name,
            self.config.port,
            self.port["last_outage_s"],
            cause,
        )
        self.scheduler.line_reopened()

    async def sleep(self, seconds: float) -> None:
        """The re-open back-off's wait (tests replace it)."""
        await asyncio.sleep(seconds)

    async def flush_outputs(self, timeout: float = 2.0) -> None:
        """Write pending outputs (shutdown values) before the line closes."""
        if self.scheduler is None or self.link is None:
            return
        deadline = self.context.clock() + timeout
        while self.scheduler.pending_writes and self.context.clock() < deadline:
            await self.scheduler.step()

    async def stop(self) -> None:
        if self.scheduler is not None:
            self.scheduler.detach()
        if self.link is not None:
            try:
                await self.close_link()
            finally:
                self.link = None

    def status(self) -> dict[str, Any]:
        if self.scheduler is None:
            return {"line": self.name, "running": False}
        return {**self.scheduler.status(), "port": dict(self.port)}
