"""Classic CAN frames as sans-I/O protocol engines (CANopen, DeviceNet) see them.

Engines never touch python-can: :mod:`fieldgate.can.adapter` converts ``can.Message``
to :class:`Frame` and back.
"""

from __future__ import annotations

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
