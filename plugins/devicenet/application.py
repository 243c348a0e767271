"""The I-7241D's Application object, vendor class 0x64: one instance per served module.

Instances are numbered from 1 in the order the front serves modules (ascending address in
the seeds' order). Every attribute of seed-003 §3.6 is served:

| Attr | Type | Access | What |
|---|---|---|---|
| 0x01 | DWORD | Get | module ID: the model number as hex digits (``$AAM`` "7017R": 0x00007017) |
| 0x02 | USINT | Get | module address |
| 0x03 | USINT | Get | checksum: 1 when the module uses one (``$AA2`` format bit 6) |
| 0x04 | DWORD | Get | baud rate in bit/s (``$AA2`` baud code) |
| 0x05 | USINT | Get | type code (``$AA2``; digital modules 0x40) |
| 0x06 | USINT | Get | data format (``$AA2``: 0 engineering, 1 %FSR, 2 hex, 3 ohms) |
| 0x07 | UDINT | Get | data error counter (the module's health error counter) |
| 0x08-0x0B | | | DCON host watchdog (below) |
| 0x0C-0x0F | USINT | Get | DO/AO/DI/AI length in bytes |
| 0x10-0x13 | USINT | Get | DO/AO/DI/AI channel count |
| 0x14/0x15 | bytes | Get/Set | DO/AO data (Set: exact size) |
| 0x16/0x17 | bytes | Get | DI/AI data |
| 0x18 | NULL | Set | fieldgate: latch the module's current outputs as its safe values (§5.3) |

0x01 and 0x03-0x06 come from what the back knows (``fieldgate.module_info``: read from the
module once it answered, the topology's values before); a back without module identities
(Modbus) answers 0x14 for them. 0x18 exists on DCON modules with outputs.

DCON host watchdog (seed-003 §3.6, §5.3, TV-44..51), only on modules of a DCON back
(elsewhere 0x14), through ``fieldgate.host_watchdog`` (shared with the canopen front's
0x2001-0x2003):

| Attr | Type | Access | Meaning | Bad value |
|---|---|---|---|---|
| 0x08 | USINT | Get/Set | watchdog enable, 0/1 | 0x09 |
| 0x09 | USINT | Get/Set | watchdog time, 0.1 s, 1..255 (Get 0: not set, the module keeps its own) | 0x09 |
| 0x0A | USINT | Get | watchdog status: 1 = timed out | Set: 0x0E |
| 0x0B | NULL | Set | clear the status (``~AA1``); the outputs are written again | Get: 0x2C |

Class attribute 5 (fieldgate's, always served): the operation state, the first digit of the
I-7241D's 7-segment display as its character (seed-003 §1.4): ``n`` (0x6E) normal, ``1``
(0x31) DCON modules init error while a back behind the front reports an error of its own
(``modules: auto`` that found no module; the Identity status shows it too).

Class attributes (served when a DCON module is served): 3 "DCON COM port timeout value"
(UINT Get/Set, the DCON backs' reply timeout in ms, 1..60000); 4 "Host OK" (BYTE Get/Set,
0/1): whether the DCON backs may send ``~**``. 1 by default (the back sends it by itself
while a module's watchdog is on and the masters are healthy; the I-7241D starts at 0); 0
stops it, so watchdog-enabled modules time out.

Set data: none 0x13, more than the type 0x15 (tolerated with the front's default
``strict_lengths: false``, as for every USINT). A back that cannot take the change now
(not running) answers 0x10 device state conflict.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from fieldgate.host_watchdog import HostWatchdogs, NoHostWatchdog, WatchdogUnavailable
from fieldgate.image import Channel, Kind
from fieldgate.layout import of_kind, pack_bits
from fieldgate.module_info import ModuleIdentity, ModuleUnavailable

from . import cip
from .assembly import Assembly
from .cip import CipError
from .objects import Attribute, CipObject, Setter, SlaveHost, const, u8, u16, u32

KINDS = (Kind.DO, Kind.AO, Kind.DI, Kind.AI)
LENGTH_ATTR, COUNT_ATTR, DATA_ATTR = 0x0C, 0x10, 0x14
WATCHDOG_ENABLE, WATCHDOG_TIME, WATCHDOG_STATUS, WATCHDOG_CLEAR = 0x08, 0x09, 0x0A, 0x0B
MODULE_ID, CHECKSUM, BAUD_RATE, TYPE_CODE, DATA_FORMAT = 0x01, 0x03, 0x04, 0x05, 0x06
LATCH_SAFE_VALUE = 0x18
COM_TIMEOUT, HOST_OK, OPERATION_STATE = 0x03, 0x04, 0x05  # class attributes
IDENTITY_FIELDS: dict[int, Callable[[ModuleIdentity], bytes]] = {
    MODULE_ID: lambda i: u32(i.module_id),
    CHECKSUM: lambda i: u8(int(bool(i.checksum))),
    BAUD_RATE: lambda i: u32(i.baudrate or 0),
    TYPE_CODE: lambda i: u8(i.type_code or 0),
    DATA_FORMAT: lambda i: u8(i.data_format or 0),
}

ErrorCounter = Callable[[str, int], int]


class ModuleView:
    def __init__(self, back: str, address: int, channels: Sequence[Channel]):
        self.back, self.address = back, address
        self.parts = {
            kind: Assembly(0, kind, pack_bits(members) if kind.is_digital else members)
            for kind in KINDS
            if (members := of_kind(channels, kind))
        }


def module_views(channels: Sequence[Channel]) -> list[ModuleView]:
    order: dict[tuple[str, int], list[Channel]] = {}
    for channel in channels:
        order.setdefault((channel.source.back, channel.source.module), []).append(channel)
    return [ModuleView(back, address, members) for (back, address), members in order.items()]


class ApplicationObject(CipObject):
    class_id, revision = 0x64, 2

    def __init__(self, slave: SlaveHost, modules: list[ModuleView], error_counter: ErrorCounter):
        super().__init__(slave)
        self.modules = modules
        self.error_counter = error_counter

    def instances(self) -> list[int]:
        return list(range(1, len(self.modules) + 1))

    def class_attributes(self) -> dict[int, Attribute]:
        table = super().class_attributes()
        # fieldgate's: the I-7241D 7-segment's first digit as its character, "n" normal, "1"
        # DCON modules init error (a back reports an error; seed-003 §1.4)
        table[OPERATION_STATE] = Attribute(lambda: u8(ord(self.slave.operation_state)))
        watchdogs, info = self.slave.host_watchdogs, self.slave.module_info
        backs = {m.back for m in self.modules if watchdogs.has(m.back, m.address)}
        table[HOST_OK] = Attribute(
            lambda: u8(watchdogs.host_ok()), self._change(1, watchdogs.set_host_ok)
        )
        table[COM_TIMEOUT] = Attribute(
            lambda: u16(info.reply_timeout_ms(backs) or 0),
            self._change(2, lambda ms: info.set_reply_timeout_ms(backs, ms)),
        )
        return table

    def instance_attributes(self, instance: int) -> dict[int, Attribute]:
        """Every attribute of seed-003 §3.6 on every module (the manual's 0 where the back has
        no such notion), and the safe-value latch 0x18 on DCON modules with outputs."""
        module = self.modules[instance - 1]
        table = {
            0x02: Attribute(lambda: u8(module.address)),
            0x07: Attribute(lambda: u32(self.error_counter(module.back, module.address))),
        }
        info = self.slave.module_info
        for attribute, encode in IDENTITY_FIELDS.items():
            table[attribute] = Attribute(self._identity_getter(module, encode))
        for offset, kind in enumerate(KINDS):
            part = module.parts.get(kind)
            size = part.size if part else 0
            count = len(part.channels) if part else 0
            table[LENGTH_ATTR + offset] = Attribute(const(u8(size)))
            table[COUNT_ATTR + offset] = Attribute(const(u8(count)))
            if part is not None:
                table[DATA_ATTR + offset] = Attribute(
                    part.data, self._writer(part) if kind.is_output else None
                )
            else:  # no such channels: empty data, as the channel count says
                table[DATA_ATTR + offset] = Attribute(
                    const(b""), self._empty_writer() if kind.is_output else None
                )
        watchdogs = self.slave.host_watchdogs
        if watchdogs.has(module.back, module.address):
            table.update(self._watchdog_attributes(watchdogs, module.back, module.address))
            if Kind.DO in module.parts or Kind.AO in module.parts:
                table[LATCH_SAFE_VALUE] = Attribute(
                    None,
                    self._change(0, lambda _: info.latch_safe_value(module.back, module.address)),
                )
        else:  # no host watchdog here (a Modbus module): reads as off, cannot be set
            table.update(
                {
                    WATCHDOG_ENABLE: Attribute(const(u8(0))),
                    WATCHDOG_TIME: Attribute(const(u8(0))),
                    WATCHDOG_STATUS: Attribute(const(u8(0))),
                    WATCHDOG_CLEAR: Attribute(None),
                }
            )
        return table

    def _empty_writer(self) -> Setter:
        def write(data: bytes) -> bytes:
            if data:
                raise CipError(cip.TOO_MUCH_DATA)
            return b""

        return write

    def _identity_getter(
        self, module: ModuleView, encode: Callable[[ModuleIdentity], bytes]
    ) -> Callable[[], bytes]:
        def get() -> bytes:
            identity = self.slave.module_info.identity(module.back, module.address)
            return encode(identity or ModuleIdentity(""))

        return get

    def _change(self, size: int, action: Callable[[int], None]) -> Setter:
        """A watchdog Set: ``size`` data bytes (0 = NULL) -> ``action(value)``, errors as CIP codes."""

        def write(data: bytes) -> bytes:
            value = self.sized.take(data, size)
            try:
                action(value)
            except ValueError:
                raise CipError(cip.INVALID_ATTRIBUTE_VALUE) from None
            except (NoHostWatchdog, WatchdogUnavailable, ModuleUnavailable):
                raise CipError(cip.DEVICE_STATE_CONFLICT) from None
            return b""

        return write

    def _watchdog_attributes(
        self, wd: HostWatchdogs, back: str, address: int
    ) -> dict[int, Attribute]:
        change = self._change
        return {
            WATCHDOG_ENABLE: Attribute(
                lambda: u8(wd.enabled(back, address)),
                change(1, lambda v: wd.set_enabled(back, address, v)),
            ),
            WATCHDOG_TIME: Attribute(
                lambda: u8(wd.timeout_tenths(back, address)),
                change(1, lambda v: wd.set_timeout_tenths(back, address, v)),
            ),
            WATCHDOG_STATUS: Attribute(lambda: u8(wd.expired(back, address))),
            WATCHDOG_CLEAR: Attribute(None, change(0, lambda _: wd.recover(back, address))),
        }

    def _writer(self, part: Assembly) -> Setter:
        def write(data: bytes) -> bytes:
            if len(data) != part.size:
                raise CipError(cip.NOT_ENOUGH_DATA if len(data) < part.size else cip.TOO_MUCH_DATA)
            self.slave.write_assembly(part, data)
            return b""

        return write
