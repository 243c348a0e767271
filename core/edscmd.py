"""``fieldgate eds TOPOLOGY [--front NAME] [-o FILE]``: the EDS of a front, for every front
type whose plugin registers an EDS writer (``registry.add_eds``: CANopen's CiA 306 EDS,
DeviceNet's EDS).

Without ``--front`` it describes the first front that has one. An invalid topology, a front
without an EDS, or an output that cannot be written is one line and exit 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .cliargs import invalid_topology
from .exitcodes import ExitCode
from .plugin import CommandError, EdsRequest, Registry
from .topology import FrontConfig, Topology, TopologyError, load_topology


def configure(parser: argparse.ArgumentParser, registry: Registry) -> None:
    from .cliargs import add_overrides_argument

    types = ", ".join(sorted(registry.eds_writers)) or "none installed"
    parser.add_argument("topology", help="topology YAML file")
    add_overrides_argument(parser, "fronts.can.node_id=5")
    parser.add_argument(
        "--front", help=f"the front to describe (default: the first front with an EDS: {types})"
    )
    parser.add_argument("-o", "--output", help="EDS file to write (default: standard output)")
    owners: dict[str, str] = {}
    for front_type, writer in sorted(registry.eds_writers.items()):
        if writer.configure is None:
            continue
        group = parser.add_argument_group(f"{front_type} fronts only")
        try:
            writer.configure(group)
        except Exception as exc:  # a broken plugin: its fronts' EDS refuses, the others work
            from .plugin import one_line

            registry.plugins[writer.plugin].error = f"eds options: {one_line(exc)}"
            continue
        for action in group._group_actions:
            owners[action.dest] = front_type
    parser.set_defaults(eds_option_owners=owners)


def choose_front(topology: Topology, registry: Registry, name: str | None) -> FrontConfig:
    """The front ``--front`` names, or the first one that has an EDS (CommandError: one line)."""
    fronts = ", ".join(f"{f.name} ({f.type})" for f in topology.fronts) or "none"
    writers = ", ".join(sorted(registry.eds_writers)) or "none installed"
    if name is not None:
        named = [f for f in topology.fronts if f.name == name]
        if not named:
            raise CommandError(f"no front named {name!r} (fronts: {fronts})")
        if named[0].type not in registry.eds_writers:
            raise CommandError(
                f"front {name!r} is a {named[0].type} front, which has no EDS (EDS for: {writers})"
            )
        return named[0]
    for front in topology.fronts:
        if front.type in registry.eds_writers:
            return front
    raise CommandError(
        f"no front with an EDS in the topology (fronts: {fronts}; EDS for: {writers})"
    )


def eds_text(args: argparse.Namespace, registry: Registry) -> tuple[FrontConfig, str]:
    """The front and its EDS, as the command line asks (TopologyError, CommandError)."""
    from .cliargs import overrides_of

    topology = load_topology(args.topology, registry, overrides_of(args, args.topology))
    front = choose_front(topology, registry, args.front)
    for dest, owner in getattr(args, "eds_option_owners", {}).items():
        if owner != front.type and getattr(args, dest, None) not in (None, False):
            option = "--" + dest.replace("_", "-")
            raise CommandError(f"{option} applies to {owner} fronts; {front.name} is {front.type}")
    writer = registry.eds_writers[front.type]
    file_name = Path(args.output).name if args.output is not None else None
    return front, writer.write(EdsRequest(topology, front, registry, args, file_name))


def run(args: argparse.Namespace, registry: Registry) -> int:
    try:
        front, text = eds_text(args, registry)
    except TopologyError as exc:
        return invalid_topology(exc)
    except CommandError as exc:
        print(f"{args.topology}: {exc}", file=sys.stderr)
        return ExitCode.FAILED
    if args.output is None:
        sys.stdout.write(text)
        return ExitCode.OK
    from .persist import write_atomic

    encoding = registry.eds_writers[front.type].encoding
    try:
        write_atomic(Path(args.output), text.encode(encoding, "replace"), make_parents=False)
    except OSError as exc:
        print(f"{args.output}: cannot write the EDS: {exc.strerror or exc}", file=sys.stderr)
        return ExitCode.FAILED
    print(f"{args.output}: EDS written for front {front.name} ({front.type})", file=sys.stderr)
    return ExitCode.OK
