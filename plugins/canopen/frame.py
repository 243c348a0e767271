"""CAN frames as the sans-I/O CANopen engine sees them, and the NMT states.

The engine never touches python-can: the adapter converts ``can.Message`` to
:class:`Frame` and back (:mod:`fieldgate.plugins.canopen.adapter`).
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple


class Frame(NamedTuple):
    """One classic CAN frame. ``dlc`` is only meaningful for RTR frames (no data).

    Immutable and compared by value; a ``NamedTuple`` because two are built per SDO
    request and it constructs in half the time of a frozen dataclass.
    """

    can_id: int
    data: bytes = b""
    rtr: bool = False
    dlc: int | None = None

    @property
    def length(self) -> int:
        return self.dlc if (self.rtr and self.dlc is not None) else len(self.data)

    def __str__(self) -> str:
        if self.rtr:
            return f"{self.can_id:03X} RTR [{self.length}]"
        return f"{self.can_id:03X} [{len(self.data)}] {self.data.hex(' ').upper()}".rstrip()


class NmtState(IntEnum):
    """NMT states with their CiA 301 heartbeat / guarding state codes."""

    INITIALISING = 0x00
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F

    @property
    def label(self) -> str:
        return self.name.replace("_", "-")


UNCONFIGURED_NODE_ID = 0xFF  # CiA 305: a node without a node-ID waits for LSS
