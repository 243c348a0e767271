"""``fieldgate simulate modbus``: simulated Modbus RTU modules on a serial port or a pty.

Modules come from a topology's back (``--topology FILE --back NAME``) or from the
command line (``--module 1:M-7052D --module 3:M-7055D``). ``--pty`` creates a
pseudo-terminal pair and prints the end the gateway should open. While it runs, it
reads commands from stdin::

    set rs485/m1/di0 1        drive an input      get rs485/m3/do0    read any channel
    show                      every channel        fault 3 no_answer [COUNT] [code=N] [delay=S] [address=N]
    clear [ADDRESS]           remove faults        quit

Ctrl-C (SIGINT) or SIGTERM stops it with exit code 0, as ``quit`` does.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import threading

from pydantic import ValidationError

from fieldgate.plugin import PluginStartError
from fieldgate.stopping import stopped_by_signals, wait_until

from .config import ModbusBackConfig
from .simulator import FAULT_KINDS, Fault, ModbusSimulator


def configure(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", help="serial port (or pyserial URL) to serve the modules on")
    where.add_argument(
        "--pty",
        action="store_true",
        help="create a pseudo-terminal pair and print the gateway's end",
    )
    parser.add_argument("--topology", help="take the modules from this topology file (with --back)")
    parser.add_argument(
        "--back", help="name of the modbus back in --topology (default: the first modbus back)"
    )
    parser.add_argument(
        "--module",
        action="append",
        default=[],
        metavar="ADDR:MODEL",
        help="a module by preset, e.g. 3:M-7055D (repeatable)",
    )
    parser.add_argument(
        "--name",
        default="rs485",
        help="back name used in channel ids with --module (default rs485)",
    )
    parser.add_argument("--baudrate", type=int, help="baud rate (default: the topology's, or 9600)")
    # --baud, the name simulate dcon used to take: accepted everywhere, not in the help
    parser.add_argument(
        "--baud", type=int, dest="baudrate", default=argparse.SUPPRESS, help=argparse.SUPPRESS
    )
    parser.add_argument(
        "--animate",
        action="store_true",
        help="move unwired inputs and wire DO->DI, AO->AI like the I-7232D demo",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="CHANNEL=VALUE",
        help="initial input value (repeatable)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        help="stop after this many seconds (default: until quit or Ctrl-C)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        config = build_config(args)
    except (ValueError, KeyError) as exc:
        print(f"fieldgate simulate modbus: {exc}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(_serve(config, args))
    except KeyboardInterrupt:  # before the signal handlers are in place, or where there are none
        return 0


def build_config(args: argparse.Namespace) -> ModbusBackConfig:
    port = args.port or "pty"
    if args.topology:
        from fieldgate.plugin import load_registry
        from fieldgate.topology import TopologyError, load_topology

        try:
            topology = load_topology(args.topology, load_registry())
        except TopologyError as exc:
            raise ValueError("; ".join(str(i) for i in exc.issues)) from None
        backs = [
            b
            for b in topology.backs
            if b.type == "modbus" and (args.back is None or b.name == args.back)
        ]
        if not backs:
            raise ValueError(
                f"{args.topology} has no modbus back{' named ' + args.back if args.back else ''}"
            )
        data = backs[0].model_dump(exclude_unset=True) | {"port": port}
    elif args.module:
        modules = []
        for item in args.module:
            address, sep, model = item.partition(":")
            if not sep or not address.isdigit():
                raise ValueError(f"--module expects ADDRESS:MODEL, got {item!r}")
            modules.append({"address": int(address), "model": model})
        data = {"name": args.name, "type": "modbus", "port": port, "modules": modules}
    else:
        raise ValueError("give --topology FILE or at least one --module ADDR:MODEL")
    if args.baudrate:
        data["baudrate"] = args.baudrate
    try:
        return ModbusBackConfig.model_validate(data)
    except ValidationError as exc:
        raise ValueError(
            "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        ) from None


async def _serve(config: ModbusBackConfig, args: argparse.Namespace) -> int:
    with stopped_by_signals() as stop:
        return await _serve_until(stop, config, args)


async def _serve_until(
    stop: asyncio.Event, config: ModbusBackConfig, args: argparse.Namespace
) -> int:
    pair = None
    port = args.port
    if args.pty:
        from fieldgate.serial_link import PtyPair

        pair = PtyPair()
        port = pair.b
    sim = ModbusSimulator(config, port, animate=args.animate)
    sim.output_listeners.append(lambda cid, value: print(f"output {cid} = {value}", flush=True))
    try:
        for item in args.set:
            execute(sim, "set " + item.replace("=", " ", 1))
        await sim.start()
    except (PluginStartError, ValueError, KeyError) as exc:
        print(f"fieldgate simulate modbus: {exc}", file=sys.stderr)
        if pair:
            pair.close()
        return 2
    addresses = ", ".join(
        f"{m.address}{' (' + m.model + ')' if m.model else ''}" for m in config.modules
    )
    print(
        f"simulating modules {addresses} on {port}"
        + (f"; point the gateway at {pair.a}" if pair else ""),
        flush=True,
    )
    try:
        await _command_loop(sim, stop, args.duration)
    finally:
        await sim.stop()
        if pair:
            pair.close()
    return 0


async def _command_loop(sim: ModbusSimulator, stop: asyncio.Event, duration: float | None) -> None:
    """Commands from stdin until ``quit`` or ``stop`` (SIGINT/SIGTERM) or ``duration``; a
    closed stdin leaves the modules served."""
    lines: asyncio.Queue[str] = asyncio.Queue()
    _read_stdin(asyncio.get_running_loop(), lines)

    async def commands() -> None:
        while True:
            reply = execute(sim, await lines.get())
            if reply == "quit":
                stop.set()
                return
            if reply:
                print(reply, flush=True)

    task = asyncio.create_task(commands())
    try:
        await wait_until(stop, duration)
    finally:
        task.cancel()


def _read_stdin(loop: asyncio.AbstractEventLoop, lines: asyncio.Queue[str]) -> None:
    """Feed stdin's lines to ``lines`` from a daemon thread: a read blocked on a terminal
    must not keep the process alive once it is stopped (asyncio.to_thread's worker would)."""

    def read() -> None:
        for line in sys.stdin or ():
            try:
                loop.call_soon_threadsafe(lines.put_nowait, line)
            except RuntimeError:  # the loop is closed: stopping
                return

    threading.Thread(target=read, name="simulate-modbus-stdin", daemon=True).start()


def execute(sim: ModbusSimulator, line: str) -> str:
    """Run one command line; returns what to print ("quit" to stop)."""
    words = line.split()
    if not words:
        return ""
    cmd, rest = words[0].lower(), words[1:]
    try:
        if cmd in ("quit", "exit"):
            return "quit"
        if cmd == "set" and len(rest) == 2:
            sim.set_input(rest[0], _number(rest[1]))
            return f"{rest[0]} = {sim.get(rest[0])}"
        if cmd == "get" and len(rest) == 1:
            return f"{rest[0]} = {sim.get(rest[0])}"
        if cmd == "show":
            return "\n".join(f"{cid} = {sim.get(cid)}" for cid in sim.channels)
        if cmd == "fault" and len(rest) >= 2:
            options = {k: v for k, _, v in (w.partition("=") for w in rest[2:] if "=" in w)}
            counts = [int(w) for w in rest[2:] if w.isdigit()]
            address = int(options["address"]) if "address" in options else None
            fault = Fault(
                rest[1],
                count=counts[0] if counts else None,
                code=int(options.get("code", 4)),
                delay=float(options.get("delay", 0.5)),
                address=address,
            )
            sim.inject(int(rest[0]), fault)
            where = "" if address is None else f" on requests touching address {address}"
            return f"module {rest[0]}: {fault.kind}{where}" + (
                f" for {fault.count} replies" if fault.count else " until cleared"
            )
        if cmd == "clear":
            sim.clear_faults(int(rest[0]) if rest else None)
            return "faults cleared"
    except (KeyError, ValueError) as exc:
        return f"error: {exc.args[0] if exc.args else exc}"
    return f"commands: set CH VALUE | get CH | show | fault ADDR {{{'|'.join(FAULT_KINDS)}}} [COUNT] [code=N] [delay=S] [address=N] | clear [ADDR] | quit"


def _number(text: str) -> bool | int | float:
    low = text.lower()
    if low in ("true", "on"):
        return True
    if low in ("false", "off"):
        return False
    try:
        return int(text, 0)
    except ValueError:
        return float(text)
