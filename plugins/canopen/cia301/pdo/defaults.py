"""What a PDO is after a reset (CiA 301 §7.2.2): its communication and mapping defaults.

The application's profile (CiA 401: ``cia401.layouts.default_pdos``) decides the
default PDO set of a node; the topology's ``tpdos:`` / ``rpdos:`` change single PDOs
(:class:`PdoSetting`); the PDO service starts every PDO from its :class:`PdoDefault` at
each reset communication.
"""

from __future__ import annotations

from dataclasses import dataclass, field

COB_INVALID = 0x8000_0000  # bit 31 of sub 1: the PDO does not exist


def mapping_entry(index: int, sub: int, bits: int) -> int:
    return index << 16 | sub << 8 | bits


@dataclass
class PdoDefault:
    """Communication and mapping defaults of one PDO. ``cob_id`` may hold ``node_id``."""

    cob_base: int | None  # predefined COB-ID without node ID, None: none
    valid: bool
    trans_type: int
    inhibit: int = 0
    event_timer: int = 0
    entries: list[int] = field(default_factory=list)
    absolute: bool = False  # cob_base is the whole CAN-ID (set by the topology), no node-ID added
    flags: int = (
        0  # other bits of sub 1 kept in the default: bit 30 "no RTR" (an EDS device's file)
    )

    def cob_id(self, node_id: int) -> int:
        if self.cob_base is None:
            return COB_INVALID
        base = self.cob_base if self.absolute else self.cob_base + node_id
        return base | self.flags | (0 if self.valid else COB_INVALID)


@dataclass(frozen=True)
class PdoSetting:
    """What the topology sets for one PDO (``tpdos:`` / ``rpdos:``); None: the style's default."""

    cob_id: int | None = None  # the CAN-ID itself, not counted from the node-ID
    valid: bool | None = None
    trans_type: int | None = None
    inhibit: int | None = None  # 100 us
    event_timer: int | None = None  # ms
    entries: tuple[int, ...] | None = None  # index << 16 | sub << 8 | bits

    def apply(self, pdo: PdoDefault) -> PdoDefault:
        """``pdo`` with this setting's values; a COB-ID given, or data mapped on a PDO that has
        a COB-ID, makes the PDO valid unless ``valid`` says otherwise."""
        cob_base, absolute = pdo.cob_base, pdo.absolute
        valid = pdo.valid
        if self.cob_id is not None:
            cob_base, absolute, valid = self.cob_id, True, True
        elif self.entries:
            valid = cob_base is not None
        if self.valid is not None:
            valid = self.valid
        return PdoDefault(
            cob_base,
            valid,
            pdo.trans_type if self.trans_type is None else self.trans_type,
            pdo.inhibit if self.inhibit is None else self.inhibit,
            pdo.event_timer if self.event_timer is None else self.event_timer,
            list(pdo.entries) if self.entries is None else list(self.entries),
            absolute,
        )


@dataclass
class PdoDefaults:
    tpdo: list[PdoDefault]
    rpdo: list[PdoDefault]
