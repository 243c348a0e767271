"""0x4500 "FnBus communication register" of the ``na9161`` style (seed-004 §3.3, §A.4).

| Sub | Type | Access | Meaning |
|---|---|---|---|
| 0 | U8 | const | 3 |
| 1 | U32 | ro | status: byte 0 error code, byte 1 slot in error, byte 2 reserved, byte 3 field power |
| 2 | U8 | rw | data mode: 1 compressed (digital bits packed across modules), 0 non-compressed |
| 3 | U32 | rw | slot active flags: bit n-1 = slot n, 1 = deactivated |

Our slots are the front's modules (RS-485 modules, not FnBus slices), numbered from 1 in
the front's order. The status is built from their health: error code
:data:`MODULE_OFFLINE` with the number of the first active slot whose module is offline
(0 / 0 when all answer); byte 3 is 0x80 while the field supply is missing, as the front's
``field_power`` input reports it (a DI wired to the 24 V field supply; without one the
supply is reported present: the gateway cannot sense it otherwise).

Sub 2 and sub 3 are *configuration*: a write is accepted at once (and read back), and the
process image takes the new layout at the next NMT Reset Node ([AMBIG-35]; a master
reconfigures its PDOs then anyway). 0x1010 "save" (sub 1 or 3) keeps them across a
restart of the gateway, 0x1011 "load" brings the topology's values back at the next start.
A deactivated slot is left out of the image (see :mod:`.layouts`). A value with which the
image would not fit (64 bytes per direction, non-compressed needing more) is refused
with 0604 0047 at the write, so a reset never meets an image it cannot build.

0x4503 "Expansion module product code" (sub n = slot n, U32 ro) describes each slot
with the seed's product-code layout (§2.5, read as wire order [AMBIG-20]): byte 0 input
size, byte 1 output size (0xC0 none, 0x80|n-1 = n bits, 0x00|n-1 = n bytes, 0x40|n-1 =
n 16-bit words), byte 2 class flags (0x40 inputs, 0x80 outputs, +0x20 analog, +0x10
special), byte 3 family (0x01 digital, 0x03 analog or special). Our codes are synthetic
(no CREVIS module behind them): a module with digital channels describes those in bytes
0/1 (whatever else it has, as the flags say); otherwise its analog words, else its
special bytes. An ST-2424-like module (4 DI + 4 DO) reads ``83 83 C0 01`` (TV-11), an
ST-5101-like counter (6 bytes in, 2 out) ``05 01 D0 03``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from fieldgate.health import HealthRegistry

from ..cia301.abort import INTERNAL_INCOMPATIBILITY, VALUE_RANGE
from ..cia301.entries import (
    UNSIGNED8,
    UNSIGNED32,
    Abort,
    Entry,
    ObjectDef,
    array,
    const,
    count_entry,
)
from ..cia401.layouts import MAX_SLOTS, LayoutError, ModuleRef

FNBUS, PRODUCT_CODES = 0x4500, 0x4503
NO_DATA = 0xC0
MODULE_OFFLINE = 0x01  # byte 0 of 0x4500:1 (gateway-defined; the seed lists no codes)
FIELD_POWER_MISSING = 0x80  # byte 3 of 0x4500:1 (from the front's field_power input)


class FnBusRegister:
    """Data mode and slot deactivation (configured, in effect) and the status of the slots."""

    def __init__(
        self,
        modules: Sequence[ModuleRef],
        health: HealthRegistry,
        *,
        compressed: bool = True,
        check: Callable[[bool, frozenset[int]], object] | None = None,
    ) -> None:
        self.modules = list(modules)
        self.check = check  # raises LayoutError when the image would not fit that setting
        self.health = health
        self.compressed = compressed  # what the image is built with now
        self.inactive_mask = 0
        self.next_compressed = compressed  # written; applied at the next reset node
        self.next_inactive_mask = 0
        self.on_change: Callable[[], None] | None = None
        self.field_power_missing = False  # the front's field_power input says so

    # -- configuration ------------------------------------------------------------------
    @property
    def pending(self) -> bool:
        return (self.next_compressed, self.next_inactive_mask) != (
            self.compressed,
            self.inactive_mask,
        )

    def apply(self) -> None:
        """Reset node: the written settings take effect."""
        self.compressed, self.inactive_mask = self.next_compressed, self.next_inactive_mask

    @property
    def inactive(self) -> frozenset[int]:
        return slots_of(self.inactive_mask)

    def _fits(self, compressed: bool, mask: int) -> None:
        if self.check is None:
            return
        try:
            self.check(compressed, slots_of(mask))
        except LayoutError as exc:
            raise Abort(INTERNAL_INCOMPATIBILITY, str(exc)) from None

    def write_mode(self, value: int) -> None:
        if value > 1:
            raise Abort(VALUE_RANGE, "data mode 0 (non-compressed) or 1 (compressed)")
        self._fits(bool(value), self.next_inactive_mask)
        self.next_compressed = bool(value)
        self._changed()

    def write_inactive(self, value: int) -> None:
        if value >> len(self.modules):
            raise Abort(
                VALUE_RANGE,
                f"slot active flags: this head has {len(self.modules)} slots (bits 0..{len(self.modules) - 1})",
            )
        self._fits(self.next_compressed, value)
        self.next_inactive_mask = value
        self._changed()

    def settings(self) -> dict[str, int]:
        """What a 0x1010 save keeps (the written values)."""
        return {"mode": int(self.next_compressed), "inactive": self.next_inactive_mask}

    def load(self, stored: object) -> None:
        """Stored settings (power-on): written and in effect at the following reset."""
        if not isinstance(stored, dict):
            return
        mode, inactive = stored.get("mode"), stored.get("inactive")
        if mode in (0, 1) and isinstance(inactive, int) and not inactive >> len(self.modules):
            try:
                self._fits(bool(mode), inactive)
            except Abort:
                return
            self.next_compressed, self.next_inactive_mask = bool(mode), inactive

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    # -- status -------------------------------------------------------------------------
    def status(self) -> int:
        power = FIELD_POWER_MISSING << 24 if self.field_power_missing else 0
        for n, module in enumerate(self.modules, 1):
            if n in self.inactive:
                continue
            try:
                online = self.health.get(module.back, module.address).online
            except KeyError:
                continue
            if not online:
                return MODULE_OFFLINE | n << 8 | power
        return power

    def objects(self) -> list[ObjectDef]:
        return [
            array(
                PRODUCT_CODES,
                "Expansion module product code",
                (
                    Entry(n, f"Slot product code {n}", UNSIGNED32, "ro", const(code), default=code)
                    for n, code in enumerate(map(product_code, self.modules), 1)
                ),
            ),
            ObjectDef(
                FNBUS,
                "FnBus communication register",
                "record",
                [
                    count_entry(3),
                    Entry(1, "FnBus status", UNSIGNED32, "ro", self.status, default=0),
                    Entry(
                        2,
                        "FnBus data mode",
                        UNSIGNED8,
                        "rw",
                        lambda: int(self.next_compressed),
                        self.write_mode,
                        default=int(self.compressed),
                        high=1,
                    ),
                    Entry(
                        3,
                        "Expansion I/O active flag",
                        UNSIGNED32,
                        "rw",
                        lambda: self.next_inactive_mask,
                        self.write_inactive,
                        default=0,
                    ),
                ],
            ),
        ]


def slots_of(mask: int) -> frozenset[int]:
    """Slot numbers (1-based) whose bit is set in a 0x4500:3 value."""
    return frozenset(n for n in range(1, MAX_SLOTS + 1) if mask >> (n - 1) & 1)


def size_code(bits: int, words: int, raw_bytes: int) -> int:
    """Byte 0/1 of a product code for one direction (seed-004 §2.5)."""
    if bits:
        return (bits // 8 - 1) if bits % 8 == 0 else 0x80 | (bits - 1)
    if words:
        return 0x40 | (words - 1)
    if raw_bytes:
        return raw_bytes - 1
    return NO_DATA


def product_code(m: ModuleRef) -> int:
    """The slot's 0x4503 value: bytes 0..3 on the wire = in, out, class, family."""
    has_in, has_out = bool(m.di or m.ai or m.si), bool(m.do or m.ao or m.so)
    flags = (
        (0x40 if has_in else 0)
        | (0x80 if has_out else 0)
        | (0x20 if m.ai or m.ao else 0)
        | (0x10 if m.si or m.so else 0)
    )
    family = 0x01 if not (m.ai or m.ao or m.si or m.so) else 0x03
    wire = bytes(
        [
            min(0xFF, size_code(m.di, m.ai, m.si)),
            min(0xFF, size_code(m.do, m.ao, m.so)),
            flags,
            family,
        ]
    )
    return int.from_bytes(wire, "little")
