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
from .assembly import AnyAssembly
from .connection import (
    COS_CYCLIC,
    COS_DATA_ROLE,
    EXPLICIT,
    POLL,
    POLL_ROLE,
    STROBE,
    Connection,
    State,
    TimeoutAction,
)
from .paths import STROBE_MAX
from .slave_state import SlaveState

EXPLICIT_MIN_SIZE = 0x20
IDENTITY_ALL_FIXED = (
    14  # Get_Attributes_All of Identity before the product name (length byte + text)
)
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
        # every response fits (the largest assembly's data, Identity Get_Attributes_All with
        # its product name: service + 14 + 1 + up to 32 bytes), so 0x11 never comes in practice
        name = len(slave.settings.product_name.encode("latin-1", "replace")[:255])
        self.explicit_size = max(
            EXPLICIT_MIN_SIZE, slave.assemblies.largest + 4, IDENTITY_ALL_FIXED + 1 + name + 1
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
    def cos_kind(self) -> str:
        """Which paths instance 4 uses: ``cos`` or ``cyclic`` (the allocation choice)."""
        return "cos" if self.slave.allocation_choice & BIT_COS else "cyclic"

    def open(self, instance: int, now: float) -> None:
        slave = self.slave
        c = self.connections[instance]
        m, master = slave.mac_id, slave.master_mac
        c.open(now)
        c.role, c.produces, c.consumes = POLL_ROLE, None, None
        if instance == EXPLICIT:
            c.produced_id = ids.group2_id(m, ids.G2_EXPLICIT_RESPONSE)
            c.consumed_id = ids.group2_id(m, ids.G2_EXPLICIT_REQUEST)
            c.produced_size = c.consumed_size = self.explicit_size
            c.transport, c.comm_characteristics = 0x83, 0x21
        elif instance == POLL:
            path = slave.paths["poll"]
            c.produced_id = ids.group1_id(ids.G1_POLL_RESPONSE, m)
            c.consumed_id = ids.group2_id(m, ids.G2_POLL)
            c.transport, c.comm_characteristics = 0x82, 0x01
            self.select(c, path.produce, path.consume)
        elif instance == STROBE:
            c.produced_id = ids.group1_id(ids.G1_STROBE_RESPONSE, m)
            c.consumed_id = ids.group2_id(master, ids.G2_STROBE)
            c.transport, c.comm_characteristics = 0x82, 0x02
            self.select(c, slave.paths["strobe"].produce, None)
        else:
            choice = slave.allocation_choice
            c.acked = not choice & BIT_ACK_SUPPRESS
            c.produced_id = ids.group1_id(ids.G1_COS_CYCLIC, m)
            c.consumed_id = ids.group2_id(m, ids.G2_COS_ACK) if c.acked else 0xFFFF
            c.transport = (0x10 if choice & BIT_COS else 0x00) | (0x02 if c.acked else 0x00)
            c.comm_characteristics = 0x01 if c.acked else 0x0F
            c.inhibit_ms = 0
            self.select(c, slave.paths[self.cos_kind()].produce, None)
        for hook in self.hooks:
            hook.opened(instance)

    def open_cos_data(self, now: float) -> bool:
        """Instance 2 for the master's change-of-state / cyclic data (COS or cyclic allocated
        without poll, with a path that consumes): consumed on G2/5, acknowledged on G1/0xF
        unless suppressed (transport class 2 or 0, as ODVA's predefined set). False (nothing
        opened) when the path consumes nothing."""
        slave = self.slave
        if slave.paths[self.cos_kind()].consume is None:
            return False
        c = self.connections[POLL]
        c.open(now)
        acked = not slave.allocation_choice & BIT_ACK_SUPPRESS
        c.role, c.acked = COS_DATA_ROLE, acked
        c.consumed_id = ids.group2_id(slave.mac_id, ids.G2_POLL)
        c.produced_id = ids.group1_id(ids.G1_POLL_RESPONSE, slave.mac_id) if acked else 0xFFFF
        c.transport, c.comm_characteristics = (0x82, 0x01) if acked else (0x80, 0xF1)
        self.select(c, None, slave.paths[self.cos_kind()].consume)
        for hook in self.hooks:
            hook.opened(POLL)
        return True

    def cos_data(self) -> Connection | None:
        """Instance 2 while it carries the master's change-of-state / cyclic data."""
        c = self.connections[POLL]
        return c if c.exists and c.role == COS_DATA_ROLE else None

    @staticmethod
    def select(c: Connection, produces: AnyAssembly | None, consumes: AnyAssembly | None) -> None:
        """The connection's paths, and its sizes from them (a strobe answers at most 8 bytes)."""
        c.produces, c.consumes = produces, consumes
        size = produces.size if produces is not None else 0
        c.produced_size = min(size, STROBE_MAX) if c.instance == STROBE else size
        c.consumed_size = 8 if c.instance == STROBE else consumes.size if consumes else 0

    def close(self, instance: int, reason: str) -> None:
        slave = self.slave
        c = self.connections[instance]
        was_running = c.is_io and c.state is State.ESTABLISHED
        cos_data = instance == POLL and c.role == COS_DATA_ROLE
        c.close()
        c.role = POLL_ROLE
        for hook in self.hooks:
            hook.stopped(instance)
        if not cos_data:
            slave.allocation_choice &= ~dict(CONNECTION_BITS)[instance]
        if instance == COS_CYCLIC:
            slave.allocation_choice &= ~BIT_ACK_SUPPRESS
        if not any(conn.exists for conn in self.connections.values()):
            slave.master_mac, slave.allocation_choice = UNALLOCATED, 0
        if was_running:
            self.master_lost(f"{'cos-cyclic-data' if cos_data else NAMES[instance]} {reason}")

    def close_all(self, reason: str) -> None:
        for instance in self.connections:
            self.close(instance, reason)

    def set_epr(self, connection: Connection, ms: int, now: float) -> int:
        """Attribute 9: the granted rate (rounded up); establishes a Configuring connection.

        The rate of instance 4 is also the rate of the master's change-of-state / cyclic data
        on instance 2 while that is still Configuring (a master that sets only instance 4)."""
        granted = connection.set_epr(ms, now)
        changed = [connection]
        data = self.cos_data()
        if (
            connection.instance == COS_CYCLIC
            and data is not None
            and data.state is State.CONFIGURING
        ):
            data.set_epr(ms, now)
            changed.append(data)
        for c in changed:
            if c.established:
                for hook in self.hooks:
                    hook.rate_set(c.instance, c.epr_ms)
        return granted

    # -- watchdogs and master loss ---------------------------------------------------------
    def check_watchdogs(self, now: float) -> None:
        for c in self.connections.values():
            if not c.expired(now):
                continue
            name = self.name(c)
            self.slave.counters[f"{name}_timeouts"] += 1
            if c.action is TimeoutAction.AUTO_DELETE or not c.is_io:
                self.close(c.instance, "timed out (deleted)")
            else:
                c.state, c.watchdog_at = State.TIMED_OUT, None
                for hook in self.hooks:
                    hook.stopped(c.instance)
                self.master_lost(f"{name} connection timed out ({c.epr_ms} ms x 4)")

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

    def name(self, c: Connection) -> str:
        return (
            "cos-cyclic-data"
            if c.instance == POLL and c.role == COS_DATA_ROLE
            else NAMES[c.instance]
        )

    def status(self) -> dict[str, dict[str, object]]:
        out: dict[str, dict[str, object]] = {}
        for c in self.connections.values():
            if c.exists:
                out[self.name(c)] = {
                    "state": c.state.name.lower(),
                    "epr_ms": c.epr_ms,
                    "produced": c.produces.instance if c.produces else None,
                    "produced_size": c.produced_size,
                    "consumed": c.consumes.instance if c.consumes else None,
                    "consumed_size": c.consumed_size,
                }
        return out
