"""``fieldgate simulate BACK``: a back's simulated modules, served from the command line.

One command for every back whose plugin registers a simulator (``registry.add_simulator``),
with the same options wherever they mean the same thing:

* the modules: ``--topology FILE [--back NAME]`` (a topology's back, ``--set PATH=VALUE``
  overrides as everywhere), or ``--module SPEC`` (repeatable; ``ADDRESS:MODEL`` unless the
  plugin says otherwise) with ``--name`` for the channel ids;
* a serial back: ``--port PORT`` or ``--pty`` (a pseudo-terminal pair; the banner names the
  gateway's end), and ``--baudrate``;
* ``--animate``, ``--input CHANNEL=VALUE`` (initial inputs), ``--duration SECONDS``;
* the back's own options, in a group of their own (DCON's ``--checksum``).

While it runs it reads commands from standard input (``set``, ``get``, ``show``, ``quit``
and the simulator's own, such as the Modbus ``fault``), prints ``output CHANNEL = VALUE``
when the gateway writes an output, and stops on ``quit``, Ctrl-C or SIGTERM (exit 0).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import threading
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from .exitcodes import ExitCode
from .plugin import PluginStartError, Registry, Simulator
from .stopping import stopped_by_signals, wait_until
from .topology import BackConfig, SerialBackConfig, TopologyError

if TYPE_CHECKING:
    from .serial_link import PtyPair

OUTPUT_POLL_S = 0.05  # how often the outputs are looked at for "output CHANNEL = VALUE" lines


class UsageError(ValueError):
    """The command line cannot describe a back (exit 2, as argparse's own errors)."""


def is_serial(registry: Registry, back_type: str) -> bool:
    ctype = registry.lookup("back", back_type)
    return ctype is not None and issubclass(ctype.model, SerialBackConfig)


def configure(parser: argparse.ArgumentParser, registry: Registry, back_type: str) -> None:
    """The options of ``fieldgate simulate BACK_TYPE``."""
    from .cliargs import add_overrides_argument, deprecated_alias, seconds

    cli = registry.simulate_cli[back_type]
    modules = parser.add_argument_group("modules (a topology's back, or --module)")
    modules.add_argument("--topology", metavar="FILE", help="take the modules from this topology")
    modules.add_argument(
        "--back", help=f"the {back_type} back of --topology to serve (default: the first one)"
    )
    add_overrides_argument(modules, "backs.0.modules.0.address=2 (with --topology)")
    modules.add_argument(
        "--module",
        action="append",
        default=[],
        metavar=cli.module_metavar,
        help=f"a module, e.g. {cli.module_example} (repeatable)",
    )
    modules.add_argument(
        "--name", default="rs485", help="the back's name in channel ids with --module (rs485)"
    )
    if is_serial(registry, back_type):
        line = parser.add_argument_group("serial line")
        where = line.add_mutually_exclusive_group(required=True)
        where.add_argument("--port", help="serial port (or pyserial URL) to serve the modules on")
        where.add_argument(
            "--pty",
            action="store_true",
            help="create a pseudo-terminal pair; print the gateway's end",
        )
        line.add_argument(
            "--baudrate", type=int, help="baud rate (default: the topology's, or 9600)"
        )
        deprecated_alias(line, "--baud", "--baudrate", type=int)
    parser.add_argument(
        "--animate",
        action="store_true",
        help="inputs change by themselves (and outputs drive inputs where the simulator wires them)",
    )
    parser.add_argument(
        "--input",
        action="append",
        default=[],
        metavar="CHANNEL=VALUE",
        help="initial value of a simulated input, e.g. rs485/m1/di0=1 (repeatable)",
    )
    parser.add_argument(
        "--duration",
        type=seconds,
        default=0,
        metavar="SECONDS",
        help="stop after this long (0, the default: until quit, Ctrl-C or SIGTERM)",
    )
    if cli.configure is not None:
        cli.configure(parser.add_argument_group(f"{back_type} only"))


def build_config(args: argparse.Namespace, registry: Registry, back_type: str) -> BackConfig:
    """The back to simulate, from ``--topology`` or ``--module``.

    TopologyError: the topology file is invalid (exit 1); UsageError: the command line does
    not describe a valid back (exit 2).
    """
    from .cliargs import overrides_of
    from .topology import load_topology

    serial = is_serial(registry, back_type)
    cli = registry.simulate_cli[back_type]
    changes: dict[str, Any] = dict(cli.fields(args)) if cli.fields is not None else {}
    if serial:
        changes["port"] = args.port or "pty"  # a --pty pair replaces it when serving
        if args.baudrate:
            changes["baudrate"] = args.baudrate
    if args.topology:
        if args.module:
            raise UsageError("give --topology or --module, not both")
        topology = load_topology(args.topology, registry, overrides_of(args, args.topology))
        backs = [
            b
            for b in topology.backs
            if b.type == back_type and (args.back is None or b.name == args.back)
        ]
        if not backs:
            named = f" named {args.back}" if args.back else ""
            raise UsageError(f"{args.topology} has no {back_type} back{named}")
        # the validated back as it is (what validation derived stays: a DCON scan file),
        # with the command line's changes validated one by one
        config = backs[0].model_copy(deep=True)
        try:
            for key, value in changes.items():
                setattr(config, key, value)
        except ValidationError as exc:
            raise UsageError(_one_line(exc)) from None
        return config
    if not args.module:
        raise UsageError("give --topology FILE or at least one --module " + cli.module_metavar)
    try:
        data = {
            "name": args.name,
            "type": back_type,
            "modules": [cli.module(spec) for spec in args.module],
            **changes,
        }
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    model = registry.lookup("back", back_type)
    assert model is not None  # a simulator is registered only beside its back type
    try:
        built = model.model.model_validate(data)
    except ValidationError as exc:
        raise UsageError(_one_line(exc)) from None
    assert isinstance(built, BackConfig)
    return built


def _one_line(exc: ValidationError) -> str:
    return "; ".join(
        f"{'.'.join(map(str, e['loc']))}: {e['msg'].removeprefix('Value error, ')}"
        for e in exc.errors()
    )


def run(args: argparse.Namespace, registry: Registry, back_type: str) -> int:
    from .cliargs import deprecated, invalid_topology

    command = f"fieldgate simulate {back_type}"
    legacy = [item for item in args.set if "/" in item.partition("=")[0]]
    if legacy:  # simulate modbus took initial inputs as --set CHANNEL=VALUE
        deprecated("--set CHANNEL=VALUE", "--input CHANNEL=VALUE")
        args.set = [item for item in args.set if item not in legacy]
        args.input = [*legacy, *args.input]
    try:
        config = build_config(args, registry, back_type)
        inputs = [_input(item) for item in args.input]
    except TopologyError as exc:
        return invalid_topology(exc)
    except UsageError as exc:
        print(f"{command}: {exc}", file=sys.stderr)
        return ExitCode.CANNOT_RUN
    try:
        return asyncio.run(_serve(args, registry, config, inputs))
    except KeyboardInterrupt:  # before the signal handlers are in place, or where there are none
        return ExitCode.OK


def _input(item: str) -> tuple[str, bool | int | float | str]:
    channel, sep, value = item.partition("=")
    if not sep or not channel:
        raise UsageError(f"--input expects CHANNEL=VALUE, got {item!r}")
    return channel, number(value)


async def _serve(
    args: argparse.Namespace,
    registry: Registry,
    config: BackConfig,
    inputs: list[tuple[str, bool | int | float | str]],
) -> int:
    with stopped_by_signals() as stop:  # before the banner: a SIGTERM right after it stops cleanly
        return await _serve_until(stop, args, registry, config, inputs)


async def _serve_until(
    stop: asyncio.Event,
    args: argparse.Namespace,
    registry: Registry,
    config: BackConfig,
    inputs: list[tuple[str, bool | int | float | str]],
) -> int:
    command = f"fieldgate simulate {config.type}"
    pair: PtyPair | None = None
    port: str | None = None
    before = config.model_dump()
    if isinstance(config, SerialBackConfig):
        port = args.port
        if args.pty:
            from .serial_link import PtyPair

            pair = PtyPair()
            port, config.port = pair.b, pair.a
    try:
        sim = registry.simulators[config.type](config, port, args.animate)
        for channel, value in inputs:
            _set_input(sim, channel, value)
        await sim.start()
    except (PluginStartError, ValueError, KeyError) as exc:
        print(f"{command}: {exc.args[0] if exc.args else exc}", file=sys.stderr)
        if pair is not None:
            pair.close()
        return ExitCode.CANNOT_RUN
    for line in sim.describe():
        print(line, flush=True)
    print(banner(config, before, port, pair is not None), flush=True)
    channels = [spec.id for spec in config.channel_specs()]
    outputs = [spec.id for spec in config.channel_specs() if spec.kind.is_output]
    try:
        await _command_loop(sim, channels, outputs, stop, args.duration)
    finally:
        await sim.stop()
        if pair is not None:
            pair.close()
    return ExitCode.OK


def banner(config: BackConfig, before: dict[str, Any], port: str | None, pty: bool) -> str:
    """The line that says what is simulated and where the gateway finds it (the ready line)."""
    listed = {m.address: m.model for m in config.modules}
    for spec in config.channel_specs():  # modules no list names (found at start: a scan file's)
        listed.setdefault(spec.source.module, None)
    modules = ", ".join(
        f"{address}{' (' + model + ')' if model else ''}"
        for address, model in sorted(listed.items())
    )
    head = f"simulating back {config.name} ({config.type}): modules {modules or '-'}"
    if isinstance(config, SerialBackConfig):
        if pty:
            return f"{head}; point the gateway at {config.port} (--set backs.{config.name}.port={config.port})"
        return f"{head} on {port}; connect the gateway's line to it"
    changed = {
        key: value
        for key, value in config.model_dump().items()
        if before.get(key) != value and not isinstance(value, (dict, list))
    }
    where = " ".join(f"--set backs.{config.name}.{k}={v}" for k, v in changed.items())
    return f"{head}; point the gateway at it: {where}" if where else head


async def _command_loop(
    sim: Simulator,
    channels: list[str],
    outputs: list[str],
    stop: asyncio.Event,
    duration: float,
) -> None:
    """Commands from stdin until ``quit``, ``stop`` (SIGINT/SIGTERM) or ``duration``; a closed
    stdin leaves the modules served. Output changes are printed as they are seen."""
    lines: asyncio.Queue[str] = asyncio.Queue()
    _read_stdin(asyncio.get_running_loop(), lines)

    async def commands() -> None:
        while True:
            reply = execute(sim, channels, await lines.get())
            if reply == "quit":
                stop.set()
                return
            if reply:
                print(reply, flush=True)

    async def watch_outputs() -> None:
        seen = {cid: _value(sim.get_output, cid) for cid in outputs}
        while True:
            await asyncio.sleep(OUTPUT_POLL_S)
            for cid in outputs:
                value = _value(sim.get_output, cid)
                if value != seen[cid]:
                    seen[cid] = value
                    print(f"output {cid} = {value}", flush=True)

    tasks = [asyncio.create_task(commands()), asyncio.create_task(watch_outputs())]
    try:
        await wait_until(stop, duration)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


def _value(read: Any, channel: str) -> object:
    try:
        return read(channel)
    except (KeyError, ValueError, NotImplementedError):
        return "?"


def _read_stdin(loop: asyncio.AbstractEventLoop, lines: asyncio.Queue[str]) -> None:
    """Feed stdin's lines to ``lines`` from a daemon thread: a read blocked on a terminal
    must not keep the process alive once it is stopped (asyncio.to_thread's worker would)."""

    def read() -> None:
        for line in sys.stdin or ():
            try:
                loop.call_soon_threadsafe(lines.put_nowait, line)
            except RuntimeError:  # the loop is closed: stopping
                return

    threading.Thread(target=read, name="simulate-stdin", daemon=True).start()


def execute(sim: Simulator, channels: list[str], line: str) -> str:
    """Run one command line; returns what to print ("quit" to stop)."""
    words = line.split()
    if not words:
        return ""
    cmd, rest = words[0].lower(), words[1:]
    try:
        if cmd in ("quit", "exit"):
            return "quit"
        if cmd == "set" and len(rest) == 2:
            _set_input(sim, rest[0], number(rest[1]))
            return f"{rest[0]} = {sim.get(rest[0])}"
        if cmd == "get" and len(rest) == 1:
            return f"{rest[0]} = {sim.get(rest[0])}"
        if cmd == "show":
            return "\n".join(f"{cid} = {_value(sim.get, cid)}" for cid in channels)
        own = sim.command(words)
        if own is not None:
            return own
    except (KeyError, ValueError) as exc:
        return f"error: {exc.args[0] if exc.args else exc}"
    extra = sim.commands_help()
    return (
        "commands: set CHANNEL VALUE | get CHANNEL | show"
        + (f" | {extra}" if extra else "")
        + " | quit"
    )


def _set_input(sim: Simulator, channel: str, value: Any) -> None:
    """A typed value to the simulator: text goes to simulators that serve string channels (the
    others refuse it as they refuse any value their channel cannot hold)."""
    sim.set_input(channel, value)


def number(text: str) -> bool | int | float | str:
    """A value typed on the command line: on/off/true/false, an integer (0x.. too), a float, or
    text for a string channel (in quotes when it would read as one of the others: "12")."""
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        return text[1:-1]
    low = text.lower()
    if low in ("true", "on"):
        return True
    if low in ("false", "off"):
        return False
    try:
        return int(text, 0)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text  # a string channel's text; any other channel refuses it with its type
