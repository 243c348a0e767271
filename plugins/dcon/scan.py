"""Finding DCON modules on a line: ``$AA2`` at every address, then ``$AAM``/``$AAF`` to identify
(``fieldgate scan dcon``; core runs the command: baud rates, progress, Ctrl-C)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fieldgate.health import ErrorKind
from fieldgate.plugin import CommandError, Scanner, ScanProgress, probe_each
from fieldgate.polling import CommError
from fieldgate.serial_link import AsyncSerial
from fieldgate.serial_timing import LineTiming

from . import codec
from .formats import DataFormat
from .link import DconLink
from .profiles import Profile, find_profile
from .scanfile import ScanFile, ScannedModule
from .tables import TABLES

__all__ = ["DconScanner", "Found", "identify", "scan_line", "scanned", "topology_yaml"]


@dataclass(frozen=True)
class Found:
    address: int
    baudrate: int
    name: str
    firmware: str
    config: codec.ModuleConfigReply
    profile: Profile | None

    def describe_range(self) -> str:
        p = self.profile
        key = p and (p.ai_table or p.ao_table)
        if not key:
            return ""
        rng = TABLES[key].get(self.config.type_code)
        return rng.label if rng else "unknown type code"


def scanned(found: Found, line_checksum: bool) -> ScannedModule:
    """A module found on the line as a scan file records it (the line's checksum setting when
    the module's own $AA2 format byte does not say: it always does)."""
    return ScannedModule(
        found.address,
        found.baudrate,
        found.config.checksum if found.config is not None else line_checksum,
        found.name,
        found.firmware,
        found.profile.model if found.profile else None,
        found.config.type_code,
        DataFormat(found.config.data_format).label,
    )


def _to_stderr(text: str) -> None:
    print(f"\n{text}", file=sys.stderr)


async def scan_line(
    link: DconLink,
    addresses: Iterable[int],
    baudrate: int,
    progress: ScanProgress | None = None,
    found: list[Found] | None = None,
    report: Callable[[str], None] = _to_stderr,
) -> list[Found]:
    """Probe each address (:func:`identify`). The modules are appended to ``found`` (a new
    list by default) as they are identified, so a caller that cancels the scan (Ctrl-C)
    still has the ones found so far; the progress callback tells how many addresses were
    done. Returns ``found``.
    """
    found = [] if found is None else found
    await probe_each(
        list(addresses), lambda address: identify(link, address, baudrate, report), found, progress
    )
    return found


async def identify(
    link: DconLink, address: int, baudrate: int, report: Callable[[str], None] = _to_stderr
) -> Found | None:
    """The module at ``address`` when it answers ``$AA2``, identified; None for silence."""
    for attempt in (1, 2):  # an answer that is not one (noise, a late reply) is tried again
        try:
            config = codec.parse_config(
                await link.transact(codec.command("$", address, "2")), address
            )
            name = codec.addressed(await link.transact(codec.command("$", address, "M")), address)
            firmware = _optional(await _try(link, address, "F"))
        except CommError as exc:
            if exc.kind is ErrorKind.TIMEOUT:
                return None
            if attempt == 2:
                report(f"address {address}: answered but {exc.kind}: {exc}")
        else:
            return Found(address, baudrate, name, firmware, config, find_profile(name))
    return None


async def _try(link: DconLink, address: int, body: str) -> str | None:
    try:
        return codec.addressed(await link.transact(codec.command("$", address, body)), address)
    except CommError:
        return None


def _optional(text: str | None) -> str:
    return text or ""


def topology_yaml(found: list[Found], port: str, checksum: bool, name: str = "rs485") -> str:
    """Ready-to-paste ``backs:`` entries, one per baud rate that had modules."""
    lines = ["backs:"]
    for baud in sorted({f.baudrate for f in found}):
        modules = [f for f in found if f.baudrate == baud]
        back = name if len({f.baudrate for f in found}) == 1 else f"{name}-{baud}"
        lines += [
            f"  - name: {back}",
            "    type: dcon",
            f"    port: {port}",
            f"    baudrate: {baud}",
            f"    checksum: {'true' if checksum else 'false'}",
            "    modules:",
        ]
        for f in modules:
            model = f.profile.model if f.profile else f"I-{f.name}"
            note = (
                f"  # $AAM {f.name}"
                + (f", firmware {f.firmware}" if f.firmware else "")
                + ("" if f.profile else ", NOT SUPPORTED")
            )
            lines.append(f"      - address: {f.address}")
            lines.append(f"        model: {model}{note}")
            if f.profile and (f.profile.ai or f.profile.ao):
                lines.append(
                    f"        type_code: 0x{f.config.type_code:02X}  # {f.describe_range()}"
                )
                lines.append(f"        data_format: {DataFormat(f.config.data_format).label}")
            if f.config.checksum != checksum:
                lines.append(
                    f"        # module checksum is {'on' if f.config.checksum else 'off'}, the line's is {'on' if checksum else 'off'}"
                )
    if len(lines) == 1:
        lines.append("  []  # no module answered")
    return "\n".join(lines) + "\n"


class DconScanner(Scanner):
    addresses = "0-255"
    address_range = (0, 255)

    def configure(self, group: argparse._ArgumentGroup) -> None:
        group.add_argument("--checksum", action="store_true", help="send and expect DCON checksums")
        group.add_argument(
            "-o",
            "--output",
            metavar="FILE",
            help="also write a scan file (JSON) for modules: auto, the EDS generators and --simulate",
        )

    async def open(self, port: str, baudrate: int, args: argparse.Namespace) -> DconLink:
        serial = await AsyncSerial.open(port, baudrate)  # PluginStartError: one line
        # every scan reply carries its address, so a late one cannot be mistaken: no settling
        return DconLink(
            serial,
            args.checksum,
            args.timeout_ms / 1000,
            settle_after_timeout=False,
            timing=LineTiming.of(baudrate, args.timeout_ms, bits=10),
        )

    async def probe(self, link: DconLink, address: int, baudrate: int) -> Found | None:
        return await identify(link, address, baudrate)

    async def close(self, link: DconLink) -> None:
        await link.serial.close()

    def topology(self, found: list[Any], args: argparse.Namespace) -> str:
        return topology_yaml(found, args.port, args.checksum, args.name)

    def save(self, found: list[Any], args: argparse.Namespace, bauds: list[int]) -> None:
        """``-o FILE``: what the scan found, as ``modules: auto`` and the EDS generators read it."""
        if args.output is None:
            return
        scan = ScanFile(
            args.port,
            [scanned(f, args.checksum) for f in found],
            args.addresses,
            bauds,
            [args.checksum],
        )
        try:
            scan.write(Path(args.output))
        except OSError as exc:
            raise CommandError(
                f"{args.output}: cannot write the scan file: {exc.strerror or exc}"
            ) from None
        print(
            f"fieldgate scan dcon: {len(found)} module(s) written to {args.output}", file=sys.stderr
        )
