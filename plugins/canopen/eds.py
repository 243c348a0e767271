"""CiA 306 EDS of exactly the object dictionary a canopen front serves.

``fieldgate eds TOPOLOGY [--front NAME] [-o FILE]`` builds the front's node the way the
running gateway does (same services, same node extensions, so the same objects,
defaults and access types) without opening a bus, and exports its dictionary with
canopen's EDS writer, plus what that writer cannot know:

* ``[DeviceInfo]``: vendor/product/revision from the identity settings, the standard
  bit rates, ``SimpleBootUpSlave=1``, ``Granularity=8`` (1 with ``bit_mapping``),
  ``DynamicChannelsSupported=0`` (no CiA 302-4 dynamic channels), ``NrOfRXPDO``/``NrOfTXPDO``,
  ``LSS_Supported=1``;
* ``[DummyUsage]``: the dummy entries RPDOs accept (0x0002-0x0007; 0x0001 with bit mapping);
* COB-IDs that depend on the node-ID are written ``$NODEID+0x180`` so one EDS serves
  every node-ID.

The I-7232D utility "creates the EDS file to match the setting result" (seed-000 §5):
so does this command, from the topology.
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import canopen

from fieldgate.plugin import CommandError, EdsRequest, GatewayContext, Registry, load_registry
from fieldgate.topology import FrontConfig, Topology, load_topology

from .cia301.pdo.engine import dummy_types
from .cia401.layouts import LayoutError

STANDARD_BITRATES = (10e3, 20e3, 50e3, 125e3, 250e3, 500e3, 800e3, 1000e3)


class AscendingRates(set[float]):
    """The bit rates a device supports, listed in ascending order by canopen's EDS writer: it
    iterates ``allowed_baudrates.union(...)``, a set, whose order for 20 kbit/s and 800 kbit/s
    (equal hashes modulo the table size) depended on how the interpreter had built the set: two
    installs wrote the same device's EDS in two orders."""

    def union(self, *others: Iterable[Any]) -> Any:
        return sorted(set(self).union(*others))


class EdsError(CommandError):
    """The topology has no such canopen front (or none at all)."""


def front_node(
    topology_source: str | Path | dict[str, Any],
    front_name: str | None = None,
    registry: Registry | None = None,
    overrides: dict[str, Any] | None = None,
) -> tuple[Any, Any]:
    """The front object and its booted-free node, as the gateway would build them."""
    registry = registry or load_registry()
    topology = load_topology(topology_source, registry, overrides)
    fronts = [
        f
        for f in topology.fronts
        if f.type == "canopen" and (front_name is None or f.name == front_name)
    ]
    if not fronts:
        others = sorted(
            {f.type for f in topology.fronts if front_name is None or f.name == front_name}
            - {"canopen"}
        )
        hint = (
            f" (it has a {' and a '.join(others)} front: fieldgate eds --front NAME)"
            if others
            else ""
        )
        raise EdsError(
            f"no canopen front{f' named {front_name!r}' if front_name else ''} in the topology{hint}"
        )
    return build_front(topology, fronts[0], registry)


def build_front(topology: Topology, cfg: FrontConfig, registry: Registry) -> tuple[Any, Any]:
    """A canopen front of ``topology`` and its node, built as the running gateway builds them."""
    context = GatewayContext.build(topology)
    ctype = registry.lookup("front", cfg.type)
    if ctype is None:
        raise EdsError("the canopen plugin is not installed")
    front: Any = ctype.factory(cfg, context)
    return front, front.build()


