"""canopen's LocalNode as a third-party device under test, with an EDS built in code."""

from __future__ import annotations

from pathlib import Path

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes

NODE_ID = 7


def _var(
    name: str,
    index: int,
    sub: int,
    dtype: int,
    access: str,
    default,
    mappable: bool = False,
    low=None,
    high=None,
) -> ODVariable:
    var = ODVariable(name, index, sub)
    var.data_type, var.access_type, var.default, var.value, var.pdo_mappable = (
        dtype,
        access,
        default,
        default,
        mappable,
    )
    var.min, var.max = low, high
    return var


def _record(od, cls, name: str, index: int, subs: list[tuple]) -> None:
    obj = cls(name, index)
    for sub, sname, dtype, access, default, *extra in subs:
        obj.add_member(_var(sname, index, sub, dtype, access, default, *extra))
    od.add_object(obj)


def build_od(node_id: int = NODE_ID) -> canopen.ObjectDictionary:
    U8, U16, U32, VS = (
        datatypes.UNSIGNED8,
        datatypes.UNSIGNED16,
        datatypes.UNSIGNED32,
        datatypes.VISIBLE_STRING,
    )
    od = canopen.ObjectDictionary()
    od.node_id = node_id
    od.device_information.product_name = "canopen LocalNode"
    od.add_object(_var("Device type", 0x1000, 0, U32, "ro", 0x00030191))  # CiA 401 with DI and DO
    od.add_object(_var("Error register", 0x1001, 0, U8, "ro", 0))
    od.add_object(_var("COB-ID SYNC", 0x1005, 0, U32, "rw", 0x80))
    od.add_object(_var("Device name", 0x1008, 0, VS, "const", "LocalNode under test"))
    od.add_object(_var("Guard time", 0x100C, 0, U16, "rw", 0))
    od.add_object(_var("Life time factor", 0x100D, 0, U8, "rw", 0))
    od.add_object(_var("COB-ID EMCY", 0x1014, 0, U32, "rw", 0x80 + node_id))
    od.add_object(_var("Producer heartbeat time", 0x1017, 0, U16, "rw", 0))
    _record(
        od,
        ODRecord,
        "Identity",
        0x1018,
        [
            (0, "n", U8, "const", 4),
            (1, "Vendor", U32, "ro", 0x1234),
            (2, "Product", U32, "ro", 1),
            (3, "Revision", U32, "ro", 1),
            (4, "Serial", U32, "ro", 99),
        ],
    )
    _record(
        od,
        ODRecord,
        "RPDO1 comm",
        0x1400,
        [
            (0, "n", U8, "const", 2),
            (1, "COB-ID", U32, "rw", 0x200 + node_id),
            (2, "Type", U8, "rw", 255),
        ],
    )
    _record(
        od, ODRecord, "RPDO1 map", 0x1600, [(0, "n", U8, "rw", 1), (1, "e1", U32, "rw", 0x62000108)]
    )
    _record(
        od,
        ODRecord,
        "TPDO1 comm",
        0x1800,
        [
            (0, "n", U8, "const", 5),
            (1, "COB-ID", U32, "rw", 0x180 + node_id),
            (2, "Type", U8, "rw", 255),
            (3, "Inhibit", U16, "rw", 0),
            (5, "Event timer", U16, "rw", 0),
        ],
    )
    _record(
        od, ODRecord, "TPDO1 map", 0x1A00, [(0, "n", U8, "rw", 1), (1, "e1", U32, "rw", 0x60000108)]
    )
    od.add_object(_var("Setpoint", 0x2000, 0, U32, "rw", 100, False, 0, 1000))
    _record(
        od,
        ODArray,
        "Read input 8-bit",
        0x6000,
        [(0, "n", U8, "ro", 1), (1, "DI1", U8, "ro", 0, True)],
    )
    _record(
        od,
        ODArray,
        "Write output 8-bit",
        0x6200,
        [(0, "n", U8, "ro", 1), (1, "DO1", U8, "rw", 0, True)],
    )
    return od


def write_eds(path: Path) -> Path:
    canopen.export_od(build_od(), str(path), doc_type="eds")
    return path


class LocalNodeDevice:
    """A canopen Network with one LocalNode on a virtual channel, booted to Pre-operational."""

    def __init__(self, channel: str, eds: Path):
        self.network = canopen.Network()
        self.network.connect(interface="virtual", channel=channel)
        self.node = canopen.LocalNode(NODE_ID, str(eds))
        self.network.add_node(self.node)

    def __enter__(self) -> LocalNodeDevice:
        self.node.nmt.state = "INITIALISING"
        self.node.nmt.state = "PRE-OPERATIONAL"  # sends the boot-up message
        return self

    def __exit__(self, *exc) -> None:
        self.node.nmt.stop_heartbeat()
        self.network.disconnect()


def main() -> None:
    """Serve the LocalNode on a real bus until stopped (the SocketCAN stage runs it as its
    own process): ``python tests/conformance/conformance_localnode.py --channel vcan0 --eds F``."""
    import argparse
    import signal
    import threading

    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--eds", type=Path, required=True, help="write the node's EDS here first")
    args = p.parse_args()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    eds = write_eds(args.eds)
    network = canopen.Network()
    network.connect(interface=args.interface, channel=args.channel)
    node = canopen.LocalNode(NODE_ID, str(eds))
    network.add_node(node)
    node.nmt.state = "INITIALISING"
    node.nmt.state = "PRE-OPERATIONAL"  # sends the boot-up message
    print("LocalNode up", flush=True)
    try:
        stop.wait()
    except KeyboardInterrupt:
        pass
    node.nmt.stop_heartbeat()
    network.disconnect()


if __name__ == "__main__":
    main()
