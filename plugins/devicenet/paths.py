"""I/O connection paths: which assembly each I/O connection produces and consumes.

The I-7241D's utility sets them per connection type, Poll, Bit-Strobe, COS and Cyclic
(seed-003 §4 rule 6, §6 step 5); here the topology does (the front's ``io_paths``). A
selector names an assembly by category (``di``, ``ai``, ``do``, ``ao``), by direction
(``inputs``, ``outputs``: every category of it, the combined instance when there are
several), by instance number (``0x66``), or ``none``. The connection's produced and
consumed sizes are the selected assemblies' sizes, and its path attributes (14/16) name
them as ``20 04 24 <instance> 30 03`` (class 4, instance, attribute 3).
"""

from __future__ import annotations

from dataclasses import dataclass

from fieldgate.image import Kind

from .assembly import AnyAssembly, Assemblies

PATH_KINDS = ("poll", "strobe", "cos", "cyclic")
# (produce, consume) per connection type when the topology says nothing: the poll carries all
# inputs and all outputs; change of state and cyclic produce all inputs and consume nothing
# (outputs then come by poll); the strobe answers the first 8 bytes of all inputs
DEFAULT_PATHS: dict[str, tuple[str | int, str | int]] = {
    "poll": ("inputs", "outputs"),
    "strobe": ("inputs", "none"),
    "cos": ("inputs", "none"),
    "cyclic": ("inputs", "none"),
}
NAMED = {"di": Kind.DI, "ai": Kind.AI, "do": Kind.DO, "ao": Kind.AO}
ASSEMBLY_CLASS, DATA_ATTRIBUTE = 0x04, 0x03
STROBE_MAX = 8


@dataclass(frozen=True)
class IoPath:
    produce: AnyAssembly | None
    consume: AnyAssembly | None

    @property
    def produced_size(self) -> int:
        return self.produce.size if self.produce else 0

    @property
    def consumed_size(self) -> int:
        return self.consume.size if self.consume else 0


def check_selector(selector: str | int, output: bool) -> None:
    """What can be said of a selector without the assemblies (``fieldgate validate``)."""
    if isinstance(selector, int):
        if not 1 <= selector <= 0xFFFF:
            raise ValueError(f"assembly instance {selector} outside 1..65535")
        return
    names = ("do", "ao", "outputs") if output else ("di", "ai", "inputs")
    if selector != "none" and selector not in names:
        other = ("di", "ai", "inputs") if output else ("do", "ao", "outputs")
        if selector in other:
            raise ValueError(
                f"'{selector}' is an {'input' if output else 'output'}: "
                f"{'consume' if output else 'produce'} takes one of {', '.join(names)}, none or an instance number"
            )
        raise ValueError(
            f"unknown assembly '{selector}': one of {', '.join(names)}, none or an instance number"
        )


def find(assemblies: Assemblies, selector: str | int, output: bool) -> AnyAssembly | None:
    """The assembly a selector names; ValueError says what the front serves instead."""
    check_selector(selector, output)
    if selector == "none":
        return None
    found: AnyAssembly | None
    if isinstance(selector, int):
        found = assemblies.instances.get(selector)
        if found is not None and found.is_output != output:
            raise ValueError(
                f"assembly 0x{selector:02X} holds {'outputs' if found.is_output else 'inputs'}"
            )
    elif selector in ("inputs", "outputs"):  # every assembly of the direction: maybe none
        return assemblies.all_outputs if output else assemblies.all_inputs
    else:
        found = next((a for a in assemblies.categories if a.kind is NAMED[selector]), None)
    if found is None:
        served = ", ".join(a.label for a in assemblies.instances.values()) or "no assembly"
        raise ValueError(f"no assembly '{selector}' here (this front serves {served})")
    return found


def resolve(
    assemblies: Assemblies, selection: dict[str, tuple[str | int, str | int]] | None = None
) -> dict[str, IoPath]:
    """The assemblies of every connection type; ValueError names the type and the selector."""
    chosen = {**DEFAULT_PATHS, **(selection or {})}
    paths: dict[str, IoPath] = {}
    for kind in PATH_KINDS:
        produce, consume = chosen[kind]
        try:
            produced = find(assemblies, produce, output=False)
        except ValueError as exc:
            raise ValueError(f"io_paths.{kind}.produce: {exc}") from None
        try:
            consumed = None if kind == "strobe" else find(assemblies, consume, output=True)
        except ValueError as exc:
            raise ValueError(f"io_paths.{kind}.consume: {exc}") from None
        paths[kind] = IoPath(produced, consumed)
    return paths


def epath(assembly: AnyAssembly | None) -> bytes:
    """``20 04 24 <instance> 30 03`` (``25 00 <instance LE16>`` above 255); empty for none."""
    if assembly is None:
        return b""
    n = assembly.instance
    instance = bytes([0x24, n]) if n <= 0xFF else bytes([0x25, 0x00]) + n.to_bytes(2, "little")
    return bytes([0x20, ASSEMBLY_CLASS]) + instance + bytes([0x30, DATA_ATTRIBUTE])


def parse_epath(path: bytes) -> int | None:
    """The assembly instance a logical path to an Assembly's data names; None for an empty
    path; ValueError for anything else."""
    if not path:
        return None
    if path[:2] != bytes([0x20, ASSEMBLY_CLASS]):
        raise ValueError("not a path to the Assembly class (20 04 ...)")
    rest = path[2:]
    if rest[:1] == b"\x24" and len(rest) >= 2:
        instance, rest = rest[1], rest[2:]
    elif rest[:2] == b"\x25\x00" and len(rest) >= 4:
        instance, rest = int.from_bytes(rest[2:4], "little"), rest[4:]
    else:
        raise ValueError("no instance segment (24 nn or 25 00 nn nn)")
    if rest not in (b"", bytes([0x30, DATA_ATTRIBUTE])):
        raise ValueError("the path must end at the data attribute (30 03)")
    return instance