def eds_text(front: Any, node: Any, file_name: str | None = None) -> str:
    """The EDS; ``[FileInfo] FileName`` is ``file_name`` (the output's name), else ``<front>.eds``."""
    od = node.od.model
    ident = front.config.identity
    info = od.device_information
    info.vendor_name = "fieldgate"
    info.vendor_number = ident.vendor_id
    info.product_name = ident.device_name
    info.product_number = ident.product_code
    info.revision_number = ident.revision
    info.order_code = front.name
    info.simple_boot_up_master = False
    info.simple_boot_up_slave = True
    io_device = getattr(front, "io", None)
    granularity = io_device.settings.granularity if io_device is not None else 8
    info.granularity = granularity
    info.dynamic_channels_supported = False
    info.group_messaging = False
    if io_device is not None and io_device.engine is not None:
        info.nr_of_RXPDO = len(io_device.engine.rpdos)
        info.nr_of_TXPDO = len(io_device.engine.tpdos)
    info.LSS_supported = True
    info.allowed_baudrates = AscendingRates(STANDARD_BITRATES)
    if (
        0x1003 in od.indices
    ):  # sub 0 counts the errors recorded: none at start (not the highest sub)
        od.indices[0x1003].subindices[0].default = 0
    for var in node.od.variables():
        if var.relative and isinstance(var.default, int):
            var.default_raw = f"$NODEID+0x{var.default:X}"
    buffer = io.StringIO()
    canopen.export_od(od, buffer, doc_type="eds")
    text = buffer.getvalue()
    dummies = dummy_types(granularity) if io_device is not None else []
    description = (
        f"fieldgate CANopen front {front.name} ({getattr(front.config, 'style', 'icpdas')} style)"
    )
    text = with_file_info(text, file_name or f"{front.name}.eds", description)
    return _set_dummy_usage(text, dummies)


def _set_dummy_usage(text: str, dummies: list[int]) -> str:
    """canopen writes DummyN=1 only for objects named DummyN; say which ones RPDOs take."""
    return re.sub(
        r"^Dummy(000[1-7])=\d+$",
        lambda m: f"Dummy{m.group(1)}={int(int(m.group(1), 16) in dummies)}",
        text,
        flags=re.MULTILINE,
    )


def with_file_info(text: str, file_name: str, description: str) -> str:
    """An EDS canopen wrote with fieldgate's ``[FileInfo]``, made now."""
    now = datetime.now(UTC)
    file_info = {
        "FileName": file_name,
        "FileVersion": 1,
        "FileRevision": 0,
        "EDSVersion": "4.0",
        "Description": description,
        "CreationTime": now.strftime("%I:%M%p"),
        "CreationDate": now.strftime("%m-%d-%Y"),
        "CreatedBy": "fieldgate eds",
        "ModificationTime": now.strftime("%I:%M%p"),
        "ModificationDate": now.strftime("%m-%d-%Y"),
        "ModifiedBy": "fieldgate eds",
    }
    return _replace_file_info(text, file_info)


def _replace_file_info(text: str, file_info: dict[str, object]) -> str:
    """canopen writes its own [FileInfo] (with a month where minutes belong); put ours."""
    lines = text.splitlines()
    out: list[str] = []
    skipping = False
    for line in lines:
        if line.strip() == "[FileInfo]":
            out.append(line)
            out += [f"{k}={v}" for k, v in file_info.items()]
            skipping = True
            continue
        if skipping and line.startswith("["):
            out.append("")
            skipping = False
        if not skipping:
            out.append(line)
    return "\n".join(out) + "\n"


def write_eds(
    topology_source: str | Path | dict[str, Any],
    front_name: str | None = None,
    dest: str | Path | None = None,
    registry: Registry | None = None,
    overrides: dict[str, Any] | None = None,
) -> str:
    """The EDS text, also written to ``dest`` when given (OSError when it cannot be: the
    folder must exist, a directory is refused); ``overrides`` as ``--set``."""
    front, node = front_node(topology_source, front_name, registry, overrides)
    text = eds_text(front, node, Path(dest).name if dest is not None else None)
    if dest is not None:
        from fieldgate.persist import write_atomic

        write_atomic(Path(dest), text.encode(), make_parents=False)
    return text


# -- fieldgate eds ------------------------------------------------------------------------
def eds_for(request: EdsRequest) -> str:
    """The EDS of the front ``fieldgate eds`` chose (registered with ``registry.add_eds``)."""
    try:
        front, node = build_front(request.topology, request.front, request.registry)
    except LayoutError as exc:
        raise EdsError(str(exc)) from None
    return eds_text(front, node, request.file_name)
