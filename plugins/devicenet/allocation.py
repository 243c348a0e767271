"""Allocate (0x4B) / Release (0x4C) Master/Slave Connection Set (DeviceNet object, class 3).

Validation order as anchors §2.4 (DEVNET.CPP): another owner 0x0C/01; choice 0, ack
suppression without COS/cyclic, COS with cyclic 0x09/02; unsupported bits (multicast
poll, bit 7) 0x02/02; explicit neither requested nor held 0x09/02; poll while instance 2
carries the master's change-of-state / cyclic data 0x02/04 (the seed's "poll after
COS/cyclic"); a connection already allocated 0x0B/02. A connection that timed out may be
allocated again (it re-opens).

Change of state or cyclic allocated without poll, with a path that consumes outputs, also
opens instance 2 for the master's data (ODVA's predefined set: the master's COS/cyclic
message uses the poll connection's identifiers); allocated together with poll, the outputs
come by poll.
"""

from __future__ import annotations

from typing import Protocol

from . import cip
from .cip import CipError
from .connection import COS_CYCLIC, COS_DATA_ROLE, EXPLICIT, POLL, STROBE, Connection, State

BIT_EXPLICIT, BIT_POLL, BIT_STROBE, BIT_MULTICAST, BIT_COS, BIT_CYCLIC, BIT_ACK_SUPPRESS = (
    0x01,
    0x02,
    0x04,
    0x08,
    0x10,
    0x20,
    0x40,
)
UNSUPPORTED = BIT_MULTICAST | 0x80
UNALLOCATED = 0xFF
BODY_FORMAT_8_8 = 0x00
CONNECTION_BITS = (
    (EXPLICIT, BIT_EXPLICIT),
    (POLL, BIT_POLL),
    (STROBE, BIT_STROBE),
    (COS_CYCLIC, BIT_COS | BIT_CYCLIC),
)


class AllocationHost(Protocol):
    """What allocation reads and calls of the slave (:class:`.engine.DeviceNetSlave` is one)."""

    master_mac: int
    allocation_choice: int
    connections: dict[int, Connection]

    def open_connection(self, instance: int, now: float) -> None: ...

    def open_cos_data(self, now: float) -> bool:
        """Open instance 2 for the master's COS/cyclic data if the path consumes; whether it did."""

    def close_connection(self, instance: int, reason: str) -> None: ...

    def master_back(self, reason: str) -> None: ...


class Allocation:
    def __init__(self, slave: AllocationHost):
        self.slave = slave

    def handle(self, service: int, body: bytes, now: float) -> bytes:
        size = 2 if service == cip.ALLOCATE else 1
        if len(body) < size:
            raise CipError(cip.NOT_ENOUGH_DATA)
        if len(body) > size:
            raise CipError(cip.TOO_MUCH_DATA)
        if service == cip.ALLOCATE:
            return self.allocate(body[0], body[1] & 0x3F, now)
        return self.release(body[0], now)

    def _requested(self, choice: int) -> list[int]:
        return [instance for instance, bits in CONNECTION_BITS if choice & bits]

    def allocate(self, choice: int, master: int, now: float) -> bytes:
        slave = self.slave
        if slave.master_mac != UNALLOCATED and slave.master_mac != master:
            raise CipError(cip.OBJECT_STATE_CONFLICT, cip.ALLOCATION_CONFLICT)
        invalid = cip.INVALID_ATTRIBUTE_VALUE, cip.INVALID_ALLOCATION_CHOICE
        if choice == 0 or (choice & BIT_ACK_SUPPRESS and not choice & (BIT_COS | BIT_CYCLIC)):
            raise CipError(*invalid)
        if choice & BIT_COS and choice & BIT_CYCLIC:
            raise CipError(*invalid)
        if choice & UNSUPPORTED:
            raise CipError(cip.RESOURCE_UNAVAILABLE, cip.INVALID_ALLOCATION_CHOICE)
        if not choice & BIT_EXPLICIT and not slave.connections[EXPLICIT].exists:
            raise CipError(*invalid)
        wanted = self._requested(choice)
        poll = slave.connections[POLL]
        if choice & BIT_POLL and poll.exists and poll.role == COS_DATA_ROLE:
            raise CipError(cip.RESOURCE_UNAVAILABLE, cip.POLL_AFTER_COS_CYCLIC)
        if any(
            slave.connections[i].exists and slave.connections[i].state is not State.TIMED_OUT
            for i in wanted
        ):
            raise CipError(cip.ALREADY_IN_STATE, cip.INVALID_ALLOCATION_CHOICE)
        slave.master_mac = master
        keep = (
            slave.allocation_choice & ~(BIT_COS | BIT_CYCLIC | BIT_ACK_SUPPRESS)
            if choice & (BIT_COS | BIT_CYCLIC)
            else slave.allocation_choice
        )
        slave.allocation_choice = keep | choice
        for instance in wanted:
            slave.open_connection(instance, now)
        reopen = not poll.exists or (poll.role == COS_DATA_ROLE and poll.state is State.TIMED_OUT)
        if choice & (BIT_COS | BIT_CYCLIC) and not choice & BIT_POLL and reopen:
            slave.open_cos_data(now)
        slave.master_back("connection set allocated")
        return bytes([BODY_FORMAT_8_8])

    def release(self, choice: int, now: float) -> bytes:
        slave = self.slave
        if choice == 0 or choice & (UNSUPPORTED | BIT_ACK_SUPPRESS):
            raise CipError(cip.INVALID_ATTRIBUTE_VALUE, cip.INVALID_ALLOCATION_CHOICE)
        wanted = self._requested(choice)
        poll = slave.connections[POLL]
        if any(not slave.connections[i].exists for i in wanted) or (
            choice & BIT_POLL and poll.role == COS_DATA_ROLE
        ):
            raise CipError(cip.ALREADY_IN_STATE, cip.INVALID_ALLOCATION_CHOICE)
        if choice & (BIT_COS | BIT_CYCLIC) and poll.exists and poll.role == COS_DATA_ROLE:
            wanted.append(POLL)  # the master's COS/cyclic data goes with its connection
        for instance in wanted:
            slave.close_connection(instance, "connection released")
        return b""
