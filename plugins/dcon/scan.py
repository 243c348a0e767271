"""Finding DCON modules on a line: ``$AA2`` at every address, then ``$AAM``/``$AAF`` to identify."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from fieldgate.health import ErrorKind
from fieldgate.polling import CommError

from . import codec
from .config import parse_addresses
from .formats import DataFormat
from .link import DconLink
from .profiles import Profile, find_profile
from .scanfile import ScannedModule
from .tables import TABLES

__all__ = ["Found", "parse_addresses", "progress_bar", "scan_line", "scanned", "topology_yaml"]


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


Progress = Callable[[int, int, int], None]  # (done, total, found)


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
    progress: Progress | None = None,
    found: list[Found] | None = None,
    report: Callable[[str], None] = _to_stderr,
) -> list[Found]:
    """Probe each address; modules that answer ``$AA2`` are identified. Silence = nobody there.

    The modules are appended to ``found`` (a new list by default) as they are identified,
    so a caller that cancels the scan (Ctrl-C) still has the ones found so far; the
    progress callback tells how many addresses were done. Returns ``found``.
    """
    addresses = list(addresses)
    found = [] if found is None else found
    count = len(found)
    for done, address in enumerate(addresses, 1):
        for attempt in (1, 2):  # an answer that is not one (noise, a late reply) is tried again
            try:
                config = codec.parse_config(
                    await link.transact(codec.command("$", address, "2")), address
                )
                name = codec.addressed(
                    await link.transact(codec.command("$", address, "M")), address
                )
                firmware = _optional(await _try(link, address, "F"))
            except CommError as exc:
                if exc.kind is ErrorKind.TIMEOUT:
                    break
                if attempt == 2:
                    report(f"address {address}: answered but {exc.kind}: {exc}")
            else:
                found.append(Found(address, baudrate, name, firmware, config, find_profile(name)))
                break
        if progress is not None:
            progress(done, len(addresses), len(found) - count)
    return found


async def _try(link: DconLink, address: int, body: str) -> str | None:
    try:
        return codec.addressed(await link.transact(codec.command("$", address, body)), address)
    except CommError:
        return None


def _optional(text: str | None) -> str:
    return text or ""


def progress_bar(stream=sys.stderr, width: int = 32) -> Progress:
    def show(done: int, total: int, found: int) -> None:
        filled = width * done // max(total, 1)
        stream.write(
            f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{total} addresses, {found} module(s) found"
        )
        if done == total:
            stream.write("\n")
        stream.flush()

    return show


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
