"""The ``fieldgate`` command line.

Core commands: ``validate``, ``run``, ``plugins``. Plugins add their own
(``simulate modbus``, ``scan dcon``, ``eds``, ...) through the registry.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeAlias

from .cliargs import (  # `X as X`: plugins import these from here too
    add_overrides_argument as add_overrides_argument,
)
from .cliargs import invalid_topology, seconds, usage_error
from .cliargs import (
    overrides_of as overrides_of,
)
from .cliargs import (
    parse_overrides as parse_overrides,
)
from .exitcodes import ExitCode
from .logsetup import LOG_FORMATS, setup_logging
from .plugin import ENTRY_POINT_GROUP, Command, Registry, load_registry, one_line
from .runtime import Gateway, GatewayStartError
from .stopping import stopped_by_signals, wait_until
from .topology import TopologyError, load_topology
from .version import __version__

if TYPE_CHECKING:  # ruamel.yaml is imported when --set is used, not at every start
    from .image import ProcessImage


def cmd_validate(args: argparse.Namespace, registry: Registry) -> int:
    try:
        topology = load_topology(args.file, registry, overrides_of(args, args.file))
    except TopologyError as exc:
        code = invalid_topology(exc)
        print(f"{args.file}: {len(exc.issues)} error(s)", file=sys.stderr)
        return code
    print(f"{args.file}: valid")
    print(topology.summary())
    return ExitCode.OK


PLUGINS_HEADER = ("PLUGIN", "VERSION", "DISTRIBUTION", "PROVIDES", "SUMMARY")


def cmd_plugins(args: argparse.Namespace, registry: Registry) -> int:
    """The installed plugins as a table; exit 1 when one failed to load (its row says why)."""
    if not registry.plugins:
        print(f"no plugins installed (entry-point group {ENTRY_POINT_GROUP})")
        return ExitCode.OK
    rows = [PLUGINS_HEADER]
    for name, info in sorted(registry.plugins.items()):
        summary = f"FAILED: {info.error}" if info.failed else info.summary
        rows.append(
            (name, info.version, info.distribution, ", ".join(info.provides) or "-", summary)
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(PLUGINS_HEADER) - 1)]
    for row in rows:
        cells = [cell.ljust(width) for cell, width in zip(row, widths, strict=False)]
        print("  ".join([*cells, row[-1]]).rstrip())
    failed = registry.failed()
    if failed:
        names = ", ".join(info.name for info in failed)
        print(f"fieldgate plugins: {len(failed)} plugin(s) failed: {names}", file=sys.stderr)
        return ExitCode.FAILED
    return ExitCode.OK


def cmd_run(args: argparse.Namespace, registry: Registry) -> int:
    overrides = overrides_of(args, args.file)
    if args.http is not None:
        overrides["gateway.http.listen"] = args.http
    try:
        gateway = Gateway.load(
            args.file,
            overrides,
            registry,
            simulate=args.simulate,
            animate=args.simulate,
        )
    except TopologyError as exc:
        return invalid_topology(exc)
    return _runner(args.loop).run(_run(gateway, args))


LOOP_CHOICES = ("auto", "uvloop", "asyncio")


def loop_factory(choice: str = "auto") -> Callable[[], asyncio.AbstractEventLoop]:
    """The event loop ``fieldgate run`` uses: uvloop when installed (``auto``), or asyncio's own.

    uvloop is a dependency on Linux and macOS: it wakes for a frame handed over from
    another thread in about two thirds of the time of asyncio's loop, which is most of
    an SDO round trip (docs/canopen-bench.md). ``asyncio`` forces the standard loop.
    """
    if choice not in LOOP_CHOICES:
        raise ValueError(f"event loop {choice!r}: expected one of {', '.join(LOOP_CHOICES)}")
    if choice == "asyncio":
        return asyncio.new_event_loop
    try:
        import uvloop
    except ImportError:
        if choice == "uvloop":
            usage_error(
                "--loop uvloop: uvloop is not installed here (pip install uvloop; there is none for Windows)"
            )
        return asyncio.new_event_loop
    return uvloop.new_event_loop


def loop_name(loop: asyncio.AbstractEventLoop) -> str:
    return "uvloop" if type(loop).__module__.startswith("uvloop") else "asyncio"


def _runner(choice: str) -> asyncio.Runner:
    return asyncio.Runner(loop_factory=loop_factory(choice))


async def _run(gateway: Gateway, args: argparse.Namespace) -> int:
    from .systemd import Notifier, status_line

    log = logging.getLogger("fieldgate")
    notifier = Notifier.from_environment()  # systemd's Type=notify service (docs/deploy.md)
    with stopped_by_signals() as stop:
        log.info("event loop: %s", loop_name(asyncio.get_running_loop()))
        tasks = []

        def fieldbus_up() -> None:
            """READY as soon as the fieldbus side runs (the north-facing children follow)."""
            if notifier is not None:
                notifier.ready(status_line(gateway))
                tasks.append(asyncio.create_task(notifier.keep_alive(lambda: status_line(gateway))))

        async def shut_down(why: str) -> None:
            log.info(why)
            if notifier is not None:
                notifier.stopping()
            for task in tasks:
                task.cancel()
            await gateway.stop()
            if notifier is not None:
                notifier.close()

        try:
            if not await _start_unless_stopped(gateway, stop, fieldbus_up):
                await shut_down("stopping (asked to while starting)")
                return ExitCode.OK
        except GatewayStartError as exc:
            log.error("cannot start: %s", exc)
            for task in tasks:
                task.cancel()
            if notifier is not None:
                notifier.status(f"cannot start: {exc}")
                notifier.close()
            return ExitCode.CANNOT_RUN
        if args.status_every:
            tasks.append(asyncio.create_task(_print_status(gateway, args.status_every)))
        await wait_until(stop, args.duration)
        await shut_down("stopping")
    return ExitCode.OK


async def _start_unless_stopped(
    gateway: Gateway, stop: asyncio.Event, on_fieldbus_up: Callable[[], None]
) -> bool:
    """Start the gateway; False when SIGTERM/SIGINT came first (the start is cancelled: the
    north-facing children start after READY and an OPC UA server's certificate took seconds
    on a busy host, which a stop must not wait for)."""
    starting = asyncio.ensure_future(gateway.start(on_fieldbus_up=on_fieldbus_up))
    asked = asyncio.ensure_future(stop.wait())
    await asyncio.wait({starting, asked}, return_when=asyncio.FIRST_COMPLETED)
    asked.cancel()
    if starting.done():
        starting.result()  # GatewayStartError goes to the caller
        return True
    starting.cancel()
    await asyncio.gather(starting, return_exceptions=True)
    return False


STATUS_LEGEND = (
    "status lines: per module and kind, digital channels as bits with channel 0 first (leftmost), "
    "analog channels as raw values; '!quality' when not every channel of the group is good"
)


async def _print_status(gateway: Gateway, period: float) -> None:
    print(STATUS_LEGEND, flush=True)
    while True:
        await asyncio.sleep(period)
        print(format_image(gateway.image), flush=True)


def format_image(image: ProcessImage) -> str:
    """One line: per module and kind, digital channels as bits (channel 0 first), analog as values.

    A group whose channels are not all good shows the worst quality, e.g. ``rs485/m5 ai=[0]!comm-fault``.
    """
    groups: dict[tuple[Any, ...], list[Any]] = {}
    for ch in image:
        groups.setdefault((ch.source.back, ch.source.module, ch.kind), []).append(ch)
    parts = []
    for (back, module, kind), channels in sorted(
        groups.items(), key=lambda kv: (kv[0][0], kv[0][1], kv[0][2].value)
    ):
        channels.sort(key=lambda c: c.source.index)
        if kind.is_digital:
            text = "".join("1" if c.value else "0" for c in channels)
        else:
            text = "[" + ",".join(str(c.value) for c in channels) + "]"
        bad = sorted({c.quality.value for c in channels if c.quality.value != "good"})
        parts.append(f"{back}/m{module} {kind.value}={text}" + ("!" + "/".join(bad) if bad else ""))
    return " | ".join(parts)


LOG_LEVELS = ["debug", "info", "warning", "error"]


Subparsers: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"


def build_parser(registry: Registry, *, run_only: bool = False) -> argparse.ArgumentParser:
    """The command line: core's commands, then the plugins' (``simulate BACK``, ``scan
    BACK``, their own commands), in the order ``--help`` lists them; ``run_only``:
    ``validate`` and ``run`` alone (``fieldgate run FILE``: the other commands' modules stay
    unloaded, a gateway's memory is what it runs)."""
    parser = argparse.ArgumentParser(
        prog="fieldgate",
        description="Fieldbus gateway: fieldbus slave fronts, RS-485 poller backs, one YAML topology.",
    )
    parser.add_argument("--version", action="version", version=f"fieldgate {__version__}")
    _log_options(parser, default_level="info", default_format="text")
    # the same options after the command too (`fieldgate run x.yaml --log-level debug`)
    common = argparse.ArgumentParser(add_help=False)
    _log_options(common, default_level=argparse.SUPPRESS, default_format=argparse.SUPPRESS)
    sub = _with_parents(
        parser.add_subparsers(dest="command", metavar="COMMAND", required=True), common
    )
    _add_topology_commands(sub)
    if run_only:
        return parser
    _add_host_commands(sub, registry)
    groups = _CommandGroups(sub, common)
    _add_back_commands(groups, registry)
    _add_plugin_commands(sub, groups, registry)
    return parser


def _log_options(parser: argparse.ArgumentParser, default_level: str, default_format: str) -> None:
    parser.add_argument(
        "--log-level",
        default=default_level,
        choices=LOG_LEVELS,
        help="log verbosity (default info)",
    )
    parser.add_argument(
        "--log-format",
        default=default_format,
        choices=LOG_FORMATS,
        help="text (default) or json: one JSON object a line",
    )


def _add_topology_commands(sub: Subparsers) -> None:
    """``validate`` and ``run``: the two commands on a topology file."""
    p = sub.add_parser(
        "validate", help="check a topology file; print every error with file:line:column"
    )
    p.add_argument("file")
    add_overrides_argument(p)
    p.set_defaults(handler=cmd_validate)

    p = sub.add_parser("run", help="run a gateway until SIGINT/SIGTERM")
    p.add_argument("file")
    add_overrides_argument(p)
    p.add_argument(
        "--simulate",
        action="store_true",
        help="serve every back from simulated modules on pseudo-terminals (no hardware)",
    )
    p.add_argument(
        "--loop",
        choices=LOOP_CHOICES,
        default="auto",
        help="event loop: auto (default: uvloop when installed, else asyncio), uvloop, or asyncio's standard loop",
    )
    p.add_argument(
        "--status-every",
        type=seconds,
        default=0,
        metavar="SECONDS",
        help="print the process image periodically (0, the default: never)",
    )
    p.add_argument(
        "--duration",
        type=seconds,
        default=0,
        metavar="SECONDS",
        help="stop by itself after this long (0, the default: run until stopped)",
    )
    p.add_argument(
        "--http",
        metavar="HOST:PORT",
        help="serve the status API, /metrics and the live page there (sets gateway.http.listen; "
        "a non-loopback address needs a token in the topology)",
    )
    p.set_defaults(handler=cmd_run)


def _add_host_commands(sub: Subparsers, registry: Registry) -> None:
    """``doctor``, ``status``, ``plugins``, ``service-unit``, ``eds``: the installation,
    a running gateway, the plugins, a front's EDS."""
    from . import doctorcmd as doctor

    p = sub.add_parser(
        "doctor",
        help="check what a topology needs of this host before run (CAN interfaces, serial "
        "ports, listeners, the systemd unit); one line per finding with its fix",
    )
    doctor.configure(p)
    p.set_defaults(handler=lambda a, r: doctor.run(a, r))

    from .statuscmd import configure_status, run_status

    p = sub.add_parser(
        "status",
        help="show a running gateway's status as a table (from its HTTP API); exit 1 when not ready",
    )
    configure_status(p)
    p.set_defaults(handler=lambda a, r: run_status(a))

    p = sub.add_parser(
        "plugins",
        help="list installed plugins: version, distribution, what each provides, summary; "
        "exit 1 when one failed to load",
    )
    p.set_defaults(handler=cmd_plugins)

    from . import edscmd, unitcmd

    p = sub.add_parser(
        "service-unit",
        help=f"print the systemd unit {unitcmd.UNIT_NAME} for this installation (docs/deploy.md)",
    )
    unitcmd.configure(p)
    p.set_defaults(handler=lambda a, r: unitcmd.run(a))

    p = sub.add_parser("eds", help="write the EDS of a front (CANopen, DeviceNet, ...)")
    edscmd.configure(p, registry)
    p.set_defaults(handler=edscmd.run)


class _CommandGroups:
    """Command words that hold sub-commands (``simulate``, ``scan``, a plugin's group),
    made on first use."""

    def __init__(self, sub: Subparsers, common: argparse.ArgumentParser):
        self.sub = sub
        self.common = common
        self.groups: dict[str, Subparsers] = {}

    def __call__(self, path: tuple[str, ...], help_text: str | None = None) -> Subparsers:
        parent = self.sub
        for depth, word in enumerate(path):
            key = " ".join(path[: depth + 1])
            if key not in self.groups:
                group_parser = parent.add_parser(
                    word, help=help_text or f"{word} commands from plugins"
                )
                self.groups[key] = _with_parents(
                    group_parser.add_subparsers(dest=f"sub{depth}", metavar="BACK", required=True),
                    self.common,
                )
            parent = self.groups[key]
        return parent


def _add_back_commands(group: _CommandGroups, registry: Registry) -> None:
    """``simulate BACK`` for every back with a simulator, ``scan BACK`` for every scanner."""
    from . import scancmd, simcmd

    for back_type in sorted(registry.simulators):
        p = group(
            ("simulate",), "serve a back's simulated modules (a serial line, a file, ...)"
        ).add_parser(
            back_type,
            help=f"simulated {back_type} modules [{registry.provider(f'simulator:{back_type}')}]",
        )
        simcmd.configure(p, registry, back_type)
        p.set_defaults(handler=lambda a, r, t=back_type: simcmd.run(a, r, t))
    for back_type, scanner in sorted(registry.scanners.items()):
        p = group(("scan",), "find the modules on a line; print a topology section").add_parser(
            back_type,
            help=f"find {back_type} modules on a line [{registry.provider(f'scan:{back_type}')}]",
        )
        scancmd.configure(p, scanner, back_type)
        p.set_defaults(handler=lambda a, r, t=back_type: scancmd.run(a, r, t))


def _add_plugin_commands(sub: Subparsers, group: _CommandGroups, registry: Registry) -> None:
    """The plugins' own commands; one whose name fieldgate has, or whose options fail to
    set up, is reported by ``fieldgate plugins`` and left out."""
    for command in sorted(registry.commands, key=lambda c: c.path):
        parent = group(command.path[:-1]) if len(command.path) > 1 else sub
        if command.path[-1] in parent.choices:  # a core command (simulate BACK, eds) has the name
            info = registry.plugins.get(command.plugin)
            if info is not None and not info.failed:
                info.error = f"command '{' '.join(command.path)}' is taken by fieldgate itself"
            continue
        cp = parent.add_parser(command.path[-1], help=f"{command.help} [{command.plugin}]")
        try:
            command.configure(cp)
        except Exception as exc:  # a broken plugin command must not take the others down
            _command_broken(registry, command, cp, one_line(exc))
            continue
        cp.set_defaults(handler=lambda a, r, run=command.run: run(a))


def _command_broken(
    registry: Registry, command: Command, parser: argparse.ArgumentParser, error: str
) -> None:
    """A plugin command whose options could not be set up: ``fieldgate plugins`` reports the
    plugin as failed, and the command itself says so in one line (exit 2)."""
    words = " ".join(command.path)
    info = registry.plugins.get(command.plugin)
    if info is not None and not info.failed:
        info.error = f"command '{words}': {error}"

    def refuse(args: argparse.Namespace, registry: Registry) -> int:
        print(f"fieldgate {words}: broken in plugin {command.plugin}: {error}", file=sys.stderr)
        return ExitCode.CANNOT_RUN

    parser.set_defaults(handler=refuse)


def _with_parents(
    subparsers: argparse._SubParsersAction[argparse.ArgumentParser], common: argparse.ArgumentParser
) -> argparse._SubParsersAction[argparse.ArgumentParser]:
    """Every parser added to ``subparsers`` also takes ``common``'s options."""
    add_parser = subparsers.add_parser

    def add_with_parents(name: str, **kwargs: Any) -> argparse.ArgumentParser:
        return add_parser(name, parents=[common, *kwargs.pop("parents", [])], **kwargs)

    subparsers.add_parser = add_with_parents  # type: ignore[method-assign]
    return subparsers


def topology_types(argv: list[str]) -> set[str] | None:
    """The front and back types of the topology ``fieldgate run FILE`` names, read from the
    file before anything else is loaded (None: not a run, or not that simple: load every
    plugin). A gateway then loads only the plugins it runs."""
    words = iter(argv)
    for word in words:
        if word in ("--log-level", "--log-format"):
            next(words, None)
        elif word.startswith("-"):
            continue
        elif word != "run":
            return None
        else:
            break
    else:
        return None
    rest = list(words)
    if any(w.startswith("--set") and ".type" in w for w in rest) or any(
        ".type=" in w for w in rest
    ):
        return None  # a type changed from the command line
    file = next((w for w in rest if not w.startswith("-")), None)
    if file is None:
        return None
    try:
        from .topology.loader import read_yaml

        data = read_yaml(file)
        types = {str(c["type"]) for part in ("fronts", "backs") for c in data[part]}
    except Exception:  # the full load reports the problem properly
        return None
    return types or None


def main(argv: list[str] | None = None) -> int:
    setup_logging("warning")
    args_given = sys.argv[1:] if argv is None else argv
    types = topology_types(args_given)
    registry = load_registry(only=types)
    parser = build_parser(registry, run_only=types is not None)
    args = parser.parse_args(argv)
    setup_logging(args.log_level, args.log_format)
    try:
        return int(args.handler(args, registry) or 0)
    except KeyboardInterrupt:
        return ExitCode.INTERRUPTED
    except BrokenPipeError:
        return ExitCode.OK


if __name__ == "__main__":
    sys.exit(main())
