"""The NA-9161's special areas (seed-004 §2.2): 0x3000 special input / 0x3200 special output
data, UNSIGNED8, one byte per sub-index in slot order (sub n = byte n-1).

Special channels (``si``/``so``) are the raw byte blocks of modules such as a high-speed
counter (:mod:`..cia401.layouts`); they never go into the default PDO mapping, but a master
may map them, and a changed input byte is a TPDO event on its 0x3000 entry. Output bytes
are written through the CiA 401 objects' output batch (one image batch per RPDO).
"""

from __future__ import annotations

from collections.abc import Sequence

from fieldgate.image import Channel

from ..cia301.entries import UNSIGNED8, ObjectDef, ObjectSpec, build_objects
from ..cia401.batching import OutputWrites
from ..cia401.layouts import SI_OBJECT, SO_OBJECT, IoLayout

Events = dict[tuple[int, int], None]  # (index, sub) an input change fires, in order


def input_events(layout: IoLayout) -> dict[str, Events]:
    """Channel id -> the 0x3000 entry its change fires."""
    return {ch.id: {(SI_OBJECT, n + 1): None} for n, ch in enumerate(layout.si)}


class SpecialBytes:
    """0x3000 / 0x3200 over a layout's special channels."""

    def __init__(self, layout: IoLayout, outputs: OutputWrites):
        self.si, self.so = layout.si, layout.so
        self.outputs = outputs

    def items(self, over: str) -> Sequence[int]:
        return range(len(self.si if over == "si" else self.so))

    @staticmethod
    def byte(channels: Sequence[Channel], n: int) -> int:
        return int(channels[n].value)

    def write_so(self, n: int, value: int) -> None:
        self.outputs.write({self.so[n].id: value})

    def objects(self) -> list[ObjectDef]:
        return build_objects(self, SPECIAL_OBJECTS, self.items)


SPECIAL_OBJECTS: tuple[ObjectSpec[SpecialBytes], ...] = (
    ObjectSpec(
        SI_OBJECT,
        "Read special input data",
        "Special input byte {i}",
        UNSIGNED8,
        "ro",
        "si",
        lambda s, n: s.byte(s.si, n),
        default=0,
        mappable=True,
    ),
    ObjectSpec(
        SO_OBJECT,
        "Write special output data",
        "Special output byte {i}",
        UNSIGNED8,
        "rw",
        "so",
        lambda s, n: s.byte(s.so, n),
        SpecialBytes.write_so,
        mappable=True,
    ),
)
