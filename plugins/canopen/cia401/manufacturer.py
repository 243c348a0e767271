"""Manufacturer-specific objects of the gateway's modules (seed-000 §3.6, seed-001 §2.5-2.6, §4.7).

One sub-index per module, modules in the front's order (the I-7232D's ascending
address); sub 0 = number of modules.

| Object | Type | Meaning |
|---|---|---|
| 0x2000 | U16 rw | error counter: +1 per failed access, wraps 65535 -> 0; write 0 to clear (``na9161`` style: 0x2030, as 0x2000 is the NA-9161's slot memory, :mod:`.slots`) |
| 0x2001 | U8 rw | DCON host watchdog enable (0/1); only with DCON modules |
| 0x2002 | U8 rw | DCON host watchdog timeout, 0.1 s (1..255); only with DCON modules |
| 0x2003 | U8 rw | DCON host watchdog expired (1); write 0 sends ``~AA1`` |
| 0x2010 | U8 ro | module address |
| 0x2011 | VISIBLE_STRING ro | module model |
| 0x2012-0x2015 | U8 ro | number of DI / DO / AI / AO channels |
| 0x2020:1 / 0x2220:1 | U16 ro | total DI / DO bits (``na9161`` style, as the NA-9161) |

A module going offline (its consecutive failures exceed the back's ``fail_threshold``,
3 by default: "more than three times") raises EMCY 0xFF00, register 0x81, manufacturer
bytes ``0B <address> 00 00 00``; its return clears it (error reset EMCY when nothing
else is active). Writing 0 to its 0x2000 counter acknowledges the error too (seed-001
TV-E04 sends the error reset then); it is raised again at the module's next offline
transition.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import Any

from fieldgate.health import HealthEvent, HealthRegistry, ModuleHealth
from fieldgate.host_watchdog import HostWatchdogs, NoHostWatchdog, WatchdogUnavailable

from ..cia301 import abort
from ..cia301.abort import VALUE_RANGE
from ..cia301.entries import (
    UNSIGNED8,
    UNSIGNED16,
    VISIBLE_STRING,
    Abort,
    Entry,
    ObjectDef,
    ObjectSpec,
    build_objects,
    const,
    count_entry,
)
from .layouts import IoLayout, ModuleRef

log = logging.getLogger("fieldgate.canopen.manufacturer")

ERROR_COUNTERS = 0x2000
NA9161_ERROR_COUNTERS = 0x2030  # the na9161 style: 0x2000 is the NA-9161's read memory
WATCHDOG_ENABLE, WATCHDOG_TIME, WATCHDOG_STATUS = 0x2001, 0x2002, 0x2003
MODULE_ADDRESS, MODULE_MODEL = 0x2010, 0x2011
MODULE_COUNTS = {0x2012: "di", 0x2013: "do", 0x2014: "ai", 0x2015: "ao"}
DI_BITS, DO_BITS = 0x2020, 0x2220
MODULE_EMCY_CODE, MODULE_EMCY_REGISTER, MODULE_EMCY_BYTE = 0xFF00, 0x80, 0x0B

Raise = Callable[[int, int, bytes], Any]  # (code, register bits, manufacturer bytes)
Clear = Callable[[int, bytes], Any]  # (code, manufacturer bytes)


def module_emcy_bytes(address: int) -> bytes:
    return bytes([MODULE_EMCY_BYTE, address & 0xFF])


class ManufacturerObjects:
    def __init__(
        self,
        layout: IoLayout,
        health: HealthRegistry,
        *,
        style: str = "icpdas",
        host_watchdogs: HostWatchdogs | None = None,
        module_emcy: bool = True,
    ):
        self.layout = layout
        self.module_emcy = module_emcy  # False: the front raises/clears the offline EMCY itself
        self.health = health
        self.style = style
        # the gateway's host watchdogs (HostWatchdogs.from_context: which backs have them, the
        # configured settings, the running backs); none: no 0x2001-0x2003
        self.host_watchdogs = host_watchdogs if host_watchdogs is not None else HostWatchdogs()
        self._raise: Raise | None = None
        self._clear: Clear | None = None
        self._keys = {(m.back, m.address) for m in layout.modules}
        health.subscribe(self._health_event)

    # -- module health -> EMCY ----------------------------------------------------------
    def attach(self, raise_error: Raise, clear_error: Clear) -> None:
        self._raise, self._clear = raise_error, clear_error
        for m in (
            self.layout.modules if self.module_emcy else ()
        ):  # modules already offline at start
            h = self._health(m)
            if h is not None and not h.online:
                raise_error(MODULE_EMCY_CODE, MODULE_EMCY_REGISTER, module_emcy_bytes(m.address))

    def detach(self) -> None:
        self._raise = self._clear = None

    def _health_event(self, health: ModuleHealth, event: HealthEvent) -> None:
        if health.key not in self._keys or self._raise is None or self._clear is None:
            return
        if event is HealthEvent.OFFLINE and self.module_emcy:
            self._raise(MODULE_EMCY_CODE, MODULE_EMCY_REGISTER, module_emcy_bytes(health.address))
        elif (
            event is HealthEvent.ONLINE and self.module_emcy
        ) or event is HealthEvent.COUNTER_CLEARED:
            self._clear(MODULE_EMCY_CODE, module_emcy_bytes(health.address))

    def _health(self, module: ModuleRef) -> ModuleHealth | None:
        try:
            return self.health.get(module.back, module.address)
        except KeyError:
            return None

    # -- 0x2000 ---------------------------------------------------------------------------
    def counter(self, module: ModuleRef) -> int:
        h = self._health(module)
        return 0 if h is None else h.error_counter

    def write_counter(self, module: ModuleRef, value: int) -> None:
        if value != 0:
            raise Abort(VALUE_RANGE, "an error counter can only be cleared (write 0)")
        h = self._health(module)
        if h is not None:
            h.clear_error_counter()

    # -- DCON watchdog (0x2001-0x2003): fieldgate.host_watchdog, shared with the devicenet front ------
    def _wd_call(self, action: Callable[[], None]) -> None:
        try:
            action()
        except (NoHostWatchdog, ValueError) as exc:
            raise Abort(VALUE_RANGE, str(exc)) from None
        except WatchdogUnavailable as exc:
            raise Abort(abort.HARDWARE_ERROR, str(exc)) from None

    def wd_enabled(self, module: ModuleRef) -> int:
        return int(self.host_watchdogs.enabled(module.back, module.address))

    def wd_time(self, module: ModuleRef) -> int:
        return self.host_watchdogs.timeout_tenths(module.back, module.address)

    def wd_status(self, module: ModuleRef) -> int:
        return int(self.host_watchdogs.expired(module.back, module.address))

    def write_wd_enabled(self, module: ModuleRef, value: int) -> None:
        self._wd_call(lambda: self.host_watchdogs.set_enabled(module.back, module.address, value))

    def write_wd_time(self, module: ModuleRef, value: int) -> None:
        self._wd_call(
            lambda: self.host_watchdogs.set_timeout_tenths(module.back, module.address, value)
        )

    def write_wd_status(self, module: ModuleRef, value: int) -> None:
        if value != 0:
            raise Abort(VALUE_RANGE, "write 0 to clear the watchdog status")
        self._wd_call(lambda: self.host_watchdogs.recover(module.back, module.address))

    # -- objects ----------------------------------------------------------------------------
    def items(self, over: str) -> list[ModuleRef]:
        return self.layout.modules  # every table row serves one entry per module

    def objects(self) -> list[ObjectDef]:
        mods = self.layout.modules
        if not mods:
            return []
        counters = MODULE_COUNTERS
        if self.style == "na9161":
            counters = replace(counters, index=NA9161_ERROR_COUNTERS)
        rows = [counters]
        if self.host_watchdogs.any((m.back, m.address) for m in mods):
            rows += WATCHDOG_OBJECTS
        objs = build_objects(self, [*rows, *MODULE_INFO_OBJECTS], self.items)
        if self.style == "na9161":
            objs += [
                _bit_size(DI_BITS, "Input information", self.layout.di_bytes),
                _bit_size(DO_BITS, "Output information", self.layout.do_bytes),
            ]
        return objs


def _channel_count(kind: str, owner: ManufacturerObjects, module: ModuleRef) -> int:
    count: int = getattr(module, kind)
    return min(255, count)


def _bit_size(index: int, name: str, digital: list[list[Any]]) -> ObjectDef:
    """0x2020 / 0x2220 (the NA-9161's): sub 1, the digital channels of one direction."""
    bits = sum(1 for b in digital for c in b if c is not None)
    entry = Entry(1, "Digital bit size", UNSIGNED16, "ro", const(bits), default=bits)
    return ObjectDef(index, name, "record", [count_entry(1), entry])


M = ManufacturerObjects
# A documented table: (index, object name, entry name ({n}: the sub-index, one per module in
# the front's order), data type, access, "modules", read, write); defaults: the values when built.
# fmt: off
MODULE_COUNTERS: ObjectSpec[ManufacturerObjects] = ObjectSpec(
    ERROR_COUNTERS, "Module error counter", "Module error counter {n}", UNSIGNED16, "rw", "modules",
    M.counter, M.write_counter)
WATCHDOG_OBJECTS: tuple[ObjectSpec[ManufacturerObjects], ...] = (
    ObjectSpec(WATCHDOG_ENABLE, "Host watchdog enable", "Host watchdog enable {n}", UNSIGNED8, "rw",
               "modules", M.wd_enabled, M.write_wd_enabled),
    ObjectSpec(WATCHDOG_TIME, "Host watchdog time", "Host watchdog time {n}", UNSIGNED8, "rw",
               "modules", M.wd_time, M.write_wd_time),
    ObjectSpec(WATCHDOG_STATUS, "Host watchdog status", "Host watchdog status {n}", UNSIGNED8, "rw",
               "modules", M.wd_status, M.write_wd_status),
)
MODULE_INFO_OBJECTS: tuple[ObjectSpec[ManufacturerObjects], ...] = (
    ObjectSpec(MODULE_ADDRESS, "Module address", "Module address {n}", UNSIGNED8, "ro", "modules",
               lambda _, m: m.address & 0xFF),
    ObjectSpec(MODULE_MODEL, "Module model", "Module model {n}", VISIBLE_STRING, "ro", "modules",
               lambda _, m: m.model or "-"),
    *(
        ObjectSpec(index, f"Module {kind.upper()} channels", f"Module {kind.upper()} channels {{n}}",
                   UNSIGNED8, "ro", "modules", partial(_channel_count, kind))
        for index, kind in MODULE_COUNTS.items()
    ),
)
# fmt: on
