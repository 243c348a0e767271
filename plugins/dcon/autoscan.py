"""``modules: auto``: the DCON modules of a line, found when the back starts.

As the I-7231D and the I-7241D do at power-on (seed-001 §1.6, seed-003 §4 rule 1), the back
probes the topology's addresses (``scan.addresses``, default 1-15) at each baud rate and
checksum setting it allows (``scan.baudrates`` / ``scan.checksums``, default the line's),
with ``$AA2`` then ``$AAM`` / ``$AAF``, and builds its modules from what answers, in
address order. The line then runs at the first setting that found modules; modules that
answered at another one are left out with a warning (one line has one baud rate and one
checksum setting).

A missing port or a line where no supported module answers does not stop the gateway (as
the I-7231D and I-7241D come up on the fieldbus and show the error, seed-001 §1.6, seed-003
§2.5 "1"): :class:`NothingFound` tells the back, which starts with the modules it expects
(:func:`expected_modules`: the previous start's scan, else the scan file) offline, or with
none, and scans again on a back-off (docs/dcon.md, "modules: auto without its line").

The result is compared with the back's scan file (if the topology names one: the EDS made
from it no longer matches when they differ) and with the previous start's scan, recorded
in the state directory (``<back>.dcon-scan.json``): the image is the same as long as the line
is, and a change is a warning naming each module.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fieldgate.plugin import PluginStartError
from fieldgate.serial_link import AsyncSerial
from fieldgate.serial_timing import LineTiming, bits_per_char

from .config import DconBackConfig, DconModuleConfig, parse_addresses
from .link import DconLink
from .scan import Found, scan_line, scanned
from .scanfile import ScanFile, ScanFileError, ScannedModule, differences

log = logging.getLogger("fieldgate.dcon")


class NothingFound(PluginStartError):
    """No supported module answered (the line is silent, or only unsupported modules answer)."""


@dataclass
class StartScan:
    """What the start scan found and what it said about it (the back's status shows it)."""

    port: str
    baudrate: int
    checksum: bool
    modules: list[ScannedModule]
    left_out: list[str] = field(default_factory=list)
    changes: list[str] = field(default_factory=list)  # against the previous start
    against_scan_file: list[str] = field(default_factory=list)
    scanned: str = ""
    # started from the previous start's scan (its file), verified on the line in the background
    from_previous: str = ""
    verified: str = ""  # "pending", then "same", "changed" or "silent" (from_previous only)

    def configs(self) -> list[DconModuleConfig]:
        return [
            DconModuleConfig.model_validate(entry)
            for m in self.modules
            if (entry := m.module_config()) is not None
        ]

    def status(self) -> dict[str, Any]:
        return {
            "scanned": self.scanned,
            "baudrate": self.baudrate,
            "checksum": self.checksum,
            "modules": [m.describe() for m in self.modules],
            "left_out": list(self.left_out),
            "changed_since_last_start": list(self.changes),
            "differs_from_scan_file": list(self.against_scan_file),
            **(
                {"from_previous": self.from_previous, "verified": self.verified}
                if self.from_previous
                else {}
            ),
        }


def record_path(state_dir: Path, back: str) -> Path:
    """Where a DCON back records its start's scan (the previous start's, at the next start)."""
    return state_dir / f"{back}.dcon-scan.json"


def _warn_scan_file_differs(config: DconBackConfig, differences: list[str]) -> None:
    log.warning(
        "%s: the line differs from the scan file %s (an EDS made from it no longer matches): %s",
        config.name,
        config.scan.file,
        "; ".join(differences),
    )


def previous_start(config: DconBackConfig, state_dir: Path) -> StartScan | None:
    """The previous start's scan as this start's result, when it can stand for the line until
    the background check has probed it (``scan.from_previous``, docs/dcon.md): recorded with
    the topology's scan settings, with supported modules. None: probe first."""
    if not config.scan.from_previous:
        return None
    record = record_path(state_dir, config.name)
    previous = _previous(config, record)
    # (not the port's name: a pseudo-terminal's changes at each start, and a line moved to
    # another adapter is what the background check finds)
    if previous is None or (
        previous.addresses,
        previous.baudrates,
        previous.checksums,
    ) != (
        config.scan.addresses,
        config.scan.baudrates or [config.baudrate],
        config.scan.checksums if config.scan.checksums is not None else [config.checksum],
    ):
        return None
    supported = previous.supported()
    if not supported:
        return None
    line = supported[0].baudrate, supported[0].checksum
    modules = [m for m in previous.modules if (m.baudrate, m.checksum) == line]
    result = StartScan(config.port, *line, sorted(modules, key=lambda m: m.address))
    if not result.configs():
        return None
    result.scanned, result.from_previous, result.verified = previous.scanned, str(record), "pending"
    log.info(
        "%s: %d DCON module(s) from the previous start's scan (%s, %s), at %d bit/s, checksum "
        "%s; verifying the line in the background",
        config.name,
        len(result.configs()),
        record,
        previous.scanned,
        result.baudrate,
        "on" if result.checksum else "off",
    )
    return result


def verified(
    config: DconBackConfig, state_dir: Path, result: StartScan, found: list[ScannedModule]
) -> list[str]:
    """The background check of a start from the previous scan is done: ``found`` is what the
    line's addresses answered at its setting. Returns the changes (empty: the same image);
    a changed line is recorded for the next start and logged (the image was built from the
    previous scan: a restart serves the new one)."""
    changes = differences(result.modules, found)
    result.verified = "changed" if changes else "same"
    if config.scan_file is not None:
        result.against_scan_file = differences(config.scan_file.modules, found)
        if result.against_scan_file:
            _warn_scan_file_differs(config, result.against_scan_file)
    if not changes:
        log.info("%s: the line answers as the previous start's scan said", config.name)
        return []
    result.changes = changes
    record = record_path(state_dir, config.name)
    now = ScanFile(
        config.port,
        found,
        config.scan.addresses,
        config.scan.baudrates or [config.baudrate],
        config.scan.checksums if config.scan.checksums is not None else [config.checksum],
    )
    try:
        now.write(record)
    except OSError as exc:
        log.error("%s: cannot record the scan in %s: %s", config.name, record, exc.strerror or exc)
    log.warning(
        "%s: the line changed since the last start (%s); the image was built from the previous "
        "scan: restart the gateway to serve the line as it is now (the scan is recorded for the "
        "next start)",
        config.name,
        "; ".join(changes),
    )
    return changes


async def find_modules(config: DconBackConfig, state_dir: Path, timeout_ms: int) -> StartScan:
    """Probe the line; raise PluginStartError (one line) when no supported module answers."""
    addresses = parse_addresses(config.scan.addresses)
    bauds = config.scan.baudrates or [config.baudrate]
    checksums = config.scan.checksums if config.scan.checksums is not None else [config.checksum]
    settings = [(baud, checksum) for baud in bauds for checksum in checksums]
    log.info(
        "%s: finding the DCON modules on %s (addresses %s; %s; reply timeout %d ms)",
        config.name,
        config.port,
        config.scan.addresses,
        ", ".join(f"{b} bit/s checksum {'on' if c else 'off'}" for b, c in settings),
        timeout_ms,
    )
    record = record_path(state_dir, config.name)
    previous = _previous(config, record)
    by_setting: dict[tuple[int, bool], list[Found]] = {}
    for baud, checksum in settings:
        taken = {f.address for found in by_setting.values() for f in found}
        by_setting[(baud, checksum)] = await _probe(
            config, baud, checksum, timeout_ms, [a for a in addresses if a not in taken]
        )
    line = next((s for s in settings if by_setting.get(s)), None)
    if line is not None and previous is not None:
        # a module the last start found gets a second chance before the image loses it
        seen = {f.address for f in by_setting[line]}
        again = [m.address for m in previous.modules if m.address not in seen]
        if again:
            by_setting[line] += await _probe(config, *line, timeout_ms, again)
            by_setting[line].sort(key=lambda f: f.address)
    if line is None:
        raise NothingFound(
            f"modules: auto: no DCON module answered on {config.port} (addresses "
            f"{config.scan.addresses}; "
            + ", ".join(f"{b} bit/s checksum {'on' if c else 'off'}" for b, c in settings)
            + f"; reply timeout {timeout_ms} ms): check the wiring, the modules' baud rate and "
            "checksum (scan.baudrates, scan.checksums), or list the modules"
        )
    found = [scanned(f, line[1]) for f in by_setting[line]]
    result = StartScan(config.port, line[0], line[1], sorted(found, key=lambda m: m.address))
    for (baud, checksum), others in by_setting.items():
        for f in others if (baud, checksum) != line else ():
            result.left_out.append(
                f"{scanned(f, checksum).describe()} answers at {baud} bit/s checksum "
                f"{'on' if checksum else 'off'}, not at the line's {line[0]} bit/s checksum "
                f"{'on' if line[1] else 'off'}: left out"
            )
    for m in result.modules:
        if m.model is None:
            result.left_out.append(
                f"module {m.address} answers $AAM {m.name!r}, a model fieldgate does not support: left out"
            )
    if not result.configs():
        raise NothingFound(
            f"modules: auto: no supported DCON module on {config.port}: "
            + "; ".join(result.left_out)
        )
    _compare(config, result, record, previous)
    return result


async def _probe(
    config: DconBackConfig, baud: int, checksum: bool, timeout_ms: int, addresses: list[int]
) -> list[Found]:
    serial = await AsyncSerial.open(
        config.port, baud, config.bytesize, config.parity, config.stopbits
    )
    try:
        # a reply to a command from before the start (the gateway restarted mid-transaction)
        # may still come: let it pass before the first probe
        await asyncio.sleep(timeout_ms / 1000)
        serial.reset_input()
        timing = LineTiming.of(
            baud,
            timeout_ms,
            config.byte_timeout_ms,
            bits_per_char(config.bytesize, config.parity, config.stopbits),
        )
        link = DconLink(
            serial,
            checksum,
            timeout_ms / 1000,
            settle_after_timeout=False,
            timing=timing,
            echo=config.echo,
        )
        return await scan_line(
            link, addresses, baud, report=lambda text: log.warning("%s: %s", config.name, text)
        )
    finally:
        await serial.close()


def expected_modules(config: DconBackConfig, state_dir: Path) -> tuple[list[DconModuleConfig], str]:
    """The modules a back whose start scan found nothing expects, and where they come from:
    the previous start's scan (the image the master last saw), else the topology's scan file
    (the image the EDS was made from), else none."""
    record = record_path(state_dir, config.name)
    for scan, source in (
        (_previous(config, record), f"the previous start's scan ({record})"),
        (config.scan_file, f"the scan file {config.scan.file}"),
    ):
        if scan is not None:
            configs = [
                DconModuleConfig.model_validate(entry)
                for m in scan.supported()
                if (entry := m.module_config()) is not None
            ]
            if configs:
                return configs, source
    return [], "nowhere (no earlier scan, no scan file)"


def _previous(config: DconBackConfig, record: Path) -> ScanFile | None:
    try:
        return ScanFile.read(record) if record.exists() else None
    except ScanFileError as exc:
        log.warning("%s: ignoring the previous scan: %s", config.name, exc)
        return None


def _compare(
    config: DconBackConfig, result: StartScan, record: Path, previous: ScanFile | None
) -> None:
    now = ScanFile(
        result.port,
        result.modules,
        config.scan.addresses,
        config.scan.baudrates or [config.baudrate],
        config.scan.checksums if config.scan.checksums is not None else [config.checksum],
    )
    result.scanned = now.scanned
    if config.scan_file is not None:
        result.against_scan_file = differences(config.scan_file.modules, result.modules)
    if previous is not None:
        result.changes = differences(previous.modules, result.modules)
    try:
        record.parent.mkdir(parents=True, exist_ok=True)
        now.write(record)
    except OSError as exc:
        log.error("%s: cannot record the scan in %s: %s", config.name, record, exc.strerror or exc)
    log.info(
        "%s: %d DCON module(s) at %d bit/s, checksum %s: %s",
        config.name,
        len(result.configs()),
        result.baudrate,
        "on" if result.checksum else "off",
        ", ".join(m.describe() for m in result.modules if m.model is not None),
    )
    for text in result.left_out:
        log.warning("%s: %s", config.name, text)
    if result.changes:
        log.warning(
            "%s: the line changed since the last start, so did the image (a master configured "
            "for the old one may refuse the connection): %s",
            config.name,
            "; ".join(result.changes),
        )
    if result.against_scan_file:
        _warn_scan_file_differs(config, result.against_scan_file)
