"""The Predefined Master/Slave Connection Set as it is allocated: connection objects 1-4
opened and closed, their identifiers and sizes, the inactivity watchdogs, and master loss.

Allocate/Release (:mod:`.allocation`) decide *which* connections open or close; this
service does it. An I/O connection whose watchdog expires (or that is released, or dropped
by a reset) while running is the master lost; a new allocation is the master back. The I/O
and explicit services hear of openings, rate changes and stops through
:class:`ConnectionHooks`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from . import ids
from .allocation import BIT_ACK_SUPPRESS, BIT_COS, CONNECTION_BITS, UNALLOCATED
from .connection import COS_CYCLIC, EXPLICIT, POLL, STROBE, Connection, State, TimeoutAction
from .slave_state import SlaveState

EXPLICIT_MIN_SIZE = 0x20
NAMES = {EXPLICIT: "explicit", POLL: "poll", STROBE: "bit-strobe", COS_CYCLIC: "cos-cyclic"}


class ConnectionHooks(Protocol):
    """What a service that uses the connections is told of them."""

    def opened(self, instance: int) -> None: ...

    def rate_set(self, instance: int, granted_ms: int) -> None: ...

    def stopped(self, instance: int) -> None: ...


class ConnectionSet:
    def __init__(self, slave: SlaveState):
        self.slave = slave
        self.hooks: list[ConnectionHooks] = []
        self.connections = {i: Connection(i) for i in NAMES}
        self.explicit_size = max(
            EXPLICIT_MIN_SIZE,
            max((a.size for a in slave.assemblies.instances.values()), default=0) + 4,
        )
        self._master_ok = True
        self._master_listeners: list[Callable[[bool, str], None]] = []

    def __getitem__(self, instance: int) -> Connection:
        return self.connections[instance]

    def on_master(self, listener: Callable[[bool, str], None]) -> None:
        self._master_listeners.append(listener)

    def deadlines(self) -> list[float | None]:
        return [c.watchdog_at for c in self.connections.values()]

    # -- opening and closing -------------------------------------------------------------
    def open(self, instance: int, now: float) -> None:
        slave = self.slave
        c = self.connections[instance]
        m, master = slave.mac_id, slave.master_mac
        c.open(now)
        assemblies = slave.assemblies
        produced, consumed = assemblies.produced_size, assemblies.consumed_size
        if instance == EXPLICIT:
            c.produced_id = ids.group2_id(m, ids.G2_EXPLICIT_RESPONSE)
            c.consumed_id = ids.group2_id(m, ids.G2_EXPLICIT_REQUEST)
            c.produced_size = c.consumed_size = self.explicit_size
            c.transport, c.comm_characteristics = 0x83, 0x21
        elif instance == POLL:
            c.produced_id = ids.group1_id(ids.G1_POLL_RESPONSE, m)
            c.consumed_id = ids.group2_id(m, ids.G2_POLL)
            c.produced_size, c.consumed_size = produced, consumed
            c.transport, c.comm_characteristics = 0x82, 0x01
        elif instance == STROBE:
            c.produced_id = ids.group1_id(ids.G1_STROBE_RESPONSE, m)
            c.consumed_id = ids.group2_id(master, ids.G2_STROBE)
            c.produced_size, c.consumed_size = min(produced, 8), 8
            c.transport, c.comm_characteristics = 0x82, 0x02
        else:
            choice = slave.allocation_choice
            c.acked = not choice & BIT_ACK_SUPPRESS
            c.produced_id = ids.group1_id(ids.G1_COS_CYCLIC, m)
            c.consumed_id = ids.group2_id(m, ids.G2_COS_ACK) if c.acked else 0xFFFF
            c.produced_size, c.consumed_size = produced, 0
            c.transport = (0x10 if choice & BIT_COS else 0x00) | (0x02 if c.acked else 0x00)
            c.comm_characteristics = 0x01 if c.acked else 0x0F
            c.inhibit_ms = 0
        for hook in self.hooks:
            hook.opened(instance)

    def close(self, instance: int, reason: str) -> None:
        slave = self.slave
        c = self.connections[instance]
        was_running = c.is_io and c.state is State.ESTABLISHED
        c.close()
        for hook in self.hooks:
            hook.stopped(instance)
        slave.allocation_choice &= ~dict(CONNECTION_BITS)[instance]
        if instance == COS_CYCLIC:
            slave.allocation_choice &= ~BIT_ACK_SUPPRESS
        if not any(conn.exists for conn in self.connections.values()):
            slave.master_mac, slave.allocation_choice = UNALLOCATED, 0
        if was_running:
            self.master_lost(f"{NAMES[instance]} {reason}")

    def close_all(self, reason: str) -> None:
        for instance in self.connections:
            self.close(instance, reason)

    def set_epr(self, connection: Connection, ms: int, now: float) -> int:
        """Attribute 9: the granted rate (rounded up); establishes a Configuring connection."""
        granted = connection.set_epr(ms, now)
        if connection.established:
            for hook in self.hooks:
                hook.rate_set(connection.instance, granted)
        return granted

    # -- watchdogs and master loss ---------------------------------------------------------
    def check_watchdogs(self, now: float) -> None:
        for c in self.connections.values():
            if not c.expired(now):
                continue
            self.slave.counters[f"{NAMES[c.instance]}_timeouts"] += 1
            if c.action is TimeoutAction.AUTO_DELETE or not c.is_io:
                self.close(c.instance, "timed out (deleted)")
            else:
                c.state, c.watchdog_at = State.TIMED_OUT, None
                for hook in self.hooks:
                    hook.stopped(c.instance)
                self.master_lost(f"{NAMES[c.instance]} connection timed out ({c.epr_ms} ms x 4)")

    def master_lost(self, reason: str) -> None:
        if not self._master_ok:
            return
        self._master_ok = False
        for listener in list(self._master_listeners):
            listener(False, reason)

    def master_back(self, reason: str) -> None:
        if self._master_ok:
            return
        self._master_ok = True
        for listener in list(self._master_listeners):
            listener(True, reason)

    def status(self) -> dict[str, dict[str, object]]:
        return {
            NAMES[i]: {"state": c.state.name.lower(), "epr_ms": c.epr_ms}
            for i, c in self.connections.items()
            if c.exists
        }
