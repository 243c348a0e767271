"""The ``dcon`` back: DCON modules on one RS-485 line, polled by core's line scheduler.

Host watchdog
-------------
Modules whose ``watchdog`` is enabled get ``~AA3EVV`` each time they come online. While
every front's master is healthy, a line job broadcasts ``~**`` (host OK) at
``host_ok_period`` (default a third of the shortest timeout). When any front reports
its master lost, the broadcast stops at once, so each module falls to its own safe
values after its timeout, whatever happens to the gateway. A module in watchdog
timeout ignores output writes (answers ``!``) until ``~AA1``: its outputs get quality
``watchdog`` and its status says so. Recovery is explicit: :meth:`DconBack.clear_watchdog`
(or :meth:`request_clear_watchdog` from synchronous code such as an SDO handler).

A front may also switch ``~**`` off altogether (:meth:`set_host_ok`, the I-7241D's
"Host OK" class attribute): watchdog-enabled modules then time out as on master loss.

Fronts reach all this through ``fieldgate.host_watchdog.HostWatchdogs`` (core), whose
protocols this back (``watchdog_settings``, ``watchdog_status``, ``set_watchdog``,
``request_clear_watchdog``, ``host_ok_enabled``, ``set_host_ok``) and its config
(``DconBackConfig.host_watchdogs``) implement: no front imports this plugin.
"""

from __future__ import annotations

import asyncio
import dataclasses
import functools
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from fieldgate.host_watchdog import ClearSteps, clear_timeout
from fieldgate.image import ChannelSpec
from fieldgate.module_info import ModuleIdentity
from fieldgate.plugin import GatewayContext, PluginStartError
from fieldgate.polling import CommError, LineJob, SerialBack
from fieldgate.serial_link import AsyncSerial
from fieldgate.topology import ModuleConfig

from .codec import BAUD_CODES, HOST_OK
from .config import DconBackConfig, DconModuleConfig
from .discovery import LineDiscovery
from .link import DconLink
from .module import DconModule

log = logging.getLogger("fieldgate.dcon")


def configured_fields(
    identity: ModuleIdentity,
) -> tuple[int | None, bool | None, int | None, int | None]:
    return identity.baudrate, identity.checksum, identity.type_code, identity.data_format


Request = tuple[Callable[[], Awaitable[Any]], "asyncio.Future[Any]"]


