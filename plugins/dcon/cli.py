"""``fieldgate scan dcon`` and ``fieldgate simulate dcon``."""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Callable
from pathlib import Path

from fieldgate.plugin import PluginStartError
from fieldgate.serial_link import AsyncSerial, PtyPair
from fieldgate.serial_timing import LineTiming
from fieldgate.stopping import stopped_by_signals, wait_until

from .link import DconLink
from .scan import parse_addresses, progress_bar, scan_line, scanned, topology_yaml
from .scanfile import ScanFile
from .simulator import DconSimulator


# -- scan --------------------------------------------------------------------------------
def configure_scan(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True, help="serial device or pyserial URL")
    parser.add_argument(
        "--baudrate",
        default="9600",
        metavar="RATE[,RATE...]",
        help="baud rate, or several separated by commas (e.g. 9600,19200,115200; default 9600)",
    )
    add_baud_alias(parser)
    parser.add_argument(
        "--addresses",
        default="0-255",
        help="addresses to probe, e.g. 1-15 or 1,2,8 (default 0-255)",
    )
    parser.add_argument("--checksum", action="store_true", help="send and expect DCON checksums")
    parser.add_argument(
        "--timeout-ms", type=int, default=100, help="reply timeout per address (default 100)"
    )
    parser.add_argument("--name", default="rs485", help="back name in the printed topology")
    parser.add_argument(
        "-o",
        "--output",
        metavar="FILE",
        help="also write a scan file (JSON) for modules: auto, the EDS generators and --simulate",
    )


def add_baud_alias(parser: argparse.ArgumentParser, **kwargs) -> None:
    """``--baud``, the older name of ``--baudrate`` (the topology's key): still accepted, not in the help."""
    parser.add_argument(
        "--baud", dest="baudrate", default=argparse.SUPPRESS, help=argparse.SUPPRESS, **kwargs
    )


def run_scan(args: argparse.Namespace) -> int:
    """Exit 0 when modules were found, 1 when none, 2 on errors, 130 when interrupted (Ctrl-C):
    then the modules found so far are printed all the same, and where the scan stopped."""
    try:
        addresses = parse_addresses(args.addresses)
        bauds = [int(b) for b in args.baudrate.split(",")]
    except ValueError as exc:
        print(f"fieldgate scan dcon: {exc}", file=sys.stderr)
        return 2
    found: list = []
    try:
        interrupted = asyncio.run(_scan(args, addresses, bauds, found))
    except (
        PluginStartError
    ) as exc:  # the port would not open (at a later baud rate: keep what the earlier ones found)
        print(f"fieldgate scan dcon: {exc}", file=sys.stderr)
        if found:
            print("fieldgate scan dcon: the modules found before that:", file=sys.stderr)
            sys.stdout.write(topology_yaml(found, args.port, args.checksum, args.name))
        return 2
    if interrupted:
        print(
            f"fieldgate scan dcon: interrupted {interrupted}; the modules found so far:",
            file=sys.stderr,
        )
    sys.stdout.write(topology_yaml(found, args.port, args.checksum, args.name))
    if args.output is not None and not interrupted:
        try:
            scan_file(args, found, bauds).write(Path(args.output))
        except OSError as exc:
            print(
                f"fieldgate scan dcon: {args.output}: cannot write the scan file: {exc.strerror or exc}",
                file=sys.stderr,
            )
            return 2
        print(
            f"fieldgate scan dcon: {len(found)} module(s) written to {args.output}", file=sys.stderr
        )
    if interrupted:
        return INTERRUPTED
    return 0 if found else 1


def scan_file(args: argparse.Namespace, found: list, bauds: list[int]) -> ScanFile:
    """What the scan found, as ``modules: auto`` and the EDS generators read it."""
    return ScanFile(
        args.port,
        [scanned(f, args.checksum) for f in found],
        args.addresses,
        bauds,
        [args.checksum],
    )


INTERRUPTED = (
    130  # 128 + SIGINT, as the shell reports a command stopped by Ctrl-C: the result is partial
)


