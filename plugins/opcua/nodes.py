"""The address space in asyncua's server: folders and variable nodes with their
attributes (description, access level) and properties (EURange, EngineeringUnits).

:mod:`.model` says what the address space holds; this module creates it on the server.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from asyncua import Server, ua

from fieldgate.topology import Topology

from . import model

VARIANT = {
    name: getattr(ua.VariantType, name)
    for name in (
        "Boolean",
        "Byte",
        "Int16",
        "UInt16",
        "Int32",
        "UInt32",
        "Int64",
        "UInt64",
        "Float",
        "Double",
        "String",
    )
}
UNIT_NS = "http://www.opcfoundation.org/UA/units/un/cefact"
# UNECE Rec. 20 common codes of the units module manuals use (UnitId = the code as base-256 ASCII)
UNECE = {
    "°C": "CEL",
    "degC": "CEL",
    "V": "VLT",
    "mV": "2Z",
    "mA": "4K",
    "A": "AMP",
    "%": "P1",
    "bar": "BAR",
    "Pa": "PAL",
    "kPa": "KPA",
    "Hz": "HTZ",
    "ohm": "OHM",
    "Ω": "OHM",
    "m/s": "MTS",
    "rpm": "RPM",
    "K": "KEL",
    "W": "WTT",
    "kW": "KWT",
    "kWh": "KWH",
    "Wh": "WHR",
    "kvar": "KVR",
    "VA": "D46",
    "kVA": "KVA",
    "m3/h": "MQH",
    "l/min": "L2",
    "s": "SEC",
    "min": "MIN",
    "h": "HUR",
}

NodeIds = Callable[[str], ua.NodeId]
"""Node id text -> the NodeId in the front's namespace."""


def unit_id(code: str) -> int:
    value = 0
    for ch in code:
        value = (value << 8) | ord(ch)
    return value


def zero(dtype: str) -> Any:
    return {"Boolean": False, "String": "", "Float": 0.0, "Double": 0.0}.get(dtype, 0)


def back_lines(topology: Topology) -> dict[str, str]:
    """Each back's line as its folder describes it: ``modbus on /dev/ttyS0 at 9600 baud``."""
    lines: dict[str, str] = {}
    for back_cfg in topology.backs:
        port = getattr(back_cfg, "port", None)
        baud = getattr(back_cfg, "baudrate", None)
        lines[back_cfg.name] = (
            f"{back_cfg.type}"
            + (f" on {port}" if port else "")
            + (f" at {baud} baud" if baud else "")
        )
    return lines


async def add_folders(
    server: Server, space: model.AddressSpace, nid: NodeIds, ns: int
) -> dict[str | None, Any]:
    """Every folder of ``space`` under Objects; node id text (None: Objects) -> node."""
    nodes: dict[str | None, Any] = {None: server.nodes.objects}
    for folder in space.folders:
        parent = nodes[folder.parent]
        node = await parent.add_folder(
            nid(folder.node_id), ua.QualifiedName(folder.browse_name, ns)
        )
        if folder.description:
            await node.write_attribute(
                ua.AttributeIds.Description,
                ua.DataValue(ua.Variant(ua.LocalizedText(folder.description))),
            )
        nodes[folder.node_id] = node
    return nodes


async def add_variable(
    parent: Any, var: model.Variable, nid: NodeIds, ns: int, initial: ua.DataValue
) -> Any:
    """A variable node under ``parent``: its description, access level (written only when
    ``var.writable``) and its EURange and EngineeringUnits properties where it has them."""
    vtype = VARIANT[var.data_type]
    node = await parent.add_variable(
        nid(var.node_id),
        ua.QualifiedName(var.browse_name, ns),
        initial.Value,
        varianttype=vtype,
        datatype=ua.NodeId(vtype.value),
    )
    await node.write_attribute(
        ua.AttributeIds.Description,
        ua.DataValue(ua.Variant(ua.LocalizedText(var.description))),
    )
    access = ua.AccessLevel.CurrentRead.mask | (
        ua.AccessLevel.CurrentWrite.mask if var.writable else 0
    )
    await node.write_attribute(
        ua.AttributeIds.AccessLevel, ua.DataValue(ua.Variant(access, ua.VariantType.Byte))
    )
    await node.write_attribute(
        ua.AttributeIds.UserAccessLevel,
        ua.DataValue(ua.Variant(access, ua.VariantType.Byte)),
    )
    if var.eu_range is not None:
        await node.add_property(
            nid(f"{var.node_id}/EURange"),
            "EURange",
            ua.Range(Low=var.eu_range[0], High=var.eu_range[1]),
        )
    if var.unit is not None:
        code = UNECE.get(var.unit)
        eu = ua.EUInformation(
            NamespaceUri=UNIT_NS,
            UnitId=unit_id(code) if code else -1,
            DisplayName=ua.LocalizedText(var.unit),
            Description=ua.LocalizedText(var.unit),
        )
        await node.add_property(nid(f"{var.node_id}/EngineeringUnits"), "EngineeringUnits", eu)
    return node