class DconBack(SerialBack):
    config: DconBackConfig

    def __init__(self, config: DconBackConfig, context: GatewayContext):
        super().__init__(config, context)
        self.modules: dict[int, DconModule] = {}
        self.dcon: DconLink | None = None
        self.host_ok_sent = 0
        self.host_ok_enabled = (
            True  # a front may switch ~** off (the I-7241D's Application class attribute 4)
        )
        self._requests: list[Request] = []
        self._host_ok_running = False
        self._host_ok_was_allowed = True
        self.reply_timeout_ms = config.timeout_ms  # the I-7241D's Application class attribute 3
        self.discovery = LineDiscovery(self.name, config, context, self._take_modules)
        context.masters.subscribe(self._on_master)

    # -- SerialBack -------------------------------------------------------------------
    async def start(self) -> None:
        d = self.discovery
        if self.config.auto and d.start_scan is None and d.scan_problem is None:
            await d.find_modules(self.reply_timeout_ms)
        await super().start()

    # (the discovery's state, as the tests and the status read it)
    @property
    def scan_problem(self) -> dict[str, Any] | None:
        return self.discovery.scan_problem

    @property
    def survey_done(self) -> bool:
        return self.discovery.survey_done

    @property
    def _survey_left(self) -> list[int] | None:
        return self.discovery.survey_left

    def _take_modules(self, modules: list[DconModuleConfig]) -> None:
        cfg = self.config
        cfg.modules[:] = modules
        for module in cfg.modules:
            self.register_health(module)
        self.context.add_channels(self.name, cfg.channel_specs())

    async def open_link(self) -> AsyncSerial:
        cfg = self.config
        serial = await AsyncSerial.open(
            cfg.port, cfg.baudrate, cfg.bytesize, cfg.parity, cfg.stopbits
        )
        timeout = self.reply_timeout_ms / 1000  # the topology's, or a front's since
        self.dcon = DconLink(
            serial,
            cfg.checksum,
            timeout,
            timing=dataclasses.replace(cfg.timing(), response=timeout),
            echo=cfg.echo,
        )
        for module in self.modules.values():
            module.link = self.dcon
        return serial

    async def close_link(self) -> None:
        await self.link.close()
        for _, future in self._requests:
            if not future.done():
                future.set_exception(PluginStartError("line closed"))
        self._requests.clear()

    def point_locations(self) -> dict[str, list[str]]:
        """The DCON command that reads or writes each point (status API)."""
        out: dict[str, list[str]] = {}
        for module in self.modules.values():
            out.update(module.point_locations())
        return out

    def make_module(self, config: ModuleConfig, specs: list[ChannelSpec]) -> DconModule:
        assert isinstance(config, DconModuleConfig)  # (the modules of a dcon back)
        # self.dcon is None while the port is missing at start: open_link sets module.link
        module = DconModule(
            config, specs, self.context.image, self.dcon, watch_status=not self._host_ok_allowed()
        )
        old = self.modules.get(config.address)
        if old is not None:  # a restart keeps what was learnt (identity, watchdog state)
            module.name, module.firmware, module.in_watchdog, module.watchdog_events = (
                old.name,
                old.firmware,
                old.in_watchdog,
                old.watchdog_events,
            )
            module.watchdog_enabled, module.watchdog_timeout_ms = (
                old.watchdog_enabled,
                old.watchdog_timeout_ms,
            )
        module.on_reset = self._rewrite
        self.modules[config.address] = module
        return module

    def _rewrite(self, module: DconModule) -> None:
        if self.scheduler is not None:
            self.scheduler.rewrite_outputs(module)

    def line_jobs(self) -> list[LineJob]:
        period = self.host_ok_period()
        jobs = [LineJob("requests", 0.0, self._run_request, lambda: bool(self._requests))]
        jobs.append(LineJob("host-ok", period or 1.0, self._host_ok, self._host_ok_wanted))
        return jobs + self.discovery.jobs(
            lambda: self.dcon,
            lambda: self.health.values(),
            lambda: any(m.watchdog_enabled for m in self.modules.values()),
        )

    # -- host OK ---------------------------------------------------------------------
    def host_ok_period(self) -> float | None:
        period = self.config.host_ok_period()
        timeouts = [m.watchdog_timeout_ms for m in self.modules.values() if m.watchdog_enabled]
        if timeouts:  # run-time changes (set_watchdog) may shorten it
            period = min(period or 1e9, min(timeouts) / 3000)
        return period

    def _host_ok_allowed(self) -> bool:
        return self.host_ok_enabled and self.context.masters.all_ok

    def _host_ok_wanted(self) -> bool:
        wanted = any(m.watchdog_enabled for m in self.modules.values()) and self._host_ok_allowed()
        if wanted != self._host_ok_running:
            self._host_ok_running = wanted
            if wanted:
                log.info(
                    "%s: sending ~** every %.0f ms", self.name, (self.host_ok_period() or 0) * 1000
                )
        return wanted

    async def _host_ok(self) -> None:
        assert self.dcon is not None
        await self.dcon.broadcast(HOST_OK)
        self.host_ok_sent += 1

    def _on_master(self, front: str, ok: bool, reason: str) -> None:
        if not ok and any(m.watchdog_enabled for m in self.modules.values()):
            log.warning(
                "%s: front %s lost its master (%s): ~** stopped; modules go to their safe values after their watchdog timeouts",
                self.name,
                front,
                reason,
            )
        self._host_ok_changed()

    def set_host_ok(self, enabled: bool) -> None:
        """Allow (default) or stop the ``~**`` broadcast: with it off, watchdog-enabled modules time out."""
        if bool(enabled) != self.host_ok_enabled:
            log.info(
                "%s: host OK (~**) %s by a front",
                self.name,
                "allowed" if enabled else "switched off",
            )
        self.host_ok_enabled = bool(enabled)
        self._host_ok_changed()

    def _host_ok_changed(self) -> None:
        allowed = self._host_ok_allowed()
        stopping = self._host_ok_was_allowed and not allowed
        self._host_ok_was_allowed = allowed
        for module in self.modules.values():
            module.watch_status = (
                not allowed
            )  # read ~AA0 with the inputs while modules may time out
            module.latch_after_write = not allowed and self._current_is_safe(module)
        if stopping:
            self._latch_current_outputs()
        if self.scheduler is not None:
            self.scheduler.wake()

    def _current_is_safe(self, module: DconModule) -> bool:
        """``safe_value: current`` (the I-7241D's rule) applies to this module: a watchdog, outputs,
        and no safe value of its own in the topology."""
        return (
            self.config.safe_value == "current"
            and module.config.safe_value is None
            and module.has_outputs
            and module.watchdog_enabled
        )

    def _latch_current_outputs(self) -> None:
        """The host OK stops: each module whose safe value is its current output latches it
        now, so its watchdog keeps the outputs as they are (writes from now on latch again)."""
        for module in self.modules.values():
            if not self._current_is_safe(module) or module.in_watchdog:
                continue
            try:
                future = self._submit(module.latch_safe_value)
            except PluginStartError:
                return  # not running: nothing on the line to latch
            future.add_done_callback(functools.partial(self._latched, module.address))

    def _latched(self, address: int, future: asyncio.Future[Any]) -> None:
        if not future.cancelled() and future.exception() is not None:
            log.warning(
                "%s: module %d: cannot latch its current outputs as safe values: %s",
                self.name,
                address,
                future.exception(),
            )

    # -- one-shot requests on the line (recovery, run-time watchdog settings) -------------------
    def _submit(self, action: Callable[[], Awaitable[Any]]) -> asyncio.Future[Any]:
        if self.scheduler is None or self.dcon is None or self.link is None:
            raise PluginStartError(f"back {self.name} is not running")
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._requests.append((action, future))
        self.scheduler.wake()
        return future

    async def _run_request(self) -> None:
        action, future = self._requests.pop(0)
        try:
            result = await action()
        except asyncio.CancelledError:
            future.cancel()
            raise
        except Exception as exc:
            if not future.done():
                future.set_exception(exc)
            future.exception()  # mark retrieved: fire-and-forget callers do not get asyncio warnings
        else:
            if not future.done():
                future.set_result(result)

    def module(self, address: int) -> DconModule:
        try:
            return self.modules[address]
        except KeyError:
            raise KeyError(f"back {self.name} has no module at address {address}") from None

    async def clear_watchdog(self, address: int, timeout: float = 2.0) -> bool:
        """Send ``~AA1`` to the module (the I-7231D's 0x2003 write). True when it cleared."""
        try:
            await asyncio.wait_for(self.request_clear_watchdog(address), timeout)
        except (CommError, PluginStartError, TimeoutError) as exc:
            log.warning("%s module %d: clearing the watchdog failed: %s", self.name, address, exc)
            return False
        return True

    def request_clear_watchdog(self, address: int) -> asyncio.Future[Any]:
        """Queue the clear of the module's timeout (core's sequence: ``~**`` when host OK is
        allowed, ``~AA1``, ``~AA0`` to confirm, the outputs written again); returns a future
        (callers may ignore it)."""
        module = self.module(address)

        async def clear() -> None:
            allowed = self._host_ok_allowed()
            steps = ClearSteps(
                clear=module.send_clear,
                expired=module.timeout_flag,
                rewrite_outputs=lambda: self._rewrite(module),  # back to what the image says
                host_ok=self._host_ok if allowed else None,
                without_host_ok="" if allowed else self._host_ok_off_reason(),
            )
            try:
                outcome = await clear_timeout(steps)
            except CommError as exc:
                module.last_clear = f"failed: {exc}"
                raise
            module.watchdog_cleared(outcome)

        return self._submit(clear)

    def _host_ok_off_reason(self) -> str:
        if not self.host_ok_enabled:
            return "switched off by the master (host OK attribute)"
        return "a front's master is lost"

    def set_watchdog(
        self, address: int, enabled: bool, timeout_ms: int | None = None
    ) -> asyncio.Future[Any]:
        """Change a module's host watchdog at run time (0x2001/0x2002): queues ``~AA3EVV``."""
        module = self.module(address)
        if timeout_ms is not None and not 100 <= timeout_ms <= 25_500:
            raise ValueError(f"watchdog timeout {timeout_ms} ms outside 100..25500")
        module.watchdog_enabled = enabled
        if timeout_ms is not None:
            module.watchdog_timeout_ms = timeout_ms
        elif not module.watchdog_timeout_ms:
            module.watchdog_timeout_ms = 2000
        self._retime_host_ok()
        return self._submit(module.configure_watchdog)

    def _retime_host_ok(self) -> None:
        if self.scheduler is None:
            return
        period = self.host_ok_period()
        for job in self.scheduler.jobs:
            if job.name == "host-ok" and period:
                job.period = period
                job.due = min(job.due, self.context.clock() + period)

    # -- what fronts learn of a module and may ask of it (fieldgate.module_info) -------------
    def module_identity(self, address: int) -> ModuleIdentity:
        """What ``$AAM`` and ``$AA2`` said, else what the topology says. KeyError if unknown."""
        module = self.module(address)
        reply = module.config_reply
        configured = self.config.module_identities()[address]
        if reply is None:
            return ModuleIdentity(configured.model, module.name, *configured_fields(configured))
        return ModuleIdentity(
            configured.model,
            module.name,
            BAUD_CODES.get(reply.baud_code, self.config.baudrate),
            reply.checksum,
            reply.type_code,
            reply.data_format,
        )

    def set_reply_timeout_ms(self, ms: int) -> None:
        """The reply timeout of every transaction from now on (the I-7241D's "DCON COM port
        timeout value"); ValueError outside the topology's range, 1..60000 ms."""
        if not 1 <= ms <= 60_000:
            raise ValueError(f"reply timeout {ms} ms outside 1..60000")
        if ms != self.reply_timeout_ms:
            log.info(
                "%s: reply timeout %d ms (was %d), set by a front",
                self.name,
                ms,
                self.reply_timeout_ms,
            )
        self.reply_timeout_ms = ms
        if self.dcon is not None:
            self.dcon.timeout = ms / 1000
            self.dcon.timing = dataclasses.replace(self.dcon.timing, response=ms / 1000)

    def can_latch_safe_value(self, address: int) -> bool:
        return self.module(address).has_outputs

    def request_latch_safe_value(self, address: int) -> asyncio.Future[Any]:
        """Queue the latch of the module's current outputs as its safe values."""
        module = self.module(address)
        if not module.has_outputs:
            raise ValueError(f"module {address} ({module.profile.model}) has no outputs")
        return self._submit(module.latch_safe_value)

    def watchdog_settings(self, address: int) -> tuple[bool, int]:
        """The module's host watchdog now: (enabled, timeout ms; 0 = not set). KeyError if unknown."""
        module = self.module(address)
        return bool(module.watchdog_enabled), module.watchdog_timeout_ms or 0

    def watchdog_status(self, address: int) -> bool:
        """True while the module sits in host-watchdog timeout (0x2003 != 0)."""
        return self.module(address).in_watchdog

    def status(self) -> dict[str, Any]:
        status = super().status()
        status["reply_timeout_ms"] = self.reply_timeout_ms
        self.discovery.status(status)
        period = self.host_ok_period()
        status["host_ok"] = {
            "enabled": self.host_ok_enabled,
            "period_ms": None if period is None else round(period * 1000),
            "sending": self._host_ok_running,
            "sent": self.host_ok_sent,
        }
        if self.dcon is not None:
            status["echo"] = self.dcon.echo.describe()
        status["dcon_modules"] = [
            m.status() for m in sorted(self.modules.values(), key=lambda m: m.address)
        ]
        return status
