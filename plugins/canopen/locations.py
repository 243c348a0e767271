"""Where a CANopen front serves each point: CiA 401 object and sub-index, and the PDOs that
map it (byte and bit in the frame), read from the mapping the master may have changed.

Used by the status API (``CanopenFront.point_locations``); nothing here runs per frame.
"""

from __future__ import annotations

from typing import Any

from .cia301.pdo.mapping import Pdo

DI_OBJECT, DO_OBJECT, AI_OBJECT, AO_OBJECT = 0x6000, 0x6200, 0x6401, 0x6411


def object_places(layout: Any) -> dict[str, tuple[int, int, int | None]]:
    """channel id -> (index, sub, bit or None) of its CiA 401 object."""
    places: dict[str, tuple[int, int, int | None]] = {}
    for index, groups in ((DI_OBJECT, layout.di_bytes), (DO_OBJECT, layout.do_bytes)):
        for n, slots in enumerate(groups):
            for bit, ch in enumerate(slots):
                if ch is not None:
                    places[ch.id] = (index, n + 1, bit)
    for index, channels in ((AI_OBJECT, layout.ai), (AO_OBJECT, layout.ao)):
        for n, ch in enumerate(channels):
            places[ch.id] = (index, n + 1, None)
    return places


def pdo_places(pdos: list[Pdo]) -> dict[tuple[int, int], list[tuple[str, int]]]:
    """(index, sub) -> [(PDO name with COB-ID, bit offset in its data)] of every valid PDO."""
    out: dict[tuple[int, int], list[tuple[str, int]]] = {}
    for pdo in pdos:
        if not pdo.valid:
            continue
        name = f"{'TPDO' if pdo.transmit else 'RPDO'}{pdo.number} (0x{pdo.can_id:03X})"
        offset = 0
        for entry in pdo.map_entries[: pdo.map_count]:
            index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            out.setdefault((index, sub), []).append((name, offset))
            offset += bits
    return out


def point_locations(layout: Any, pdos: list[Pdo]) -> dict[str, list[str]]:
    mapped = pdo_places(pdos)
    out: dict[str, list[str]] = {}
    for cid, (index, sub, bit) in object_places(layout).items():
        texts = [f"0x{index:04X}:{sub}" + (f" bit {bit}" if bit is not None else "")]
        for name, offset in mapped.get((index, sub), []):
            if bit is None:
                texts.append(f"{name} bytes {offset // 8}-{offset // 8 + 1}")
            else:
                at = offset + bit
                texts.append(f"{name} byte {at // 8} bit {at % 8}")
        out[cid] = texts
    return out
