"""The sans-I/O DeviceNet Group 2 Only slave: fed ``(frame, now)``, returns frames to send.

The engine is the composition of the slave's services, one file each:

* :mod:`.netaccess`: duplicate MAC ID check, communication fault, Offline Connection Set,
  Device Heartbeat, restarts (Identity Reset, MAC ID and baud rate changes);
* :mod:`.explicit`: the unconnected port (Allocate/Release) and the explicit connection,
  fragmented both ways, serving the CIP objects (:mod:`.objects`, :mod:`.application`);
* :mod:`.connection_set`: the Predefined Master/Slave connections as allocated
  (:mod:`.allocation`), their watchdogs, master loss;
* :mod:`.io_messaging`: poll, bit-strobe, change of state and cyclic.

The adapter calls :meth:`DeviceNetSlave.receive`, :meth:`~DeviceNetSlave.tick` at
:meth:`~DeviceNetSlave.next_deadline`, and :meth:`~DeviceNetSlave.flush` after calling
anything else (:meth:`~DeviceNetSlave.inputs_changed`). The front hears of master loss /
return through :meth:`~DeviceNetSlave.on_master` and of a duplicate MAC through
:meth:`~DeviceNetSlave.on_fault`. Bad frames are counted in ``counters``, never raised.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from fieldgate.can.frame import Frame
from fieldgate.host_watchdog import HostWatchdogs
from fieldgate.module_info import ModuleInfo

from . import ids
from .allocation import UNALLOCATED, Allocation
from .application import ApplicationObject, module_views
from .assembly import AnyAssembly, Assemblies
from .connection import Connection
from .connection_set import ConnectionSet
from .explicit import ExplicitServer
from .io_messaging import IoMessaging
from .netaccess import NetworkAccess
from .objects import (
    AcknowledgeHandlerObject,
    AssemblyObject,
    ConnectionObject,
    DeviceNetObject,
    IdentityObject,
)
from .settings import Settings
from .slave_state import SlaveState

log = logging.getLogger("fieldgate.devicenet")

__all__ = ["DeviceNetSlave", "Settings"]


class DeviceNetSlave(SlaveState):
    def __init__(self, settings: Settings, assemblies: Assemblies):
        super().__init__(settings, assemblies)
        self.bus_off_interrupt = 0
        self.bus_off_count = 0
        self.module_fault = False
        self.link_fault: str | None = None  # the interface not set as configured (the front's)
        self.back_fault: str | None = None  # a back behind the front reports an error (the front's)
        self.module_errors: Callable[[str, int], int] = lambda back, address: 0  # the front's
        self.host_watchdogs = HostWatchdogs()  # the front gives the gateway's
        self.module_info = ModuleInfo()  # the front gives the gateway's
        self.connection_set = ConnectionSet(self)
        self.connections: dict[int, Connection] = self.connection_set.connections
        self.io = IoMessaging(self, self.connection_set)
        self.network = NetworkAccess(self, self.connection_set)
        self.allocation = Allocation(self)
        application = ApplicationObject(
            self,
            module_views(assemblies.channels),
            lambda back, address: self.module_errors(back, address),
        )
        self.objects = {
            o.class_id: o
            for o in (
                IdentityObject(self),
                DeviceNetObject(self),
                AssemblyObject(self),
                ConnectionObject(self),
                AcknowledgeHandlerObject(self),
                application,
            )
        }
        self.explicit = ExplicitServer(
            self, self.connection_set, self.network, self.allocation, self.objects
        )
        self.deadline_after_call: float | None = None
        self._listen: frozenset[int] = frozenset()
        self._listen_key: tuple[int, int] | None = None

    # -- listeners ------------------------------------------------------------------------
    def on_master(self, listener: Callable[[bool, str], None]) -> None:
        self.connection_set.on_master(listener)

    def on_fault(self, listener: Callable[[str], None]) -> None:
        self.network.on_fault(listener)

    def on_settings(self, listener: Callable[[int, int], None]) -> None:
        """``listener(mac_id, baud_code)`` when either is changed over the network (to be stored)."""
        self.network.on_settings(listener)

    def on_bit_timing(self, listener: Callable[[int, float], None]) -> None:
        self.network.on_bit_timing(listener)

    def bit_timing_done(self, ok: bool, now: float) -> None:
        """The adapter's answer to a bit-rate switch: the duplicate MAC ID check follows."""
        self.now = now
        self.network.bit_timing_done(ok, now)
        self.deadline_after_call = self.next_deadline()

    # -- adapter interface ----------------------------------------------------------------
    def boot(self, now: float) -> list[Frame]:
        """Start (or restart) with the duplicate MAC ID check."""
        self.network.start_check(now)
        return self._done()

    def receive(self, frame: Frame, now: float) -> list[Frame]:
        self.now = now
        try:
            self._dispatch(frame, now)
            if self.online and self.io.due(now):
                self.io.produce(
                    now
                )  # a connection just established produces at once, after its response
        except Exception:  # never let a frame stop the gateway; count it (and show the first)
            self.counters["rx_internal_errors"] += 1
            if self.counters["rx_internal_errors"] == 1:
                log.exception("DeviceNet frame %s not handled", frame)
        return self._done()

    def tick(self, now: float) -> list[Frame]:
        self.now = now
        self.network.tick(now)
        if self.online:
            self.connection_set.check_watchdogs(now)
            self.explicit.tick(now)
            self.io.tick(now)
        return self._done()

    def flush(self) -> list[Frame]:
        return self._done()

    def listen_ids(self) -> frozenset[int]:
        """The CAN-IDs this slave takes frames on (the adapter's acceptance filters).

        Group 2 for its MAC ID (all eight message IDs: requests, poll, duplicate MAC ID
        check, ...), the allocated master's bit-strobe, and the Group 4 Offline Connection
        Set (0x7EC-0x7EF). The same object while the MAC ID and the master are unchanged.
        """
        key = (self.mac_id, self.master_mac)
        if key != self._listen_key:
            wanted = {ids.group2_id(self.mac_id, message) for message in range(8)}
            if self.master_mac != UNALLOCATED:
                wanted.add(ids.group2_id(self.master_mac, ids.G2_STROBE))
            wanted.update(ids.group4_id(message) for message in range(0x2C, 0x30))
            self._listen, self._listen_key = frozenset(wanted), key
        return self._listen

    def next_deadline(self) -> float | None:
        times = [*self.network.deadlines(), *self.io.deadlines()]
        times += self.connection_set.deadlines() + self.explicit.deadlines()
        due = [t for t in times if t is not None]
        return min(due) if due else None

    def _done(self) -> list[Frame]:
        out = self.take_frames()
        self.deadline_after_call = self.next_deadline()
        return out

    # -- dispatch -----------------------------------------------------------------------------
    def _dispatch(self, frame: Frame, now: float) -> None:
        if frame.rtr:
            self.counters["rx_rtr_ignored"] += 1
            return
        if len(frame.data) > 8:  # not a classic CAN frame (a virtual bus lets one through)
            self.counters["rx_malformed"] += 1
            return
        group, message, mac = ids.decode(frame.can_id)
        if group == 4 and message == ids.G4_FAULTED_REQUEST:
            self.network.offline_request(frame.data, now)
            return
        if group != 2:
            return  # group 1/3 traffic and other group 4 messages are for other nodes
        data = frame.data
        if mac == self.mac_id and message == ids.G2_DUP_MAC:
            self.network.dup_mac_frame(data)
            return
        if not self.online:
            if mac == self.mac_id:
                self.counters["rx_while_" + self.state] += 1
            return
        if message == ids.G2_STROBE and mac == self.master_mac:
            self.io.strobe(data, now)
        elif mac != self.mac_id:
            return
        elif message == ids.G2_UNCONNECTED_REQUEST:
            self.explicit.unconnected(data, now)
        elif message == ids.G2_EXPLICIT_REQUEST:
            self.explicit.request_frame(data, now)
        elif message == ids.G2_POLL:
            self.io.master_data(data, now)
        elif message == ids.G2_COS_ACK:
            self.io.cos_ack(now)
        else:
            self.counters["rx_unexpected"] += 1

    # -- what the objects and allocation call (objects.SlaveHost, allocation.AllocationHost) --
    @property
    def fault_reason(self) -> str:
        return self.network.fault_reason

    @property
    def heartbeat_s(self) -> int:
        return self.network.heartbeat_s

    @property
    def identity_status(self) -> int:
        """Identity attribute 5: bit 0 owned (allocated), bit 8 minor recoverable fault (a module
        offline, the interface not set as configured), bit 10 major recoverable fault (a back
        reports an error: no module found, the I-7241D's 7-segment ``1``)."""
        minor = self.module_fault or self.link_fault is not None
        return (
            (0x0001 if self.allocation_choice else 0)
            | (0x0100 if minor else 0)
            | (0x0400 if self.back_fault is not None else 0)
        )

    @property
    def operation_state(self) -> str:
        """The I-7241D 7-segment's first digit: ``1`` DCON modules init error (a back behind the
        front reports an error of its own), else ``n`` normal."""
        return "1" if self.back_fault is not None else "n"

    def set_heartbeat(self, seconds: int) -> None:
        self.network.set_heartbeat(seconds)

    def schedule_restart(self, class_id: int) -> None:
        self.network.schedule_restart(class_id)

    def change_mac(self, mac: int) -> None:
        self.network.change_mac(mac)

    def settings_changed(self) -> None:
        self.network.settings_changed()

    def write_assembly(self, assembly: AnyAssembly, data: bytes) -> None:
        self.assemblies.consume(assembly, data)

    def set_epr(self, connection: Connection, ms: int) -> int:
        return self.connection_set.set_epr(connection, ms, self.now)

    def open_connection(self, instance: int, now: float) -> None:
        self.connection_set.open(instance, now)

    def select_path(
        self, connection: Connection, produces: AnyAssembly | None, consumes: AnyAssembly | None
    ) -> None:
        self.connection_set.select(connection, produces, consumes)

    def open_cos_data(self, now: float) -> bool:
        return self.connection_set.open_cos_data(now)

    def close_connection(self, instance: int, reason: str) -> None:
        self.connection_set.close(instance, reason)

    def master_back(self, reason: str) -> None:
        self.connection_set.master_back(reason)

    # -- from the front -------------------------------------------------------------------------
    def inputs_changed(self, now: float) -> None:
        """An input of this front changed: a change-of-state connection produces (inhibit time permitting)."""
        self.io.inputs_changed(now)
        self.deadline_after_call = self.next_deadline()

    @property
    def outgoing(self) -> Any:
        """The explicit response being sent in fragments, if any."""
        return self.explicit.outgoing

    def status(self) -> dict[str, Any]:
        return {
            "state": self.state,
            "mac_id": self.mac_id,
            "bitrate": self.bitrate,
            "fault": self.fault_reason or None,
            "identity_status": self.identity_status,
            "link_fault": self.link_fault,
            "back_fault": self.back_fault,
            "master_mac": None if self.master_mac == UNALLOCATED else self.master_mac,
            "allocation_choice": self.allocation_choice,
            "connections": self.connection_set.status(),
            "io_paths": {
                kind: {
                    "produce": path.produce.instance if path.produce else None,
                    "produced_size": path.produced_size,
                    "consume": path.consume.instance if path.consume else None,
                    "consumed_size": path.consumed_size,
                }
                for kind, path in self.paths.items()
            },
            **self.counters,
        }
