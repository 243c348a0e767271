"""The NMT states, and the CAN frame type the CANopen engine uses (:mod:`fieldgate.can.frame`)."""

from __future__ import annotations

from enum import IntEnum

from fieldgate.can.frame import Frame

__all__ = ["Frame", "NmtState", "UNCONFIGURED_NODE_ID"]


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
