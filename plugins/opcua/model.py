"""The address space the front serves, as plain data (no OPC UA library here).

Stable across restarts: every node id is a string built from names in the topology
(``ns=<namespace_uri>;s=rs485/m3/ai0``), so a SCADA tag list survives a restart, a reordering
of the YAML, and another front being added. Layout under ``Objects``::

    <gateway>                         folder   s=<gateway>
      <back>                          folder   s=<back>
        m<address>                    folder   s=<back>/m<address>   (description: model, line)
          di0, do0, ai0 ...           variable s=<channel id>        (DataType from the channel;
                                                                      EngineeringUnits, EURange
                                                                      where the back scaled it)
          ai0_eng                     variable s=<channel id>/eng    (Double, display-scaled only)
          Health                      folder   s=<back>/m<address>/health
            Online, ErrorCounter, ConsecutiveFailures, LastError
      Fronts                          folder   s=fronts
        <front>                       folder   s=fronts/<front>      (every other front)
          MasterPresent, State
"""

from __future__ import annotations

import fnmatch
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from fieldgate.image import Channel, DataType, Kind, Scaling

# OPC UA built-in DataType ids (ns=0)
UA_TYPE: dict[DataType, str] = {
    DataType.BOOL: "Boolean",
    DataType.UINT8: "Byte",
    DataType.INT16: "Int16",
    DataType.UINT16: "UInt16",
    DataType.INT32: "Int32",
    DataType.UINT32: "UInt32",
    DataType.FLOAT32: "Float",
    DataType.INT64: "Int64",
    DataType.UINT64: "UInt64",
    DataType.FLOAT64: "Double",
    DataType.STRING: "String",
}

KIND_TEXT = {
    Kind.DI: "digital input",
    Kind.DO: "digital output",
    Kind.AI: "analog input",
    Kind.AO: "analog output",
    Kind.SI: "special input byte",
    Kind.SO: "special output byte",
}

HEALTH_VARIABLES = (
    # (browse name, node id suffix, DataType, what it says)
    (
        "Online",
        "online",
        "Boolean",
        "false while the module is offline (consecutive failures above the threshold)",
    ),
    (
        "ErrorCounter",
        "error_counter",
        "UInt16",
        "failed transactions, wrapping at 65535 (CANopen 0x2000)",
    ),
    (
        "ConsecutiveFailures",
        "consecutive_failures",
        "UInt32",
        "failed transactions since the last good one",
    ),
    ("LastError", "last_error", "String", "the last failure, in one line"),
)
FRONT_VARIABLES = (
    ("MasterPresent", "master_present", "Boolean", "false while the front has lost its master"),
    ("State", "state", "String", "the front's protocol state (NMT state, connection state)"),
)


@dataclass(frozen=True)
class Folder:
    node_id: str
    browse_name: str
    parent: str | None  # None: under Objects
    description: str = ""


@dataclass(frozen=True)
class Variable:
    node_id: str
    browse_name: str
    parent: str
    data_type: str  # an OPC UA built-in type name
    description: str
    channel_id: str | None = None  # a process-image channel (None: health or front state)
    writable: bool = False
    engineering: bool = False  # the scaled twin of a channel (Double)
    eu_range: tuple[float, float] | None = None  # EURange (percent deadband uses it)
    unit: str | None = None  # EngineeringUnits display name


@dataclass
class AddressSpace:
    folders: list[Folder] = field(default_factory=list)
    variables: list[Variable] = field(default_factory=list)

    def by_channel(self) -> dict[str, list[Variable]]:
        out: dict[str, list[Variable]] = {}
        for var in self.variables:
            if var.channel_id is not None:
                out.setdefault(var.channel_id, []).append(var)
        return out


def module_folder(back: str, address: int) -> str:
    return f"{back}/m{address}"


