"""I/O connection paths (paths.py): the path attributes name the assemblies each connection carries."""

from __future__ import annotations

from ...dnet import (
    CHOICE_EXPLICIT,
    CHOICE_POLL,
    CHOICE_STROBE,
    SET,
    CipErrorSeen,
    DnetDevice,
    status_text,
)
from ...framework import Context, Fail, Skip, case
from .common import (
    ASSEMBLY,
    CONNECTION,
    POLL_INSTANCE,
    STROBE_INSTANCE,
    P,
    dev,
    io_sizes,
    number,
    set_epr,
)


def assembly_of(path: bytes, what: str) -> int | None:
    """The Assembly instance a connection path names (``20 04 24 nn 30 03``), None if empty."""
    if not path:
        return None
    if path[:3] == b"\x20\x04\x24" and len(path) >= 4 and path[4:] in (b"", b"\x30\x03"):
        return path[3]
    if path[:4] == b"\x20\x04\x25\x00" and len(path) >= 6 and path[6:] in (b"", b"\x30\x03"):
        return number(path[4:6])
    raise Fail(
        f"{what} is not a path to an Assembly's data",
        expected="20 04 24 <instance> 30 03 (or 20 04 25 00 <instance LE16> 30 03)",
        seen=path.hex(" ").upper(),
    )


def check_path(
    d: DnetDevice, instance: int, path_attr: int, size_attr: int, what: str
) -> int | None:
    """The path attribute names an assembly whose data has the connection's size; its instance."""
    path = d.get(CONNECTION, instance, path_attr)
    length = number(d.get(CONNECTION, instance, path_attr - 1))
    if length != len(path):
        raise Fail(
            f"{what}: path length attribute {path_attr - 1} disagrees with the path",
            expected=str(len(path)),
            seen=str(length),
        )
    size = number(d.get(CONNECTION, instance, size_attr))
    assembly = assembly_of(path, f"{what} (attribute {path_attr})")
    if assembly is None:
        return None
    data = d.get(ASSEMBLY, assembly, 3)
    fits = size == len(data) or (instance == STROBE_INSTANCE and size == min(len(data), 8))
    if not fits:
        raise Fail(
            f"{what}: the connection's size is not its assembly's",
            expected=f"attribute {size_attr} = {len(data)} (assembly 0x{assembly:02X} data)",
            seen=str(size),
        )
    return assembly


@case(
    P,
    "io_paths",
    "the I/O connections' path attributes (14/16) name the assembly each carries, of the "
    "connection's size; a path set while Configuring selects another assembly, the size follows",
)
def io_paths(ctx: Context) -> None:
    d = dev(ctx)
    try:
        d.allocate(CHOICE_EXPLICIT | CHOICE_POLL | CHOICE_STROBE)
    except CipErrorSeen as err:
        raise Skip(f"poll + bit-strobe refused ({status_text(err.general)})") from None
    produced = check_path(d, POLL_INSTANCE, 14, 7, "poll produced path")
    check_path(d, POLL_INSTANCE, 16, 8, "poll consumed path")
    check_path(d, STROBE_INSTANCE, 14, 7, "bit-strobe produced path")
    if produced is None:
        return
    # another input assembly: each instance up to the class's maximum whose Set is accepted
    highest = number(d.get(ASSEMBLY, 0, 2))
    others = [n for n in range(1, highest + 1) if n != produced]
    selected = None
    for n in others:
        reply = d.request(
            bytes([SET, CONNECTION, POLL_INSTANCE, 14, 0x20, 0x04, 0x24, n, 0x30, 0x03])
        )
        if reply is None:
            raise Fail("no response to Set of the poll's produced path")
        if reply.service == SET | 0x80:
            selected = n
            break
        if reply.data[:1] == b"\x0e":
            raise Skip(
                "the paths are Get only here: selection is by the device's own configuration"
            )
    if selected is None:
        return  # one input assembly: nothing else to select
    check_path(d, POLL_INSTANCE, 14, 7, f"poll produced path set to 0x{selected:02X}")
    size = number(d.get(CONNECTION, POLL_INSTANCE, 7))
    set_epr(d, POLL_INSTANCE, 1000)
    _, consumed = io_sizes(d, POLL_INSTANCE)
    first = d.poll(b"")  # idle: the produced data only
    if first is None:
        raise Fail("no poll response after selecting a path", expected=f"{size} bytes")
    answer = d.poll_fragments(first, size)
    if len(answer) != size:
        raise Fail(
            "the poll answers another size than its selected path",
            expected=f"{size} bytes (assembly 0x{selected:02X})",
            seen=f"{len(answer)} bytes",
        )
    reply = d.request(
        bytes([SET, CONNECTION, POLL_INSTANCE, 14, 0x20, 0x04, 0x24, produced, 0x30, 0x03])
    )
    if reply is None or reply.data[:1] != b"\x0c":
        raise Fail(
            "a path Set on an Established connection was not refused",
            expected="error 0x0C (object state conflict)",
            seen=str(reply.frames[-1]) if reply else "nothing",
        )
