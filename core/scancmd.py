"""``fieldgate scan BACK``: find the modules on a line and print a ready-to-paste topology
section, for every back whose plugin registers a :class:`~fieldgate.plugin.Scanner`.

The options every back shares are here (``--port``, ``--baudrate`` one rate or several,
``--addresses``, ``--timeout-ms``, ``--name``); a back adds its own in a group of their own.
Exit codes: 0 modules found, 1 none, 2 the port failed or a wrong option, 130 Ctrl-C (what
was found so far is printed all the same, and where the scan stopped).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from typing import Any, TextIO

from .exitcodes import ExitCode
from .plugin import CommandError, PluginStartError, Registry, Scanner, ScanProgress


def configure(parser: argparse.ArgumentParser, scanner: Scanner, back_type: str) -> None:
    from .cliargs import deprecated_alias

    low, high = scanner.address_range
    parser.add_argument("--port", required=True, help="serial device or pyserial URL")
    parser.add_argument(
        "--baudrate",
        default="9600",
        metavar="RATE[,RATE...]",
        help="baud rate, or several separated by commas (e.g. 9600,19200,115200; default 9600)",
    )
    deprecated_alias(parser, "--baud", "--baudrate")
    parser.add_argument(
        "--addresses",
        default=scanner.addresses,
        help=f"addresses to probe, e.g. 1-15 or 1,2,8 (default {scanner.addresses}; {low}..{high})",
    )
    parser.add_argument(
        "--timeout-ms", type=int, default=100, help="reply timeout per address (default 100)"
    )
    parser.add_argument("--name", default="rs485", help="back name in the printed topology")
    scanner.configure(parser.add_argument_group(f"{back_type} only"))


def parse_addresses(text: str, low: int = 0, high: int = 255) -> list[int]:
    """'0-255', '1-15,32' -> addresses (ValueError outside ``low``..``high``)."""
    result: list[int] = []
    for part in text.split(","):
        first, _, last = part.strip().partition("-")
        start, end = int(first, 0), int(last or first, 0)
        if not low <= start <= end <= high:
            raise ValueError(f"address range {part!r} outside {low}..{high}")
        result.extend(range(start, end + 1))
    return sorted(set(result))


def progress_bar(stream: TextIO = sys.stderr, width: int = 32) -> ScanProgress:
    def show(done: int, total: int, found: int) -> None:
        filled = width * done // max(total, 1)
        stream.write(
            f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{total} addresses, {found} module(s) found"
        )
        if done == total:
            stream.write("\n")
        stream.flush()

    return show


class _Progress:
    """The progress callback of one baud rate: draws the bar, remembers how far it got."""

    def __init__(self, bar: ScanProgress) -> None:
        self.bar = bar
        self.done = 0

    def __call__(self, count: int, total: int, modules: int) -> None:
        self.done = count
        self.bar(count, total, modules)


def run(args: argparse.Namespace, registry: Registry, back_type: str) -> int:
    command = f"fieldgate scan {back_type}"
    scanner = registry.scanners[back_type]
    try:
        addresses = parse_addresses(args.addresses, *scanner.address_range)
        bauds = [int(b) for b in args.baudrate.split(",")]
    except ValueError as exc:
        print(f"{command}: {exc}", file=sys.stderr)
        return ExitCode.CANNOT_RUN
    found: list[Any] = []
    try:
        interrupted = asyncio.run(_scan(scanner, args, addresses, bauds, found))
    except (
        PluginStartError
    ) as exc:  # the port would not open (at a later baud rate: keep the finds)
        print(f"{command}: {exc}", file=sys.stderr)
        if found:
            print(f"{command}: the modules found before that:", file=sys.stderr)
            sys.stdout.write(scanner.topology(found, args))
        return ExitCode.CANNOT_RUN
    if interrupted:
        print(f"{command}: interrupted {interrupted}; the modules found so far:", file=sys.stderr)
    sys.stdout.write(scanner.topology(found, args))
    if interrupted:
        return ExitCode.INTERRUPTED
    try:
        scanner.save(found, args, bauds)
    except CommandError as exc:
        print(f"{command}: {exc}", file=sys.stderr)
        return ExitCode.CANNOT_RUN
    return ExitCode.OK if found else ExitCode.FAILED


async def _scan(
    scanner: Scanner,
    args: argparse.Namespace,
    addresses: list[int],
    bauds: list[int],
    found: list[Any],
) -> str | None:
    """Scan at each baud rate, appending to ``found``. None when done; where it stopped when
    Ctrl-C interrupted it (asyncio.run cancels this task on SIGINT)."""
    for n, baud in enumerate(bauds):
        progress = _Progress(progress_bar())
        try:
            print(f"scanning {args.port} at {baud} bit/s", file=sys.stderr)
            await scanner.scan(args.port, baud, addresses, args, progress, found)
        except asyncio.CancelledError:
            done = progress.done
            if 0 < done < len(addresses):
                print(file=sys.stderr)  # end the progress bar's line
            where = (
                f"at address {addresses[done]} at {baud} bit/s (it and the addresses after it were not probed)"
                if done < len(addresses)
                else f"after the last address at {baud} bit/s"
            )
            rest = bauds[n + 1 :]
            return where + (f", {', '.join(map(str, rest))} bit/s not scanned" if rest else "")
    return None
