"""DeviceNet EDS of exactly the slave a devicenet front serves.

``fieldgate eds TOPOLOGY [--front NAME] [-o FILE]`` builds the front's slave the
way the running gateway does (same assemblies, same identity settings) without opening a
bus, and reads what the EDS states from the slave's own CIP objects:

* ``[Device]``: Identity attributes 1-4 and 7 through the Identity object's getters, so
  the EDS names the device a scanner finds on the bus (VendCode, ProdType, ProdCode,
  MajRev/MinRev, ProdName);
* ``[IO_Info]``: one InputN / OutputN per assembly an I/O connection may carry, with its
  path ``20 04 24 <instance> 30 03`` (what Connection attributes 14/16 answer and take), so
  a configurator offers the selectable paths; the ``PollInfo``/``StrobeInfo``/``COSInfo``/
  ``CyclicInfo`` defaults are the topology's ``io_paths``; the combination masks follow the
  Allocate rules (COS and cyclic exclude each other);
* ``[ParamClass]``/``[Params]``: the attributes a configurator may set (heartbeat, BOI,
  and with DCON modules Host OK and each module's host watchdog), with their paths.

The I-7241D utility lists the I/O connection paths and "creates the EDS file to match the
setting result" (seed-003 §6): so does this command, from the topology.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, cast

from fieldgate.exitcodes import ExitCode
from fieldgate.plugin import CommandError, EdsRequest, GatewayContext, Registry, load_registry
from fieldgate.topology import FrontConfig, Topology, TopologyError, load_topology

from .application import HOST_OK, WATCHDOG_ENABLE, WATCHDOG_TIME, ApplicationObject
from .assembly import AnyAssembly, Assembly
from .engine import DeviceNetSlave
from .paths import STROBE_MAX, epath

IDENTITY, DEVICENET, ASSEMBLY, CONNECTION, APPLICATION = 0x01, 0x03, 0x04, 0x05, 0x64
# I/O type mask bits (PollInfo, Input/Output entries)
POLL_BIT, STROBE_BIT, COS_BIT, CYCLIC_BIT = 0x0001, 0x0002, 0x0004, 0x0008
# CIP device profiles (Identity attribute 2) by name; others are written by number
DEVICE_TYPES = {
    0x00: "Generic Device",
    0x07: "General Purpose Discrete I/O",
    0x0C: "Communications Adapter",
    0x2B: "Generic Device (keyable)",
}
VENDOR_NAMES = {803: "ICP DAS"}  # seed-003 §3.1 (the I-7241D's statement of compliance)
# EDS parameter data types and descriptor bits
BOOL, USINT = 0xC1, 0xC6
ENUMERATED, READ_ONLY = 0x0002, 0x0010
WATCHDOG_DEFAULT_TENTHS = 50  # a module whose watchdog time was never set: the seed's 5.0 s


class EdsError(CommandError):
    """The topology has no such devicenet front (one line, for the command's error)."""


@dataclass
class IoEntry:
    """One ``InputN``/``OutputN`` entry: the data one or more connection types carry."""

    size: int
    mask: int
    name: str
    path: bytes
    help: str


@dataclass
class Param:
    name: str
    path: bytes
    data_type: int
    minimum: int
    maximum: int
    default: int
    help: str
    units: str = ""
    enum: dict[int, str] = field(default_factory=dict)

    @property
    def descriptor(self) -> int:
        return ENUMERATED if self.enum else 0


@dataclass
class Description:
    """Everything the EDS states, read from one slave."""

    front: str
    gateway: str
    vendor_id: int
    device_type: int
    product_code: int
    major_revision: int
    minor_revision: int
    product_name: str
    inputs: list[IoEntry]
    outputs: list[IoEntry]
    defaults: dict[
        str, tuple[int, int]
    ]  # connection type -> (default InputN, default OutputN), 0 = none
    params: list[Param]
    groups: list[tuple[str, list[int]]]


# -- what the slave serves ------------------------------------------------------------------
def attribute(slave: DeviceNetSlave, class_id: int, instance: int, attr: int) -> bytes:
    """What a Get_Attribute_Single of this attribute answers."""
    return slave.objects[class_id].attribute(instance, attr).read()


def number(data: bytes) -> int:
    return int.from_bytes(data, "little")


def attribute_path(class_id: int, instance: int, attr: int) -> bytes:
    return bytes([0x20, class_id, 0x24, instance, 0x30, attr])


def io_entry(assembly: AnyAssembly, mask: int, name: str, size: int | None = None) -> IoEntry:
    """The data of one assembly (its first ``size`` bytes for a bit-strobe entry)."""
    whole = assembly.size
    note = "" if size is None or size == whole else f": the first {size} bytes"
    return IoEntry(
        whole if size is None else size, mask, name, epath(assembly), assembly.label + note
    )


def entry_name(assembly: AnyAssembly) -> str:
    if isinstance(assembly, Assembly):
        return f"{assembly.kind.value.upper()} data"
    return "All outputs" if assembly.is_output else "All inputs"


def ordered(first: AnyAssembly | None, assemblies: Sequence[AnyAssembly]) -> list[AnyAssembly]:
    """The poll's assembly first (Input1/Output1 as before paths could be chosen), then the
    others in instance order."""
    rest = [a for a in assemblies if a is not first]
    return ([first] if first is not None else []) + rest


def io_entries(
    slave: DeviceNetSlave,
) -> tuple[list[IoEntry], list[IoEntry], dict[str, tuple[int, int]]]:
    """One InputN / OutputN per assembly a connection may carry, with its path, so a
    configurator offers them; the ``<type>Info`` defaults are the topology's ``io_paths``.

    Every input assembly serves poll, change of state and cyclic, and the bit-strobe when it
    fits its 8 bytes; a strobe path to a larger one gets its own entry (its first 8 bytes)."""
    paths = slave.paths
    everything = list(slave.assemblies.instances.values())
    inputs: list[IoEntry] = []
    outputs: list[IoEntry] = []
    in_index: dict[int, int] = {}
    out_index: dict[int, int] = {}
    for assembly in ordered(paths["poll"].produce, [a for a in everything if not a.is_output]):
        mask = POLL_BIT | COS_BIT | CYCLIC_BIT | (STROBE_BIT if assembly.size <= STROBE_MAX else 0)
        inputs.append(io_entry(assembly, mask, entry_name(assembly)))
        in_index[assembly.instance] = len(inputs)
    for assembly in ordered(paths["poll"].consume, [a for a in everything if a.is_output]):
        outputs.append(io_entry(assembly, POLL_BIT | COS_BIT | CYCLIC_BIT, entry_name(assembly)))
        out_index[assembly.instance] = len(outputs)
    strobe = paths["strobe"].produce
    strobe_input = 0
    if strobe is not None:
        if strobe.size <= STROBE_MAX:
            strobe_input = in_index[strobe.instance]
        else:
            name = f"{entry_name(strobe)}, first {STROBE_MAX} bytes"
            inputs.append(io_entry(strobe, STROBE_BIT, name, STROBE_MAX))
            strobe_input = len(inputs)

    def defaults(kind: str) -> tuple[int, int]:
        path = paths[kind]
        return (
            in_index[path.produce.instance] if path.produce else 0,
            out_index[path.consume.instance] if path.consume else 0,
        )

    return (
        inputs,
        outputs,
        {
            "Poll": defaults("poll"),
            "Strobe": (strobe_input, 0),
            "COS": defaults("cos"),
            "Cyclic": defaults("cyclic"),
        },
    )


def parameters(slave: DeviceNetSlave) -> tuple[list[Param], list[tuple[str, list[int]]]]:
    """The attributes a configurator may set, with the values the slave starts with."""
    params = [
        Param(
            "Heartbeat interval",
            attribute_path(IDENTITY, 1, 10),
            USINT,
            0,
            255,
            number(attribute(slave, IDENTITY, 1, 10)),
            "Identity heartbeat message interval; 0 = no heartbeat",
            units="s",
        ),
        Param(
            "Bus-off interrupt",
            attribute_path(DEVICENET, 1, 3),
            BOOL,
            0,
            1,
            number(attribute(slave, DEVICENET, 1, 3)),
            "What the node does on CAN bus-off",
            enum={0: "Hold in bus-off", 1: "Reset and continue"},
        ),
    ]
    groups = [("DeviceNet", [1, 2])]
    application = cast(ApplicationObject, slave.objects[APPLICATION])  # class 0x64 is always one
    dcon = [
        (instance, module)
        for instance, module in enumerate(application.modules, start=1)
        if slave.host_watchdogs.has(module.back, module.address)
    ]
    if dcon:
        on_off = {0: "Off", 1: "On"}
        params.append(
            Param(
                "Host OK",
                attribute_path(APPLICATION, 0, HOST_OK),
                USINT,
                0,
                1,
                number(attribute(slave, APPLICATION, 0, HOST_OK)),
                "DCON backs may send the host-OK broadcast (~**); 0 lets watchdog-enabled modules time out",
                enum=on_off,
            )
        )
        watchdog = [len(params)]
        for instance, module in dcon:
            tenths = (
                number(attribute(slave, APPLICATION, instance, WATCHDOG_TIME))
                or WATCHDOG_DEFAULT_TENTHS
            )
            label = f"Module {module.address} ({module.back})"
            params.append(
                Param(
                    f"{label} watchdog",
                    attribute_path(APPLICATION, instance, WATCHDOG_ENABLE),
                    USINT,
                    0,
                    1,
                    number(attribute(slave, APPLICATION, instance, WATCHDOG_ENABLE)),
                    f"DCON host watchdog of module {module.address}",
                    enum=on_off,
                )
            )
            params.append(
                Param(
                    f"{label} watchdog time",
                    attribute_path(APPLICATION, instance, WATCHDOG_TIME),
                    USINT,
                    1,
                    255,
                    tenths,
                    f"DCON host watchdog time of module {module.address}",
                    units="x0.1 s",
                )
            )
            watchdog += [len(params) - 1, len(params)]
        groups.append(("DCON host watchdog", watchdog))
    return params, groups


def describe(front: Any, slave: DeviceNetSlave) -> Description:
    vendor, device_type, product_code = (
        number(attribute(slave, IDENTITY, 1, a)) for a in (1, 2, 3)
    )
    major, minor = attribute(slave, IDENTITY, 1, 4)
    name = attribute(slave, IDENTITY, 1, 7)
    params, groups = parameters(slave)
    inputs, outputs, defaults = io_entries(slave)
    return Description(
        front.name,
        front.context.topology.gateway.name or "fieldgate",
        vendor,
        device_type,
        product_code,
        major,
        minor,
        name[1 : 1 + name[0]].decode("latin-1"),
        inputs,
        outputs,
        defaults,
        params,
        groups,
    )


# -- the EDS text -----------------------------------------------------------------------------
def quoted(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def hex_path(path: bytes) -> str:
    return quoted(path.hex(" ").upper())


def entry(key: str, fields: Sequence[tuple[str, str]]) -> list[str]:
    """``key =`` then one field per line with its comment, the last one ending with ``;``."""
    lines = [f"        {key} ="]
    for n, (value, comment) in enumerate(fields):
        text = value + (";" if n == len(fields) - 1 else ",")
        lines.append(
            f"                {text:<23} $ {comment}" if comment else f"                {text}"
        )
    return lines


def single(key: str, value: str, comment: str = "") -> str:
    text = f"        {key} = {value};"
    return f"{text:<39} $ {comment}" if comment else text


def io_lines(key: str, io: IoEntry) -> list[str]:
    return entry(
        key,
        [
            (str(io.size), "size in bytes"),
            ("0", "significant bits (0 = all)"),
            (f"0x{io.mask:04X}", "I/O type mask"),
            (quoted(io.name), "name"),
            (str(len(io.path)), "path size"),
            (hex_path(io.path), "path"),
            (quoted(io.help), "help"),
        ],
    )


def param_lines(number_: int, p: Param) -> list[str]:
    lines = entry(
        f"Param{number_}",
        [
            ("0", "reserved, shall equal 0"),
            (f"{len(p.path)},{hex_path(p.path)}", "link path size, link path"),
            (f"0x{p.descriptor:04X}", "descriptor"),
            (f"0x{p.data_type:02X}", "data type"),
            ("1", "data size in bytes"),
            (quoted(p.name), "name"),
            (quoted(p.units), "units"),
            (quoted(p.help), "help string"),
            (f"{p.minimum},{p.maximum},{p.default}", "min, max, default"),
            (",,,", "mult, div, base, offset scaling"),
            (",,,", "mult, div, base, offset links"),
            ("", "decimal places"),
        ],
    )
    if p.enum:
        lines += entry(
            f"Enum{number_}", [(f"{value},{quoted(text)}", "") for value, text in p.enum.items()]
        )
    return lines


def eds_text(d: Description, now: datetime | None = None, vendor_name: str | None = None) -> str:
    now = now or datetime.now(UTC)
    vendor_name = vendor_name or VENDOR_NAMES.get(d.vendor_id, "fieldgate")
    type_name = DEVICE_TYPES.get(
        d.device_type,
        "Vendor Specific" if 100 <= d.device_type <= 199 else f"Device type {d.device_type}",
    )
    lines = [
        f"$ DeviceNet EDS of fieldgate front {d.front!r} (gateway {d.gateway!r}), written by `fieldgate eds`.",
        "$ It describes this topology's I/O sizes: regenerate it when the modules change, and change",
        "$ product_code or major_revision with them so a scanner never mixes two layouts.",
        "",
        "[File]",
        single("DescText", quoted(f"fieldgate DeviceNet front {d.front} ({d.gateway})")),
        single("CreateDate", now.strftime("%m-%d-%Y"), "mm-dd-yyyy"),
        single("CreateTime", now.strftime("%H:%M:%S"), "hh:mm:ss"),
        single("ModDate", now.strftime("%m-%d-%Y")),
        single("ModTime", now.strftime("%H:%M:%S")),
        single("Revision", "1.0", "EDS file revision"),
        "",
        "[Device]",
        single("VendCode", str(d.vendor_id), "Identity attribute 1"),
        single("VendName", quoted(vendor_name)),
        single("ProdType", str(d.device_type), "Identity attribute 2"),
        single("ProdTypeStr", quoted(type_name)),
        single("ProdCode", str(d.product_code), "Identity attribute 3"),
        single("MajRev", str(d.major_revision), "Identity attribute 4"),
        single("MinRev", str(d.minor_revision)),
        single("ProdName", quoted(d.product_name), "Identity attribute 7"),
        single("Catalog", quoted(d.front)),
        "",
        "[IO_Info]",
        "        $ I/O type mask: 0x0001 poll, 0x0002 bit-strobe, 0x0004 change of state, 0x0008 cyclic",
        single("Default", f"0x{POLL_BIT:04X}", "poll"),
    ]
    combine = {
        "Poll": POLL_BIT | STROBE_BIT | COS_BIT | CYCLIC_BIT,
        "Strobe": POLL_BIT | STROBE_BIT | COS_BIT | CYCLIC_BIT,
        "COS": POLL_BIT | STROBE_BIT | COS_BIT,
        "Cyclic": POLL_BIT | STROBE_BIT | CYCLIC_BIT,
    }
    for kind, mask in combine.items():
        default_in, default_out = d.defaults[kind]
        lines += entry(
            f"{kind}Info",
            [
                (f"0x{mask:04X}", "may be combined with"),
                (str(default_in), "default input (0 = none)"),
                (str(default_out), "default output (0 = none)"),
            ],
        )
    for n, io in enumerate(d.inputs, start=1):
        lines += io_lines(f"Input{n}", io)
    for n, io in enumerate(d.outputs, start=1):
        lines += io_lines(f"Output{n}", io)
    lines += [
        "",
        "[ParamClass]",
        single("MaxInst", "0", "no Parameter object: configurators use the link paths"),
        single("Descriptor", "0x0000"),
        single("CfgAssembly", "0", "no configuration assembly"),
        "",
        "[Params]",
    ]
    for n, p in enumerate(d.params, start=1):
        lines += param_lines(n, p)
    lines += ["", "[Groups]"]
    for n, (name, numbers) in enumerate(d.groups, start=1):
        lines += entry(
            f"Group{n}",
            [
                (quoted(name), "name"),
                (str(len(numbers)), "number of parameters"),
                (",".join(map(str, numbers)), "parameters"),
            ],
        )
    return "\n".join(lines) + "\n"


# -- topology -> EDS ------------------------------------------------------------------------
def front_slave(
    topology_source: str | Path | dict[str, Any],
    front_name: str | None = None,
    registry: Registry | None = None,
    overrides: dict[str, Any] | None = None,
) -> tuple[Any, DeviceNetSlave]:
    """The devicenet front and a slave built as the gateway builds it (no bus, no clock)."""
    registry = registry or load_registry()
    topology = load_topology(topology_source, registry, overrides)
    if front_name is not None:
        named = [f for f in topology.fronts if f.name == front_name]
        if not named:
            known = ", ".join(f"{f.name} ({f.type})" for f in topology.fronts) or "none"
            raise EdsError(f"no front named {front_name!r} (fronts: {known})")
        if named[0].type != "devicenet":
            raise EdsError(
                f"front {front_name!r} is a {named[0].type} front, not devicenet"
                + (" (its EDS: fieldgate eds)" if named[0].type == "canopen" else "")
            )
        cfg = named[0]
    else:
        fronts = [f for f in topology.fronts if f.type == "devicenet"]
        if not fronts:
            raise EdsError("no devicenet front in the topology")
        cfg = fronts[0]
    return build_front(topology, cfg, registry)


def build_front(
    topology: Topology, cfg: FrontConfig, registry: Registry
) -> tuple[Any, DeviceNetSlave]:
    """A devicenet front of ``topology`` and its slave, built as the running gateway builds them."""
    context = GatewayContext.build(topology)
    ctype = registry.lookup("front", cfg.type)
    if ctype is None:
        raise EdsError("the devicenet plugin is not installed")
    front: Any = ctype.factory(cfg, context)
    return front, front.build()


def write_eds(
    topology_source: str | Path | dict[str, Any],
    front_name: str | None = None,
    dest: str | Path | None = None,
    registry: Registry | None = None,
    now: datetime | None = None,
    vendor_name: str | None = None,
    overrides: dict[str, Any] | None = None,
) -> str:
    """The EDS text, also written to ``dest`` when given (OSError when it cannot be: the
    folder must exist, a directory is refused)."""
    front, slave = front_slave(topology_source, front_name, registry, overrides)
    text = eds_text(describe(front, slave), now, vendor_name)
    if dest is not None:
        from fieldgate.persist import write_atomic

        write_atomic(Path(dest), text.encode("latin-1", "replace"), make_parents=False)
    return text


# -- fieldgate eds ----------------------------------------------------------------------------
def eds_for(request: EdsRequest) -> str:
    """The EDS of the front ``fieldgate eds`` chose (registered with ``registry.add_eds``)."""
    front, slave = build_front(request.topology, request.front, request.registry)
    return eds_text(describe(front, slave), None, request.options.vendor_name)


def configure_eds(group: argparse._ArgumentGroup) -> None:
    group.add_argument(
        "--vendor-name", help="VendName (default: ICP DAS for vendor 803, else fieldgate)"
    )


def register_eds(registry: Registry) -> None:
    registry.add_eds("devicenet", eds_for, configure_eds, encoding="latin-1")
    registry.add_command(
        ("devicenet", "eds"),
        "deprecated: fieldgate eds TOPOLOGY [--front NAME] (the same EDS)",
        configure,
        run,
    )


# -- fieldgate devicenet eds: the old spelling, kept for one release --------------------------
def configure(parser: argparse.ArgumentParser) -> None:
    from fieldgate.cliargs import add_overrides_argument

    parser.add_argument("topology", help="topology YAML file")
    parser.add_argument("--front", help="devicenet front name (default: the first devicenet front)")
    parser.add_argument("-o", "--output", help="EDS file to write (default: standard output)")
    configure_eds(parser.add_argument_group("devicenet fronts"))
    add_overrides_argument(parser, "fronts.dnet.identity.product_code=7")


def to_stderr(*lines: str, code: int = ExitCode.FAILED) -> int:
    """Print ``lines`` on standard error; the command's exit code (1: an invalid topology, no
    such front, an output that cannot be written; as ``fieldgate eds`` and ``validate``)."""
    print("\n".join(lines), file=sys.stderr)
    return code


def run(args: argparse.Namespace) -> int:
    from fieldgate.cliargs import deprecated, overrides_of

    deprecated("fieldgate devicenet eds", "fieldgate eds TOPOLOGY [--front NAME]")
    try:
        text = write_eds(
            args.topology,
            args.front,
            args.output,
            vendor_name=args.vendor_name,
            overrides=overrides_of(args, args.topology),
        )
    except TopologyError as exc:
        return to_stderr(*map(str, exc.issues))
    except EdsError as exc:
        return to_stderr(f"{args.topology}: {exc}")
    except OSError as exc:
        return to_stderr(f"{args.output}: cannot write the EDS: {exc.strerror or exc}")
    if args.output is not None:
        return to_stderr(
            f"{args.output}: EDS written for {args.front or 'the first devicenet front'}",
            code=ExitCode.OK,
        )
    sys.stdout.write(text)
    return ExitCode.OK
