"""The conformance test tool for CANopen and DeviceNet devices: ``fieldgate conformance`` (also ``python -m fieldgate.conformance``)."""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

from fieldgate.exitcodes import ExitCode
from fieldgate.plugin import PluginStartError, Registry, hookimpl

from .framework import (
    DEVICENET_PROFILES,
    MASTER_PROFILES,
    OPT_IN,
    PROFILES,
    PROTOCOL_PROFILES,
    Options,
    Timing,
    Verdict,
)
from .outcome import DeviceSilent
from .report import details, line, summary, write_junit

if TYPE_CHECKING:
    from collections.abc import Callable

    from .framework import CaseResult
    from .runner import SuiteConfig

HELP = "run the CANopen conformance suite against a device (black box: bus + EDS)"
VIRTUAL_HINT = (
    "; note: python-can's virtual bus exists only inside one process, so a gateway started in another"
    " process is not on it (use socketcan with a vcan channel, or a real adapter)"
)


def _shell(command: str) -> Callable[[], None]:
    """``--power-cycle``: run the command; one that fails stops the case with its exit code."""

    def run() -> None:
        done = subprocess.run(command, shell=True, check=False)
        if done.returncode:
            raise RuntimeError(f"--power-cycle {command!r} exited {done.returncode}")

    return run


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--interface",
        default="socketcan",
        help="python-can interface (socketcan, virtual, pcan, slcan, ...); default socketcan",
    )
    p.add_argument("--channel", default="vcan0", help="python-can channel; default vcan0")
    p.add_argument("--bitrate", type=int, default=None, help="bit rate for adapters that set it")
    p.add_argument(
        "--protocol",
        choices=("canopen", "devicenet"),
        default="canopen",
        help="the device's protocol; default canopen",
    )
    p.add_argument(
        "--mac-id",
        type=int,
        help="devicenet: MAC ID of the device under test (0..63); no EDS needed",
    )
    p.add_argument(
        "--master-mac",
        type=int,
        default=0,
        help="devicenet: the tester's own MAC ID (must be free on the bus); default 0",
    )
    p.add_argument(
        "--node-id",
        type=int,
        help="node-ID of the device under test (1..127); required unless --list",
    )
    p.add_argument(
        "--eds", metavar="FILE", help="the device's EDS (or DCF); required unless --list"
    )
    p.add_argument(
        "--profile",
        action="append",
        choices=PROFILES + DEVICENET_PROFILES + ("all",),
        default=[],
        help=f"run only these profiles (repeatable): {', '.join(PROFILES)} (canopen), {', '.join(DEVICENET_PROFILES)} (devicenet); default: all of the protocol's but the device-specific {', '.join(OPT_IN)}; 'all': the CiA profiles the device's EDS supports and the device-specific ones its identity (0x1018 vendor-ID, 0x1008 name) matches; the master-fit {', '.join(MASTER_PROFILES)} runs only when named",
    )
    p.add_argument(
        "-k",
        dest="patterns",
        action="append",
        default=[],
        metavar="PATTERN",
        help="run only cases whose id contains PATTERN (or matches a glob); repeatable",
    )
    p.add_argument("--list", action="store_true", help="list the selected cases and exit")
    p.add_argument(
        "--shuffle",
        type=int,
        default=None,
        metavar="SEED",
        help="run the cases in an order shuffled with SEED (every verdict must be the same as in order)",
    )
    p.add_argument("--junit", metavar="FILE", help="also write a JUnit XML report")
    p.add_argument(
        "--loopback",
        action="store_true",
        help="the device's outputs are wired to its inputs (DO n → DI n, AO n → AI n): enables the I/O cases",
    )
    p.add_argument(
        "--lss-spare-node-id",
        type=int,
        default=None,
        metavar="ID",
        help="a free node-ID the LSS cases may configure temporarily (default: node-ID + 1)",
    )
    p.add_argument(
        "--power-cycle",
        metavar="COMMAND",
        default=None,
        help="a shell command that restarts the device as at power-on (a relay, 'systemctl "
        "restart fieldgate@plc'); enables the cases that need a power-on",
    )
    t = Timing()
    g = p.add_argument_group("timing")
    g.add_argument(
        "--timeout",
        type=float,
        default=t.response,
        metavar="S",
        help=f"wait for an answer that must come (default {t.response})",
    )
    g.add_argument(
        "--silence",
        type=float,
        default=t.silence,
        metavar="S",
        help=f"watch for a frame that must not come (default {t.silence})",
    )
    g.add_argument(
        "--tolerance-ms",
        type=float,
        default=t.tolerance_ms,
        help=f"absolute slack on periods and delays (default {t.tolerance_ms})",
    )
    g.add_argument(
        "--tolerance-pct",
        type=float,
        default=t.tolerance_pct,
        help=f"relative slack on periods and delays (default {t.tolerance_pct})",
    )
    g.add_argument(
        "--heartbeat-ms",
        type=int,
        default=t.heartbeat_ms,
        help=f"producer time used by heartbeat cases (default {t.heartbeat_ms})",
    )
    g.add_argument(
        "--bootup-timeout",
        type=float,
        default=t.bootup,
        metavar="S",
        help=f"a reset must end in a boot-up within this (default {t.bootup})",
    )
    g.add_argument(
        "--sdo-server-timeout",
        type=float,
        default=t.sdo_server_timeout,
        metavar="S",
        help=f"a stalled SDO transfer must be aborted within this (default {t.sdo_server_timeout})",
    )