def build(
    gateway: str,
    channels: Iterable[Channel],
    writable: Iterable[str] = (),
    modules: Mapping[tuple[str, int], str] | None = None,
    lines: Mapping[str, str] | None = None,
    locations: Mapping[str, list[str]] | None = None,
    other_fronts: Iterable[str] = (),
) -> AddressSpace:
    """The address space of ``channels`` (in front order).

    ``modules`` maps (back, address) to the module model, ``lines`` a back to a one-line
    description of its line ("modbus on /dev/ttyUSB0 at 9600 baud"), ``locations`` a channel
    id to where its back reads it ("input register 0"): all three only make descriptions.
    """
    patterns = list(writable)
    modules = modules or {}
    lines = lines or {}
    locations = locations or {}
    space = AddressSpace()
    space.folders.append(Folder(gateway, gateway, None, f"fieldgate gateway {gateway}"))
    backs_seen: set[str] = set()
    modules_seen: set[tuple[str, int]] = set()
    for channel in channels:
        src = channel.source
        if src.back not in backs_seen:
            backs_seen.add(src.back)
            space.folders.append(
                Folder(
                    src.back,
                    src.back,
                    gateway,
                    f"back {src.back}: {lines.get(src.back, '')}".rstrip(": "),
                )
            )
        key = (src.back, src.module)
        if key not in modules_seen:
            modules_seen.add(key)
            _add_module(space, src.back, src.module, modules.get(key, ""))
        is_writable = channel.kind.is_output and any(
            fnmatch.fnmatchcase(channel.id, p) for p in patterns
        )
        text = _describe(channel, modules.get(key, ""), lines, locations)
        space.variables += _channel_variables(channel, text, is_writable)
    _add_fronts(space, gateway, list(other_fronts))
    return space


def _add_module(space: AddressSpace, back: str, module: int, model: str) -> None:
    """A module's folder with its health folder and variables."""
    folder = module_folder(back, module)
    space.folders.append(
        Folder(
            folder,
            f"m{module}",
            back,
            f"module {module}{f' ({model})' if model else ''} on back {back}",
        )
    )
    health = f"{folder}/health"
    space.folders.append(Folder(health, "Health", folder, f"health of module {module}"))
    for name, suffix, dtype, text in HEALTH_VARIABLES:
        space.variables.append(Variable(f"{health}/{suffix}", name, health, dtype, text))


def _describe(
    channel: Channel, model: str, lines: Mapping[str, str], locations: Mapping[str, list[str]]
) -> str:
    """A channel variable's description: its label, what and where it is, how it is read."""
    src = channel.source
    where = "; ".join(locations.get(channel.id, []))
    text = (
        f"{KIND_TEXT[channel.kind]} {src.index} of module {src.module}"
        f"{f' ({model})' if model else ''} on back {src.back}"
        f"{f', {lines[src.back]}' if src.back in lines else ''}"
        f"{f'; read as {where}' if where else ''}"
    )
    if channel.spec.label:
        text = f"{channel.spec.label}: {text}"
    return text


def _channel_variables(channel: Channel, text: str, is_writable: bool) -> list[Variable]:
    """A channel's variable, and its scaled twin ``<id>/eng`` where the channel has a
    scaling (a value in engineering units already carries them itself: no twin)."""
    local = channel.id.rsplit("/", 1)[-1]
    folder = module_folder(channel.source.back, channel.source.module)
    scaling: Scaling | None = channel.spec.scaling
    eng = channel.spec.engineering
    dtype = UA_TYPE[channel.spec.data_type]
    if eng is not None:
        text += f"; {eng.describe()}" if eng.describe() else ""
        return [
            Variable(
                channel.id,
                local,
                folder,
                dtype,
                text,
                channel.id,
                is_writable,
                eu_range=eng.eu_range,
                unit=eng.unit or None,
            )
        ]
    raw_range = (scaling.raw_min, scaling.raw_max) if scaling is not None else None
    out = [
        Variable(
            channel.id, local, folder, dtype, text, channel.id, is_writable, eu_range=raw_range
        )
    ]
    if scaling is not None:
        out.append(
            Variable(
                f"{channel.id}/eng",
                f"{local}_eng",
                folder,
                "Double",
                f"{local} in engineering units ({scaling.unit or 'no unit'}), scaled from the raw value; read-only",
                channel.id,
                engineering=True,
                eu_range=(scaling.eng_min, scaling.eng_max),
                unit=scaling.unit or None,
            )
        )
    return out


def _add_fronts(space: AddressSpace, gateway: str, fronts: list[str]) -> None:
    """The other fronts' folder: each one's master presence and protocol state."""
    if not fronts:
        return
    space.folders.append(Folder("fronts", "Fronts", gateway, "the gateway's other fronts"))
    for name in fronts:
        node = f"fronts/{name}"
        space.folders.append(Folder(node, name, "fronts", f"front {name}"))
        for browse, suffix, dtype, text in FRONT_VARIABLES:
            space.variables.append(Variable(f"{node}/{suffix}", browse, node, dtype, text))
