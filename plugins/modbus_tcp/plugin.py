"""The ``modbus-tcp`` plugin's registration and its `fieldgate map` command.

The front (:mod:`.front`, with its server) is imported when a topology has a modbus-tcp
front, not by every gateway, `validate` or `map` that loads the plugins.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from fieldgate.plugin import Front, GatewayContext, Registry, hookimpl
from fieldgate.topology import TopologyError

from .config import ModbusTcpFrontConfig
from .map import ModbusMap


def make_front(config: ModbusTcpFrontConfig, context: GatewayContext) -> Front:
    from .front import ModbusTcpFront

    return ModbusTcpFront(config, context)


# -- `fieldgate map TOPOLOGY [--front NAME]` ----------------------------------------------------
def front_map(
    topology_source: Any,
    front_name: str | None = None,
    registry: Registry | None = None,
    overrides: dict[str, Any] | None = None,
) -> tuple[str, ModbusMap]:
    """(front name, map) of a modbus-tcp front of a topology; ValueError when there is none."""
    from fieldgate.plugin import GatewayContext, load_registry
    from fieldgate.topology import load_topology

    topology = load_topology(topology_source, registry or load_registry(), overrides)
    fronts = [f for f in topology.fronts if isinstance(f, ModbusTcpFrontConfig)]
    if front_name is not None:
        fronts = [f for f in fronts if f.name == front_name]
        if not fronts:
            raise ValueError(f"no modbus-tcp front named {front_name!r}")
    if not fronts:
        raise ValueError("the topology has no modbus-tcp front")
    front = fronts[0]
    ctx = GatewayContext.build(topology)
    return front.name, ModbusMap.from_channels(
        ctx.front_channels(front),
        front.writable,
        front.byte_order,
        scaled_values=front.scaled_values,
    )


def configure(parser: argparse.ArgumentParser) -> None:
    from fieldgate.cli import add_overrides_argument

    parser.add_argument("topology", help="topology YAML file")
    add_overrides_argument(parser, "fronts.scada.unit_id=2")
    parser.add_argument(
        "--front", help="modbus-tcp front name (default: the first modbus-tcp front)"
    )


def run(args: argparse.Namespace) -> int:
    from fieldgate.cli import overrides_of

    try:
        name, modbus_map = front_map(
            args.topology, args.front, overrides=overrides_of(args, args.topology)
        )
    except TopologyError as exc:
        for issue in exc.issues:
            print(issue, file=sys.stderr)
        return 1
    except ValueError as exc:
        print(f"{args.topology}: {exc}", file=sys.stderr)
        return 1
    print(f"# Modbus map of front {name} ({args.topology})")
    sys.stdout.write(modbus_map.text())
    return 0


@hookimpl
def fieldgate_register(registry: Any) -> None:
    registry.add_front(
        "modbus-tcp",
        ModbusTcpFrontConfig,
        make_front,
        "Modbus TCP server on the process image",
        north=True,
    )
    registry.add_command(("map",), "print the Modbus map of a modbus-tcp front", configure, run)
