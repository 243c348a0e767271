"""How a ``dcon`` back learns its line's modules beyond the topology's list.

* ``modules: auto``: the start scan (:mod:`.autoscan`), or at once the previous start's scan
  with the line verified in the background (``scan.from_previous``); when the port is missing or the line
  silent, the back starts anyway with the modules it expects (the previous start's scan,
  else the scan file) and shows the I-7231D/I-7241D's "DCON modules init error" until they
  answer; with nothing to expect it scans the line again on a back-off and, when modules
  answer, records them and asks for a restart.
* Listed modules: the survey probes the other addresses of ``scan.addresses`` once, one a
  second, and warns about modules that answer but are not listed.

The back (:mod:`.back`) runs these as line jobs (:meth:`LineDiscovery.jobs`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from typing import Any

from fieldgate.health import ModuleHealth
from fieldgate.plugin import GatewayContext, PortUnavailable
from fieldgate.polling import LineJob

from .autoscan import (
    NothingFound,
    StartScan,
    expected_modules,
    find_modules,
    previous_start,
    record_path,
    verified,
)
from .config import DconBackConfig, DconModuleConfig, parse_addresses
from .link import DconLink
from .scan import scan_line, scanned
from .scanfile import ScanFile, ScannedModule

log = logging.getLogger("fieldgate.dcon")
SURVEY_PERIOD_S = 1.0  # listed modules: one other address probed a second
VERIFY_PERIOD_S = 0.2  # modules: auto from the previous scan: one address checked each 0.2 s
RESCAN_FIRST_S, RESCAN_MAX_S = 2.0, 60.0  # modules: auto with nothing expected: scan back-off


class LineDiscovery:
    def __init__(
        self,
        name: str,
        config: DconBackConfig,
        context: GatewayContext,
        take_modules: Callable[[list[DconModuleConfig]], None],
    ):
        self.name = name
        self.config = config
        self.context = context
        self.take_modules = take_modules  # the back registers their health and channels
        self.reply_timeout_ms = config.timeout_ms
        self.start_scan: StartScan | None = None  # modules: auto, once per process
        # modules: auto whose start scan found nothing (port missing, line silent): why, and
        # what the back does about it (status "start_scan")
        self.scan_problem: dict[str, Any] | None = None
        self._rescan_delay = RESCAN_FIRST_S
        self._rescan_due: float | None = None
        # listed modules: the other addresses of scan.addresses, probed once after start
        self.survey: list[str] = []
        self.survey_left: list[int] | None = None
        self.survey_done = False
        # modules: auto started from the previous scan: the addresses still to verify, what
        # answered, and the previous modules that get a second probe before they count missing
        self._verify_left: list[int] = []
        self._verify_found: list[ScannedModule] = []
        self._verify_again: list[int] | None = None

    # -- modules: auto ----------------------------------------------------------------------
    async def find_modules(self, reply_timeout_ms: int) -> None:
        """``modules: auto``: the line's modules become the back's (a restart of the back
        keeps them: the fronts built on them). A missing port or a silent line does not stop
        the start: see :meth:`start_without_scan`."""
        cfg = self.config
        self.reply_timeout_ms = reply_timeout_ms
        previous = previous_start(cfg, self.context.state_dir)
        if previous is not None:  # start at once; the line is verified in the background
            cfg.baudrate, cfg.checksum = previous.baudrate, previous.checksum
            self.take_modules(previous.configs())
            self.start_scan = previous
            self._verify_left = parse_addresses(cfg.scan.addresses)
            return
        try:
            result = await find_modules(cfg, self.context.state_dir, reply_timeout_ms)
        except (PortUnavailable, NothingFound) as exc:
            self.start_without_scan(str(exc))
            return
        cfg.baudrate, cfg.checksum = result.baudrate, result.checksum
        self.take_modules(result.configs())
        self.start_scan = result

    def start_without_scan(self, why: str) -> None:
        """The I-7231D/I-7241D way: come up on the fieldbus and show the error. The back
        starts with the modules it expects (the previous start's scan, else the scan file)
        offline; they come online when they answer, as listed modules do. With nothing to
        expect it starts with no module and scans the line again on a back-off."""
        expected, source = expected_modules(self.config, self.context.state_dir)
        self.take_modules(expected)
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

    # -- line jobs ---------------------------------------------------------------------------
    def jobs(
        self,
        link: Callable[[], DconLink | None],
        health: Callable[[], Iterable[ModuleHealth]],
        watchdog_on: Callable[[], bool],
    ) -> list[LineJob]:
        """The rescan, the end of the init error and the survey, as they apply: ``link``
        is the back's open line, ``health`` its modules', ``watchdog_on`` whether any module
        has a host watchdog (the survey waits then)."""
        jobs = []
        if self._rescan_due is not None:
            jobs.append(LineJob("rescan", 0.5, lambda: self._rescan(link()), self._rescan_wanted))
        if self._verify_left:
            jobs.append(
                LineJob(
                    "verify",
                    VERIFY_PERIOD_S,
                    lambda: self._verify_one(link()),
                    lambda: bool(self._verify_left) and not watchdog_on(),  # as the survey
                    self.context.clock() + VERIFY_PERIOD_S,  # the modules' first polls first
                )
            )
        if (self.scan_problem is not None and self.scan_problem["modules"]) or self._verify_left:
            jobs.append(
                LineJob("init-check", 0.5, lambda: self._init_check(health()), self._init_pending)
            )
        cfg = self.config
        if self.survey_left is None:  # once per process, not at each restart of the back
            listed = {m.address for m in cfg.modules}
            wanted = not cfg.auto and cfg.scan.survey
            self.survey_left = (
                [a for a in parse_addresses(cfg.scan.addresses) if a not in listed]
                if wanted
                else []
            )
            self.survey_done = not self.survey_left
        if self.survey_left:
            start = self.context.clock() + SURVEY_PERIOD_S  # the listed modules' polls first
            jobs.append(
                LineJob(
                    "survey",
                    SURVEY_PERIOD_S,
                    lambda: self._survey_one(link()),
                    # an empty address holds the line for a reply timeout and its silence,
                    # which may be longer than the keep-alive (~**) may wait
                    lambda: bool(self.survey_left) and not watchdog_on(),
                    start,
                )
            )
        return jobs

    def _init_pending(self) -> bool:
        return self.name in self.context.health.back_errors

    async def _init_check(self, health: Iterable[ModuleHealth]) -> None:
        """The expected modules of a start without a scan: once every one has answered, the
        init error ends (no line traffic: the health of the modules' polls says it)."""
        if all(h.last_success is not None and h.online for h in health):
            if self.scan_problem is not None:
                self.scan_problem["resolved"] = True
            log.info("%s: every expected module answers: the init error ends", self.name)
            self.context.health.back_error(self.name, None)

    def _rescan_wanted(self) -> bool:
        return self._rescan_due is not None and self.context.clock() >= self._rescan_due

    async def _rescan(self, dcon: DconLink | None) -> None:
        """modules: auto, nothing expected: probe the line's addresses at its setting. When
        supported modules answer, the scan is recorded (the next start builds the image from
        it) and the status asks for a restart: the fronts' images were built without them."""
        assert dcon is not None and self.scan_problem is not None
        cfg = self.config
        found = await scan_line(
            dcon, parse_addresses(cfg.scan.addresses), cfg.baudrate, report=lambda t: None
        )
        self.scan_problem["rescans"] += 1
        modules = [scanned(f, cfg.checksum) for f in found]
        if not any(m.model is not None for m in modules):
            self._rescan_delay = min(self._rescan_delay * 2, RESCAN_MAX_S)
            self._rescan_due = self.context.clock() + self._rescan_delay
            return
        self._rescan_due = None
        record = record_path(self.context.state_dir, cfg.name)
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

    async def _verify_one(self, dcon: DconLink | None) -> None:
        """modules: auto started from the previous scan: probe one address of the line at its
        setting; after the last (and a second probe of a previous module that was silent),
        compare with the image (:func:`.autoscan.verified`)."""
        assert dcon is not None and self.start_scan is not None and self._verify_left
        cfg = self.config
        address = self._verify_left.pop(0)
        found = await scan_line(dcon, [address], cfg.baudrate, report=lambda text: None)
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

    async def _survey_one(self, dcon: DconLink | None) -> None:
        """Probe one address the topology does not list; after the last, warn about what answered."""
        assert dcon is not None and self.survey_left
        address = self.survey_left.pop(0)
        found = await scan_line(dcon, [address], self.config.baudrate, report=lambda text: None)
        self.survey += [scanned(f, self.config.checksum).describe() for f in found]
        if not self.survey_left:
            self.survey_done = True
            if self.survey:
                log.warning(
                    "%s: modules answer but are not in the topology: %s (list them, or use modules: auto)",
                    self.name,
                    ", ".join(self.survey),
                )

    def status(self, status: dict[str, Any]) -> None:
        """The start scan (or what the back did without one) and the survey, into ``status``."""
        if self.start_scan is not None:
            status["start_scan"] = self.start_scan.status()
        elif self.scan_problem is not None:
            status["start_scan"] = dict(self.scan_problem)
        if not self.config.auto and self.config.scan.survey:
            status["survey"] = list(self.survey)
