"""The CIP objects the slave serves: Identity (1), DeviceNet (3), Assembly (4), Connection (5),
Acknowledge Handler (0x2B).

Each object maps ``(instance, attribute)`` to an :class:`Attribute` (a getter returning
bytes, None for a Set-only attribute, and an optional setter taking bytes and returning
the response data). Class-level attributes are instance 0. Errors are
:class:`~.cip.CipError`. Identity instance 1 also answers Get_Attributes_All (0x01) and
Reset (0x05).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from fieldgate.host_watchdog import HostWatchdogs
from fieldgate.module_info import ModuleInfo

from . import cip
from .allocation import Allocation
from .assembly import AnyAssembly, Assemblies
from .cip import CipError
from .connection import (
    COS_CYCLIC,
    COS_DATA_ROLE,
    EXPLICIT,
    STROBE,
    Connection,
    State,
    TimeoutAction,
)
from .paths import IoPath, epath, parse_epath
from .settings import Settings

Getter = Callable[[], bytes]
Setter = Callable[[bytes], bytes]


@dataclass
class Attribute:
    get: Getter | None  # None: Set only (Get answers 0x2C)
    set: Setter | None = None

    def read(self) -> bytes:
        """What a Get answers; a Set-only attribute is CIP error 0x2C."""
        if self.get is None:
            raise CipError(cip.ATTRIBUTE_NOT_GETTABLE)
        return self.get()


class SlaveHost(Protocol):
    """What the CIP objects read and call of the slave (:class:`.engine.DeviceNetSlave` is one).

    The objects depend on this interface, not on the engine module: the engine imports
    the objects, nothing imports the engine back.
    """

    settings: Settings
    assemblies: Assemblies
    paths: dict[str, IoPath]
    allocation: Allocation
    connections: dict[int, Connection]
    host_watchdogs: HostWatchdogs
    module_info: ModuleInfo
    mac_id: int
    baud_code: int
    pending_baud_code: int | None
    master_mac: int
    allocation_choice: int
    bus_off_interrupt: int
    bus_off_count: int
    ack_timer_ms: int
    ack_retry_limit: int

    @property
    def heartbeat_s(self) -> int: ...

    @property
    def identity_status(self) -> int: ...

    @property
    def operation_state(self) -> str: ...

    def set_heartbeat(self, seconds: int) -> None: ...

    def schedule_restart(self, class_id: int) -> None: ...

    def change_mac(self, mac: int) -> None: ...

    def settings_changed(self) -> None: ...

    def write_assembly(self, assembly: AnyAssembly, data: bytes) -> None: ...

    def set_epr(self, connection: Connection, ms: int) -> int: ...

    def select_path(
        self, connection: Connection, produces: AnyAssembly | None, consumes: AnyAssembly | None
    ) -> None: ...


def u8(v: int) -> bytes:
    return bytes([v & 0xFF])


def u16(v: int) -> bytes:
    return (v & 0xFFFF).to_bytes(2, "little")


def u32(v: int) -> bytes:
    return (v & 0xFFFFFFFF).to_bytes(4, "little")


def short_string(text: str) -> bytes:
    raw = text.encode("latin-1", "replace")[:255]
    return bytes([len(raw)]) + raw


def const(data: bytes) -> Getter:
    return lambda: data


class Sized:
    """Set data of a fixed-size attribute: too short 0x13, too long 0x15 (unless tolerated)."""

    def __init__(self, slave: SlaveHost):
        self.slave = slave

    def take(self, data: bytes, size: int) -> int:
        if len(data) < size:
            raise CipError(cip.NOT_ENOUGH_DATA)
        if len(data) > size and not self.slave.settings.tolerate_trailing_bytes:
            raise CipError(cip.TOO_MUCH_DATA)
        return int.from_bytes(data[:size], "little")


class CipObject:
    class_id = 0
    revision = 1

    def __init__(self, slave: SlaveHost):
        self.slave = slave
        self.sized = Sized(slave)

    def instances(self) -> list[int]:
        return [1]

    def class_attributes(self) -> dict[int, Attribute]:
        return {
            1: Attribute(const(u16(self.revision))),
            2: Attribute(lambda: u16(max(self.instances(), default=0))),
        }

    def instance_attributes(self, instance: int) -> dict[int, Attribute]:
        return {}

    def attribute(self, instance: int, attribute: int) -> Attribute:
        if instance != 0 and instance not in self.instances():
            raise CipError(cip.OBJECT_DOES_NOT_EXIST)
        table = self.class_attributes() if instance == 0 else self.instance_attributes(instance)
        if attribute not in table:
            raise CipError(cip.ATTRIBUTE_NOT_SUPPORTED)
        return table[attribute]

    def service(self, service: int, instance: int, body: bytes, now: float) -> bytes:
        """Object-specific services beyond Get/Set_Attribute_Single."""
        raise CipError(cip.SERVICE_NOT_SUPPORTED)


IDENTITY_ALL = (1, 2, 3, 4, 5, 6, 7)  # Get_Attributes_All order


class IdentityObject(CipObject):
    class_id, revision = 0x01, 1

    def instance_attributes(self, instance: int) -> dict[int, Attribute]:
        s = self.slave.settings
        return {
            1: Attribute(const(u16(s.vendor_id))),
            2: Attribute(const(u16(s.device_type))),
            3: Attribute(const(u16(s.product_code))),
            4: Attribute(const(bytes([s.major_revision, s.minor_revision]))),
            5: Attribute(lambda: u16(self.slave.identity_status)),
            6: Attribute(const(u32(s.serial))),
            7: Attribute(const(short_string(s.product_name))),
            10: Attribute(lambda: u8(self.slave.heartbeat_s), self._set_heartbeat),
        }

    def _all_attributes(self, body: bytes) -> bytes:
        """Get_Attributes_All: vendor, device type, product code, revision, status, serial,
        product name (attributes 1-7 in the DeviceNet specification's order)."""
        if body:
            raise CipError(cip.TOO_MUCH_DATA)
        table = self.instance_attributes(1)
        return b"".join(table[attribute].read() for attribute in IDENTITY_ALL)

    def _set_heartbeat(self, data: bytes) -> bytes:
        self.slave.set_heartbeat(self.sized.take(data, 1))
        return b""

    def service(self, service: int, instance: int, body: bytes, now: float) -> bytes:
        if instance not in (0, 1):
            raise CipError(cip.OBJECT_DOES_NOT_EXIST)
        if service == cip.GET_ATTRIBUTES_ALL and instance == 1:
            return self._all_attributes(body)
        if service != cip.RESET or instance != 1:
            raise CipError(cip.SERVICE_NOT_SUPPORTED)
        if len(body) > 1:
            raise CipError(cip.TOO_MUCH_DATA)
        if body and body[0] != 0:
            raise CipError(cip.INVALID_PARAMETER)  # type 1 (factory defaults) is not offered
        self.slave.schedule_restart(self.class_id)
        return b""


BAUD_CODES = {125_000: 0, 250_000: 1, 500_000: 2}


class DeviceNetObject(CipObject):
    class_id, revision = 0x03, 2

    def class_attributes(self) -> dict[int, Attribute]:
        return {1: Attribute(const(u16(self.revision)))}

    def instance_attributes(self, instance: int) -> dict[int, Attribute]:
        slave = self.slave
        return {
            1: Attribute(lambda: u8(slave.mac_id), self._set_mac),
            2: Attribute(
                lambda: u8(
                    slave.baud_code if slave.pending_baud_code is None else slave.pending_baud_code
                ),
                self._set_baud,
            ),
            3: Attribute(lambda: u8(slave.bus_off_interrupt), self._set_boi),
            4: Attribute(lambda: u8(slave.bus_off_count), self._set_bus_off_count),
            5: Attribute(lambda: bytes([slave.allocation_choice, slave.master_mac])),
        }

    def _byte_up_to(self, data: bytes, highest: int) -> int:
        """The one-byte value written; above ``highest``: Invalid attribute value."""
        value = self.sized.take(data, 1)
        if value > highest:
            raise CipError(cip.INVALID_ATTRIBUTE_VALUE)
        return value

    def _set_mac(self, data: bytes) -> bytes:
        self.slave.change_mac(self._byte_up_to(data, 63))
        return b""

    def _set_baud(self, data: bytes) -> bytes:
        self.slave.pending_baud_code = self._byte_up_to(data, 2)
        self.slave.settings_changed()
        return b""

    def _set_boi(self, data: bytes) -> bytes:
        self.slave.bus_off_interrupt = self._byte_up_to(data, 1)
        return b""

    def _set_bus_off_count(self, data: bytes) -> bytes:
        self.sized.take(data, 1)  # any write clears the counter
        self.slave.bus_off_count = 0
        return b""

    def service(self, service: int, instance: int, body: bytes, now: float) -> bytes:
        if service in (cip.ALLOCATE, cip.RELEASE) and instance == 1:
            return self.slave.allocation.handle(service, body, now)
        raise CipError(cip.SERVICE_NOT_SUPPORTED)


class AssemblyObject(CipObject):
    class_id, revision = 0x04, 2

    def instances(self) -> list[int]:
        return list(self.slave.assemblies.instances)

    def instance_attributes(self, instance: int) -> dict[int, Attribute]:
        assembly = self.slave.assemblies.instances[instance]

        def write(data: bytes) -> bytes:
            if len(data) < assembly.size:
                raise CipError(cip.NOT_ENOUGH_DATA)
            if len(data) > assembly.size:
                raise CipError(cip.TOO_MUCH_DATA)
            self.slave.write_assembly(assembly, data)
            return b""

        return {3: Attribute(assembly.data, write if assembly.is_output else None)}


class ConnectionObject(CipObject):
    """Connection instances 1-4 while they exist. The I/O connections' path attributes 14/16
    name the assembly they produce / consume (``20 04 24 <instance> 30 03``) and may be set
    while the connection is Configuring (ODVA; the I-7241D's tables mark them Get): the
    sizes (7/8) follow."""

    class_id, revision = 0x05, 1

    def instances(self) -> list[int]:
        return [n for n, c in self.slave.connections.items() if c.exists]

    def class_attributes(self) -> dict[int, Attribute]:
        return {1: Attribute(const(u16(self.revision)))}

    def instance_attributes(self, instance: int) -> dict[int, Attribute]:
        c = self.slave.connections[instance]

        def produced_path() -> bytes:
            return epath(c.produces)

        def consumed_path() -> bytes:
            return ACK_HANDLER_PATH if self._acks_path(c) else epath(c.consumes)

        return {
            1: Attribute(lambda: u8(c.state)),
            2: Attribute(const(u8(0 if instance == EXPLICIT else 1))),
            3: Attribute(lambda: u8(c.transport)),
            4: Attribute(lambda: u16(c.produced_id)),
            5: Attribute(lambda: u16(c.consumed_id)),
            6: Attribute(lambda: u8(c.comm_characteristics)),
            7: Attribute(lambda: u16(c.produced_size)),
            8: Attribute(lambda: u16(c.consumed_size)),
            9: Attribute(lambda: u16(c.epr_ms), lambda data: self._set_epr(c, data)),
            12: Attribute(lambda: u8(c.action), lambda data: self._set_action(c, data)),
            13: Attribute(lambda: u16(len(produced_path()))),
            14: Attribute(produced_path, self._path_setter(c, produced=True)),
            15: Attribute(lambda: u16(len(consumed_path()))),
            16: Attribute(consumed_path, self._path_setter(c, produced=False)),
            17: Attribute(lambda: u16(c.inhibit_ms), lambda data: self._set_inhibit(c, data)),
        }

    @staticmethod
    def _acks_path(c: Connection) -> bool:
        """Instance 4 acknowledged consumes the master's acks: its path is the Acknowledge Handler."""
        return c.instance == COS_CYCLIC and c.acked

    def _path_setter(self, c: Connection, produced: bool) -> Setter | None:
        if c.instance == EXPLICIT or (not produced and (c.instance in (STROBE, COS_CYCLIC))):
            return None  # explicit: no paths; strobe consumes the strobe bits; 4 consumes acks
        if produced and c.role == COS_DATA_ROLE:
            return None  # the master's COS/cyclic data: the slave produces only acks

        def write(data: bytes) -> bytes:
            if c.state is not State.CONFIGURING:
                raise CipError(cip.OBJECT_STATE_CONFLICT)
            try:
                instance = parse_epath(data)
            except ValueError:
                raise CipError(cip.INVALID_ATTRIBUTE_VALUE) from None
            assembly = None if instance is None else self.slave.assemblies.instances.get(instance)
            if instance is not None and (assembly is None or assembly.is_output == produced):
                raise CipError(cip.INVALID_ATTRIBUTE_VALUE)  # no such assembly, or the wrong way
            if produced:
                self.slave.select_path(c, assembly, c.consumes)
            else:
                self.slave.select_path(c, c.produces, assembly)
            return b""

        return write

    def _set_epr(self, c: Connection, data: bytes) -> bytes:
        granted = self.slave.set_epr(c, self.sized.take(data, 2))
        return u16(granted)

    def _set_action(self, c: Connection, data: bytes) -> bytes:
        value = self.sized.take(data, 1)
        if value not in (TimeoutAction.TIMED_OUT, TimeoutAction.AUTO_DELETE):
            raise CipError(cip.INVALID_ATTRIBUTE_VALUE)
        c.action = TimeoutAction(value)
        return b""

    def _set_inhibit(self, c: Connection, data: bytes) -> bytes:
        if c.instance != COS_CYCLIC:
            raise CipError(cip.ATTRIBUTE_NOT_SETTABLE)
        c.inhibit_ms = self.sized.take(data, 2)
        return b""


ACK_HANDLER_PATH = bytes([0x20, 0x2B, 0x24, 0x01])


class AcknowledgeHandlerObject(CipObject):
    """Acknowledge Handler (class 0x2B) instance 1, what the acknowledged change-of-state /
    cyclic connection's consumed path names (seed-003 §3.5: ``20 2B 24 01``): 1 acknowledge
    timer (ms before a production is sent again), 2 retry limit, 3 the producing connection
    instance (4)."""

    class_id, revision = 0x2B, 1

    def instance_attributes(self, instance: int) -> dict[int, Attribute]:
        slave = self.slave
        return {
            1: Attribute(lambda: u16(slave.ack_timer_ms), self._set_timer),
            2: Attribute(lambda: u8(slave.ack_retry_limit), self._set_retries),
            3: Attribute(const(u16(COS_CYCLIC))),
        }

    def _set_timer(self, data: bytes) -> bytes:
        value = self.sized.take(data, 2)
        if value == 0:
            raise CipError(cip.INVALID_ATTRIBUTE_VALUE)
        self.slave.ack_timer_ms = value
        return b""

    def _set_retries(self, data: bytes) -> bytes:
        self.slave.ack_retry_limit = self.sized.take(data, 1)
        return b""
