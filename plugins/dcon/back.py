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
from fieldgate.image import ChannelSpec, Kind
from fieldgate.module_info import ModuleIdentity
from fieldgate.plugin import GatewayContext, PluginStartError, PortUnavailable
from fieldgate.polling import CommError, LineJob, SerialBack
from fieldgate.serial_link import AsyncSerial
from fieldgate.topology import ModuleConfig

from .autoscan import (
    NothingFound,
    StartScan,
    expected_modules,
    find_modules,
    previous_start,
    verified,
)
from .codec import BAUD_CODES, HOST_OK
from .config import DconBackConfig, DconModuleConfig, parse_addresses
from .link import DconLink
from .module import DconModule
from .profiles import AIDIO, AO_SINGLE
from .scan import scan_line, scanned
from .scanfile import ScanFile, ScannedModule

log = logging.getLogger("fieldgate.dcon")
SURVEY_PERIOD_S = 1.0  # listed modules: one other address probed a second
VERIFY_PERIOD_S = 0.2  # modules: auto from the previous scan: one address checked each 0.2 s
RESCAN_FIRST_S, RESCAN_MAX_S = 2.0, 60.0  # modules: auto with nothing expected: scan back-off


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
        self.start_scan: StartScan | None = None  # modules: auto, once per process
        # modules: auto whose start scan found nothing (port missing, line silent): why, and
        # what the back does about it (status "start_scan")
        self.scan_problem: dict[str, Any] | None = None
        self._rescan_delay = RESCAN_FIRST_S
        self._rescan_due: float | None = None
        # listed modules: the other addresses of scan.addresses, probed once after start
        self.survey: list[str] = []
        self._survey_left: list[int] | None = None
        self.survey_done = False
        # modules: auto started from the previous scan: the addresses still to verify, what
        # answered, and the previous modules that get a second probe before they count missing
        self._verify_left: list[int] = []
        self._verify_found: list[ScannedModule] = []
        self._verify_again: list[int] | None = None
        context.masters.subscribe(self._on_master)

    # -- SerialBack -------------------------------------------------------------------
    async def start(self) -> None:
        if self.config.auto and self.start_scan is None and self.scan_problem is None:
            await self._find_modules()
        await super().start()

    async def _find_modules(self) -> None:
        """``modules: auto``: the line's modules become the back's (a restart of the back
        keeps them: the fronts built on them). A missing port or a silent line does not stop
        the start: see :meth:`_start_without_scan`."""
        cfg = self.config
        previous = previous_start(cfg, self.context.state_dir)
        if previous is not None:  # start at once; the line is verified in the background
            cfg.baudrate, cfg.checksum = previous.baudrate, previous.checksum
            self._take_modules(previous.configs())
            self.start_scan = previous
            self._verify_left = parse_addresses(cfg.scan.addresses)
            return
        try:
            result = await find_modules(cfg, self.context.state_dir, self.reply_timeout_ms)
        except (PortUnavailable, NothingFound) as exc:
            self._start_without_scan(str(exc))
            return
        cfg.baudrate, cfg.checksum = result.baudrate, result.checksum
        self._take_modules(result.configs())
        self.start_scan = result

    def _take_modules(self, modules: list[DconModuleConfig]) -> None:
        cfg = self.config
        cfg.modules[:] = modules
        for module in cfg.modules:
            self.register_health(module)
        self.context.add_channels(self.name, cfg.channel_specs())

    def _start_without_scan(self, why: str) -> None:
        """The I-7231D/I-7241D way: come up on the fieldbus and show the error. The back
        starts with the modules it expects (the previous start's scan, else the scan file)
        offline; they come online when they answer, as listed modules do. With nothing to
        expect it starts with no module and scans the line again on a back-off."""
        expected, source = expected_modules(self.config, self.context.state_dir)
        self._take_modules(expected)
        # the I-7231D/I-7241D's "DCON modules init error" (7-segment 1): the fronts serving this
        # back show it their way until every expected module has answered (with none expected:
        # until the gateway restarts with what a re-scan found)
        self.context.health.back_error(self.name, f"DCON modules init error: {why}")
        self.scan_problem = {
            "error": why,
            "modules_from": source,
            "modules": [f"{m.model} at {m.address}" for m in expected],
            "rescans": 0,
            "found_later": [],
            "restart_needed": False,
        }
        if expected:
            log.error(
                "%s: %s; started with the %d module(s) of %s, offline until they answer",
                self.name,
                why,
                len(expected),
                source,
            )
        else:
            self._rescan_due = self.context.clock() + RESCAN_FIRST_S
            log.error(
                "%s: %s; started with no module (nothing to expect: no earlier scan, no scan "
                "file); scanning the line again every %.0f-%.0f s",
                self.name,
                why,
                RESCAN_FIRST_S,
                RESCAN_MAX_S,
            )

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
        for address, module in self.modules.items():
            aa, p = f"{address:02X}", module.profile
            read_di, write_do = (
                (f"@{aa}DI reply", f"@{aa}DO(data)")
                if p.digital == AIDIO
                else (f"@{aa} reply", f"@{aa}(data)")
            )
            for i, cid in enumerate(module.by_kind[Kind.DI]):
                out[cid] = [f"{read_di} bit {i}"]
            for i, cid in enumerate(module.by_kind[Kind.DO]):
                out[cid] = [f"{write_do} bit {i}"]
            for i, cid in enumerate(module.by_kind[Kind.AI]):
                out[cid] = [f"#{aa} reply, value {i + 1}"]
            for i, cid in enumerate(module.by_kind[Kind.AO]):
                out[cid] = [f"#{aa}(data)" if p.ao_style == AO_SINGLE else f"#{aa}{i}(data)"]
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
        if self._rescan_due is not None:
            jobs.append(LineJob("rescan", 0.5, self._rescan, self._rescan_wanted))
        if self._verify_left:
            jobs.append(
                LineJob(
                    "verify",
                    VERIFY_PERIOD_S,
                    self._verify_one,
                    self._verify_wanted,
                    self.context.clock() + VERIFY_PERIOD_S,  # the modules' first polls first
                )
            )
        if (self.scan_problem is not None and self.scan_problem["modules"]) or self._verify_left:
            jobs.append(LineJob("init-check", 0.5, self._init_check, self._init_pending))
        cfg = self.config
        if self._survey_left is None:  # once per process, not at each restart of the back
            listed = {m.address for m in cfg.modules}
            wanted = not cfg.auto and cfg.scan.survey
            self._survey_left = (
                [a for a in parse_addresses(cfg.scan.addresses) if a not in listed]
                if wanted
                else []
            )
            self.survey_done = not self._survey_left
        if self._survey_left:
            start = self.context.clock() + SURVEY_PERIOD_S  # the listed modules' polls first
            jobs.append(
                LineJob("survey", SURVEY_PERIOD_S, self._survey_one, self._survey_wanted, start)
            )
        return jobs

    def _init_pending(self) -> bool:
        return self.name in self.context.health.back_errors

    async def _init_check(self) -> None:
        """The expected modules of a start without a scan: once every one has answered, the
        init error ends (no line traffic: the health of the modules' polls says it)."""
        if all(h.last_success is not None and h.online for h in self.health.values()):
            if self.scan_problem is not None:
                self.scan_problem["resolved"] = True
            log.info("%s: every expected module answers: the init error ends", self.name)
            self.context.health.back_error(self.name, None)

    def _rescan_wanted(self) -> bool:
        return self._rescan_due is not None and self.context.clock() >= self._rescan_due

    async def _rescan(self) -> None:
        """modules: auto, nothing expected: probe the line's addresses at its setting. When
        supported modules answer, the scan is recorded (the next start builds the image from
        it) and the status asks for a restart: the fronts' images were built without them."""
        assert self.dcon is not None and self.scan_problem is not None
        cfg = self.config
        found = await scan_line(
            self.dcon, parse_addresses(cfg.scan.addresses), cfg.baudrate, report=lambda t: None
        )
        self.scan_problem["rescans"] += 1
        modules = [scanned(f, cfg.checksum) for f in found]
        if not any(m.model is not None for m in modules):
            self._rescan_delay = min(self._rescan_delay * 2, RESCAN_MAX_S)
            self._rescan_due = self.context.clock() + self._rescan_delay
            return
        self._rescan_due = None
        record = self.context.state_dir / f"{cfg.name}.dcon-scan.json"
        scan = ScanFile(cfg.port, modules, cfg.scan.addresses, [cfg.baudrate], [cfg.checksum])
        try:
            record.parent.mkdir(parents=True, exist_ok=True)
            scan.write(record)
        except OSError as exc:
            log.error("%s: cannot record the scan in %s: %s", self.name, record, exc)
        self.scan_problem["found_later"] = [m.describe() for m in modules]
        self.scan_problem["restart_needed"] = True
        log.error(
            "%s: modules answer now (%s), but the image was built without them: restart the "
            "gateway to serve them (the scan is recorded for the next start)",
            self.name,
            ", ".join(self.scan_problem["found_later"]),
        )

    def _verify_wanted(self) -> bool:
        """As the survey: not while a host watchdog is on (an empty address holds the line)."""
        return bool(self._verify_left) and not any(
            m.watchdog_enabled for m in self.modules.values()
        )

    async def _verify_one(self) -> None:
        """modules: auto started from the previous scan: probe one address of the line at its
        setting; after the last (and a second probe of a previous module that was silent),
        compare with the image (:func:`verified`)."""
        assert self.dcon is not None and self.start_scan is not None and self._verify_left
        cfg = self.config
        address = self._verify_left.pop(0)
        found = await scan_line(self.dcon, [address], cfg.baudrate, report=lambda text: None)
        self._verify_found += [scanned(f, cfg.checksum) for f in found]
        if self._verify_left:
            return
        if self._verify_again is None:
            seen = {m.address for m in self._verify_found}
            self._verify_again = [
                m.address
                for m in self.start_scan.modules
                if m.model is not None and m.address not in seen
            ]
            if self._verify_again:
                self._verify_left = list(self._verify_again)
                return
        found_all = sorted(self._verify_found, key=lambda m: m.address)
        if any(m.model is not None for m in found_all):
            verified(cfg, self.context.state_dir, self.start_scan, found_all)
            return
        # a silent line: the previous scan stays the record (as a start that found nothing),
        # and the fronts show the init error until every module has answered
        self.start_scan.verified = "silent"
        why = (
            f"modules: auto: no DCON module answered on {cfg.port} (addresses "
            f"{cfg.scan.addresses}; {cfg.baudrate} bit/s checksum "
            f"{'on' if cfg.checksum else 'off'}; reply timeout {self.reply_timeout_ms} ms)"
        )
        self.context.health.back_error(self.name, f"DCON modules init error: {why}")
        log.error(
            "%s: %s; the %d module(s) of the previous start's scan stay offline until they answer",
            self.name,
            why,
            len(cfg.modules),
        )

    def _survey_wanted(self) -> bool:
        """Addresses left, and no host watchdog on: an empty address holds the line for a reply
        timeout and its silence, which may be longer than the keep-alive (~**) may wait."""
        return bool(self._survey_left) and not any(
            m.watchdog_enabled for m in self.modules.values()
        )

    async def _survey_one(self) -> None:
        """Probe one address the topology does not list; after the last, warn about what answered."""
        assert self.dcon is not None and self._survey_left
        address = self._survey_left.pop(0)
        found = await scan_line(
            self.dcon, [address], self.config.baudrate, report=lambda text: None
        )
        self.survey += [scanned(f, self.config.checksum).describe() for f in found]
        if not self._survey_left:
            self.survey_done = True
            if self.survey:
                log.warning(
                    "%s: modules answer but are not in the topology: %s (list them, or use modules: auto)",
                    self.name,
                    ", ".join(self.survey),
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
        if self.start_scan is not None:
            status["start_scan"] = self.start_scan.status()
        elif self.scan_problem is not None:
            status["start_scan"] = dict(self.scan_problem)
        if not self.config.auto and self.config.scan.survey:
            status["survey"] = list(self.survey)
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
