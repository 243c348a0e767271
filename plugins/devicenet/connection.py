"""Connection objects (class 5) of the Predefined Master/Slave set and their watchdogs.

Instance 1 explicit, 2 poll, 3 bit-strobe, 4 change-of-state / cyclic. The inactivity
watchdog is 4 x expected packet rate (EPR), re-armed by every message the connection
consumes; EPR 0 disables it. Setting EPR on a Configuring I/O connection establishes it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from .assembly import AnyAssembly

EXPLICIT, POLL, STROBE, COS_CYCLIC = 1, 2, 3, 4
# what instance 2 carries: the poll, or the master's change-of-state / cyclic data (when COS or
# cyclic is allocated without poll and its path consumes an assembly; ODVA's predefined set)
POLL_ROLE, COS_DATA_ROLE = "poll", "cos-data"
CHOICE_BITS = {EXPLICIT: 0x01, POLL: 0x02, STROBE: 0x04, COS_CYCLIC: 0x30}
EXPLICIT_DEFAULT_EPR_MS = 2500
EPR_RESOLUTION_MS = 10
WATCHDOG_FACTOR = 4


class State(IntEnum):
    NON_EXISTENT = 0
    CONFIGURING = 1
    WAITING_FOR_ID = 2
    ESTABLISHED = 3
    TIMED_OUT = 4
    DEFERRED_DELETE = 5


class TimeoutAction(IntEnum):
    TIMED_OUT = 0
    AUTO_DELETE = 1
    AUTO_RESET = 2
    DEFERRED_DELETE = 3


def round_epr(ms: int) -> int:
    """EPR rounded up to the timer resolution (3594 -> 3600, as TV-03/TV-04)."""
    return min(0xFFFF, math.ceil(ms / EPR_RESOLUTION_MS) * EPR_RESOLUTION_MS)


@dataclass
class Connection:
    instance: int
    state: State = State.NON_EXISTENT
    epr_ms: int = 0
    action: TimeoutAction = TimeoutAction.TIMED_OUT
    produced_id: int = 0xFFFF
    consumed_id: int = 0xFFFF
    produced_size: int = 0
    consumed_size: int = 0
    transport: int = 0x83
    comm_characteristics: int = 0x01
    inhibit_ms: int = 0
    watchdog_at: float | None = None
    acked: bool = True  # COS/cyclic: the acknowledged variant (no suppression)
    produces: AnyAssembly | None = None  # the produced connection path's assembly
    consumes: AnyAssembly | None = None  # the consumed connection path's assembly
    role: str = POLL_ROLE  # instance 2 only

    @property
    def exists(self) -> bool:
        return self.state is not State.NON_EXISTENT

    @property
    def established(self) -> bool:
        return self.state is State.ESTABLISHED

    @property
    def is_io(self) -> bool:
        return self.instance != EXPLICIT

    def open(self, now: float) -> None:
        if self.instance == EXPLICIT:
            self.state, self.epr_ms, self.action = (
                State.ESTABLISHED,
                EXPLICIT_DEFAULT_EPR_MS,
                TimeoutAction.AUTO_DELETE,
            )
        else:
            self.state, self.epr_ms, self.action = State.CONFIGURING, 0, TimeoutAction.TIMED_OUT
        self.kick(now)

    def close(self) -> None:
        self.state, self.epr_ms, self.watchdog_at = State.NON_EXISTENT, 0, None

    def set_epr(self, ms: int, now: float) -> int:
        self.epr_ms = round_epr(ms)
        if self.state is State.CONFIGURING:
            self.state = State.ESTABLISHED
        self.kick(now)
        return self.epr_ms

    @property
    def watched(self) -> bool:
        """Whether this connection consumes anything that proves the master alive."""
        return self.epr_ms > 0 and (self.instance != COS_CYCLIC or self.acked)

    def kick(self, now: float) -> None:
        """A consumed message (or a new EPR): re-arm the inactivity watchdog."""
        self.watchdog_at = (
            now + WATCHDOG_FACTOR * self.epr_ms / 1000.0
            if self.established and self.watched
            else None
        )

    def expired(self, now: float) -> bool:
        return self.watchdog_at is not None and now >= self.watchdog_at