def config_from_args(args: argparse.Namespace) -> SuiteConfig:
    from .runner import SuiteConfig

    timing = Timing(
        response=args.timeout,
        silence=args.silence,
        tolerance_ms=args.tolerance_ms,
        tolerance_pct=args.tolerance_pct,
        heartbeat_ms=args.heartbeat_ms,
        bootup=args.bootup_timeout,
        sdo_server_timeout=args.sdo_server_timeout,
    )
    options = Options(
        loopback=args.loopback,
        lss_spare_node_id=args.lss_spare_node_id,
        power_cycle=_shell(args.power_cycle) if args.power_cycle else None,
    )
    return SuiteConfig(
        args.node_id,
        args.eds,
        args.profile,
        args.patterns,
        timing,
        options,
        shuffle=getattr(args, "shuffle", None),
    )


def run(args: argparse.Namespace) -> int:
    # the case modules load only when cases are listed or run, not at every `fieldgate` start
    from .catalog import select
    from .runner import run_suite

    foreign = [p for p in args.profile if p != "all" and p not in PROTOCOL_PROFILES[args.protocol]]
    if foreign:
        print(
            f"conformance: profile {', '.join(foreign)} is not a {args.protocol} profile (see --protocol)",
            file=sys.stderr,
        )
        return ExitCode.CANNOT_RUN
    if args.list:
        for c in select(args.profile, args.patterns, protocol=args.protocol):
            print(f"{c.id:<34} {c.title}")
        return ExitCode.OK
    if args.protocol == "devicenet":
        return run_devicenet(args)
    if args.node_id is None or args.eds is None:
        print("conformance: --node-id and --eds are required", file=sys.stderr)
        return ExitCode.CANNOT_RUN
    if not 1 <= args.node_id <= 127:
        print("conformance: --node-id must be 1..127", file=sys.stderr)
        return ExitCode.CANNOT_RUN
    config = config_from_args(args)
    print(
        f"fieldgate conformance: node {args.node_id} on {args.interface}:{args.channel}, EDS {args.eds}",
        flush=True,
    )

    properties = {
        "node-id": str(args.node_id),
        "bus": f"{args.interface}:{args.channel}",
        "eds": args.eds,
    }
    return _run_and_report(
        args,
        properties,
        lambda progress, on_start: run_suite(
            config,
            interface=args.interface,
            channel=args.channel,
            bitrate=args.bitrate,
            progress=progress,
            on_start=on_start,
        ),
    )


def _run_and_report(
    args: argparse.Namespace,
    properties: dict[str, str],
    start: Callable[
        [Callable[[CaseResult], None], Callable[[dict[str, str]], None]], list[CaseResult]
    ],
) -> int:
    """Run ``start(progress, on_start)``, print the report, write JUnit; the exit code."""

    def progress(result: CaseResult) -> None:
        print(line(result), flush=True)
        if result.verdict in (Verdict.FAIL, Verdict.INFO):
            print("\n".join(details(result)), flush=True)

    def on_start(header: dict[str, str]) -> None:
        properties.update(header)
        ident = {k: v for k, v in header.items() if k not in RUN_KEYS}
        if ident:
            print("device: " + ", ".join(f"{k} {v}" for k, v in ident.items()), flush=True)
        for key in RUN_KEYS:
            if header.get(key):
                print(f"{key}: {header[key]}", flush=True)

    try:
        results = start(progress, on_start)
    except DeviceSilent as exc:
        print(
            f"conformance: cannot start: {exc}{VIRTUAL_HINT if args.interface == 'virtual' else ''}",
            file=sys.stderr,
        )
        return ExitCode.CANNOT_RUN
    except (
        OSError,
        ValueError,
        PluginStartError,
    ) as exc:  # the bus (one line from open_bus) or the EDS
        print(f"conformance: cannot start: {exc}", file=sys.stderr)
        return ExitCode.CANNOT_RUN
    print()
    print(summary(results))
    if args.junit:
        write_junit(results, args.junit, properties)
    return ExitCode.FAILED if any(r.verdict is Verdict.FAIL for r in results) else ExitCode.OK


RUN_KEYS = ("profiles", "left out", "EDS notes")  # header lines beside the device's identity


def run_devicenet(args: argparse.Namespace) -> int:
    from .runner import DnetSuiteConfig, run_devicenet_suite

    if (
        args.mac_id is None
        or not 0 <= args.mac_id <= 63
        or not 0 <= args.master_mac <= 63
        or args.mac_id == args.master_mac
    ):
        print(
            "conformance: --protocol devicenet needs --mac-id 0..63 (and a different --master-mac 0..63)",
            file=sys.stderr,
        )
        return ExitCode.CANNOT_RUN
    base = config_from_args(args)
    config = DnetSuiteConfig(
        args.mac_id, args.master_mac, args.profile, args.patterns, base.timing, base.options
    )
    print(
        f"fieldgate conformance: DeviceNet MAC ID {args.mac_id} on {args.interface}:{args.channel} (tester MAC ID {args.master_mac})",
        flush=True,
    )
    properties = {"mac-id": str(args.mac_id), "bus": f"{args.interface}:{args.channel}"}
    return _run_and_report(
        args,
        properties,
        lambda progress, on_start: run_devicenet_suite(
            config,
            interface=args.interface,
            channel=args.channel,
            bitrate=args.bitrate,
            progress=progress,
            on_start=on_start,
        ),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fieldgate.conformance", description=HELP)
    configure(parser)
    return run(parser.parse_args(argv))


@hookimpl
def fieldgate_register(registry: Registry) -> None:
    registry.add_command(("conformance",), HELP, configure, run)