class _ScanProgress:
    """scan_line's progress callback for one baud rate: draws the bar, remembers how far it got."""

    def __init__(self, bar: Callable[[int, int, int], None]) -> None:
        self.bar = bar
        self.done = 0

    def __call__(self, count: int, total: int, modules: int) -> None:
        self.done = count
        self.bar(count, total, modules)


async def _scan(
    args: argparse.Namespace, addresses: list[int], bauds: list[int], found: list
) -> str | None:
    """Scan at each baud rate, appending to ``found``. None when done; where it stopped when
    Ctrl-C interrupted it (asyncio.run cancels this task on SIGINT)."""
    for n, baud in enumerate(bauds):
        progress = _ScanProgress(progress_bar())
        try:
            print(
                f"scanning {args.port} at {baud} bit/s, checksum {'on' if args.checksum else 'off'}",
                file=sys.stderr,
            )
            serial = await AsyncSerial.open(args.port, baud)
            try:
                # every scan reply carries its address, so a late one cannot be mistaken: no settling
                link = DconLink(
                    serial,
                    args.checksum,
                    args.timeout_ms / 1000,
                    settle_after_timeout=False,
                    timing=LineTiming.of(baud, args.timeout_ms, bits=10),
                )
                await scan_line(link, addresses, baud, progress, found)
            finally:
                await serial.close()
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


# -- simulate ------------------------------------------------------------------------------
def configure_simulate(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", help="serial device (or pty end) to serve")
    where.add_argument(
        "--pty",
        action="store_true",
        help="create a pseudo-terminal pair and print the end to connect to",
    )
    parser.add_argument(
        "--module",
        action="append",
        default=[],
        metavar="ADDR:MODEL[:TYPE[:FORMAT]]",
        help="a simulated module, e.g. 1:I-7043 or 4:I-7012:0x08:hex (repeat)",
    )
    parser.add_argument("--checksum", action="store_true", help="modules expect and send checksums")
    parser.add_argument("--baudrate", type=int, default=9600, help="baud rate (default 9600)")
    add_baud_alias(parser, type=int)
    parser.add_argument(
        "--animate",
        action="store_true",
        help="inputs change by themselves (walking DI bit, AI sine)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=0,
        help="stop after this many seconds (default: until Ctrl-C)",
    )


def parse_module(text: str) -> tuple:
    parts = text.split(":")
    if len(parts) < 2:
        raise ValueError(f"--module expects ADDR:MODEL[:TYPE[:FORMAT]], got {text!r}")
    entry: list = [int(parts[0], 0), parts[1]]
    if len(parts) > 2:
        entry.append(
            int(parts[2], 16) if not parts[2].lower().startswith("0x") else int(parts[2], 0)
        )
    if len(parts) > 3:
        entry.append(parts[3])
    return tuple(entry)


def run_simulate(args: argparse.Namespace) -> int:
    try:
        modules = [parse_module(m) for m in args.module]
        if not modules:
            raise ValueError("give at least one --module")
    except ValueError as exc:
        print(f"fieldgate simulate dcon: {exc}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(_simulate(args, modules))
    except (ValueError, KeyError, PluginStartError) as exc:
        print(f"fieldgate simulate dcon: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0


async def _simulate(args: argparse.Namespace, modules: list[tuple]) -> int:
    pair = PtyPair() if args.pty else None
    port = pair.b if pair else args.port
    sim = DconSimulator.from_modules(
        port, modules, checksum=args.checksum, baudrate=args.baudrate, animate=args.animate
    )
    with stopped_by_signals() as stop:
        await sim.start()
        try:
            for m in sim.bus.modules.values():
                print(
                    f"module {m.address:3d}: {m.profile.model} ({m.profile.description}), type 0x{m.type_code:02X}, {m.data_format.name.lower()}",
                    flush=True,
                )
            print(f"serving on {pair.a if pair else port} (connect the gateway there)", flush=True)
            await wait_until(stop, args.duration)
        finally:
            await sim.stop()
            if pair:
                pair.close()
    return 0
