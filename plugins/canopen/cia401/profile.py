"""CiA 401 generic I/O objects bound to the process image.

The process image is the one source of truth: 0x6000/0x6401 read input channels,
0x6200/0x6411 write output channels, and the error-mode objects 0x6206/0x6207 (DO) and
0x6443/0x6444 (AO) read and write each output channel's :class:`~fieldgate.image.ErrorMode`
(``image.set_error_mode``), which ``context.masters.lost(...)`` applies.

| Object | Meaning | Per |
|---|---|---|
| 0x6000 | read DI, 8 channels per byte (after 0x6002 polarity) | DI byte |
| 0x6002 | DI polarity, 1 = inverted | DI byte |
| 0x6200 | write DO, 8 channels per byte, only bits set in 0x6208 pass | DO byte |
| 0x6206 / 0x6207 | DO error mode (1 = go to the error value) / error value | DO byte |
| 0x6208 | DO filter mask (1 = the written bit is taken over) | DO byte |
| 0x6401 | read AI, INTEGER16 | AI channel |
| 0x6411 | write AO, INTEGER16 | AO channel |
| 0x6421 | AI interrupt trigger (bit 0 above upper limit, 1 below lower limit, 2 delta) | AI channel |
| 0x6422 | AI interrupt source, one bit per channel, cleared when read | 32 AI channels |
| 0x6423 | AI global interrupt enable (default FALSE: analog changes fire no TPDO) | - |
| 0x6424 / 0x6425 | AI upper / lower limit (INTEGER32) | AI channel |
| 0x6426 | AI delta (UNSIGNED32) | AI channel |
| 0x6443 / 0x6444 | AO error mode (1 = error value) / error value (INTEGER32) | AO channel |
| 0x6020-0x6027 | read DI bit, BOOLEAN, 128 per object (``bit_objects``) | DI bit |
| 0x6220-0x6227 | write DO bit, BOOLEAN, 128 per object (``bit_objects``) | DO bit |
| 0x3000 / 0x3200 | special input / output byte (NA-9161), UNSIGNED8 | byte |

Bit sub-index n is bit (n-1) % 8 of 0x6000/0x6200 sub (n-1) // 8 + 1 (padding bits read
0 and ignore writes); the bit objects let a master map single channels (1-bit entries).

Events: a change of a DI value fires ``engine.object_changed(0x6000, byte)`` (and the bit
object's entry when served); with 0x6423 TRUE an AI change that meets its 0x6421
trigger fires ``(0x6401, channel)`` (``analog_events="interrupt"``, the ICP DAS style); with
``analog_events="change"`` (the NA-9161, which has no 0x6421-0x6426: they are not served)
every AI change fires it; a special input byte fires ``(0x3000, byte)``. One
process-image batch (a poll reply) fires each object once, however many of its channels
changed.

Output writes made inside :meth:`Profile401.batch` (the PDO engine writes an RPDO, or the
RPDOs of one SYNC, in one) are collected and written to the image as one batch when it
ends; outside it (an SDO download) each object write is its own batch.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from fieldgate.image import (
    Change,
    Channel,
    DataType,
    ErrorMode,
    ProcessImage,
    Subscription,
    Value,
)
from fieldgate.layout import byte_value

from ..cia301.abort import VALUE_RANGE
from ..cia301.entries import (
    BOOLEAN,
    INTEGER16,
    INTEGER32,
    UNSIGNED8,
    UNSIGNED32,
    Abort,
    Entry,
    ObjectDef,
    array,
)
from .layouts import (
    AI_OBJECT,
    AO_OBJECT,
    DI_OBJECT,
    DO_OBJECT,
    SI_OBJECT,
    SO_OBJECT,
    IoLayout,
    LayoutError,
)

DI_POLARITY, DO_ERROR_MODE, DO_ERROR_VALUE, DO_FILTER = 0x6002, 0x6206, 0x6207, 0x6208
AI_TRIGGER, AI_SOURCE, AI_ENABLE, AI_UPPER, AI_LOWER, AI_DELTA = (
    0x6421,
    0x6422,
    0x6423,
    0x6424,
    0x6425,
    0x6426,
)
AO_ERROR_MODE, AO_ERROR_VALUE = 0x6443, 0x6444
TRIGGER_UPPER, TRIGGER_LOWER, TRIGGER_DELTA = 0x01, 0x02, 0x04
DI_BIT_OBJECT, DO_BIT_OBJECT, BITS_PER_OBJECT, BIT_OBJECTS = 0x6020, 0x6220, 128, 8


def _u16_to_u8(data: bytes) -> bytes:
    """A 2-byte write to 0x6443 (the ICP DAS manuals print it UNSIGNED16; CiA 401: UNSIGNED8)."""
    if data[1]:
        raise Abort(VALUE_RANGE, "0x6443: 0 = keep the value, 1 = go to the error value")
    return data[:1]


def _i16_to_i32(data: bytes) -> bytes:
    """A 2-byte write to 0x6444 (printed U16 by the ICP DAS and NA-9161 manuals; CiA 401:
    INTEGER32): the 16-bit raw value, sign-extended as 0x6411's INTEGER16 is."""
    return int.from_bytes(data, "little", signed=True).to_bytes(4, "little", signed=True)


SHORT_WRITES = {0x6443: _u16_to_u8, 0x6444: _i16_to_i32}  # 2-byte downloads a style may take


def bit_position(n: int) -> tuple[int, int, int]:
    """Digital channel n (0-based) -> (bit object offset, its sub-index, 8-bit byte index)."""
    return n // BITS_PER_OBJECT, n % BITS_PER_OBJECT + 1, n // 8


def to_int16(channel: Channel, value: bool | int | float | None = None) -> int:
    """A channel's value as the INTEGER16 CiA 401 shows (raw bits of a UINT16, clamped otherwise)."""
    v = channel.value if value is None else value
    if channel.spec.data_type is DataType.UINT16 and isinstance(v, int) and v > 0x7FFF:
        return v - 0x10000
    if isinstance(v, float) and not math.isfinite(v):
        return 0x7FFF if v == math.inf else (-0x8000 if v == -math.inf else 0)
    v = int(round(v))
    return max(-0x8000, min(0x7FFF, v))


def from_int16(channel: Channel, value: int) -> bool | int | float:
    """An INTEGER16 written to an analog output, in the channel's own data type."""
    dtype = channel.spec.data_type
    if dtype is DataType.UINT16:
        return value & 0xFFFF
    if dtype is DataType.UINT32 and value < 0:
        raise Abort(VALUE_RANGE, f"{channel.id} takes no negative values")
    if dtype is DataType.FLOAT32:
        return float(value)
    if dtype is DataType.BOOL:
        raise Abort(VALUE_RANGE, f"{channel.id} is boolean")
    return value


def _uses_error_value(channel: Channel) -> bool:
    return channel.error_mode.use_value


def _uses_error_value_int(channel: Channel) -> int:
    return int(channel.error_mode.use_value)


def _error_value_bit(channel: Channel) -> bool:
    return bool(channel.error_mode.value)


def _bits(slots: list[Channel | None], pick: Callable[[Channel], bool]) -> int:
    return sum(1 << i for i, ch in enumerate(slots) if ch is not None and pick(ch))


class Profile401:
    """The CiA 401 objects of one front, over ``image``; ``origin`` labels its output writes."""

    def __init__(
        self,
        image: ProcessImage,
        layout: IoLayout,
        origin: str,
        *,
        filter_default: int = 0xFF,
        trigger_default: int = 0x07,
        bit_objects: bool = False,
        analog_events: str = "interrupt",
    ):
        self.image = image
        self.layout = layout
        self.origin = origin
        self.bit_objects = bit_objects
        # "change": every AI change is an event, no 0x6421-0x6426 (the NA-9161 has none);
        # "interrupt": only through 0x6423 and 0x6421 (CiA 401; default FALSE, the I-7232D's
        # "analog changes do not trigger a TPDO")
        self.analog_events = analog_events
        if bit_objects and 8 * max(len(layout.di_bytes), len(layout.do_bytes)) > (
            BITS_PER_OBJECT * BIT_OBJECTS
        ):
            raise LayoutError(
                f"bit_mapping: the bit objects hold at most {BITS_PER_OBJECT * BIT_OBJECTS} digital channels per direction"
            )
        n_di, n_do, n_ai = len(layout.di_bytes), len(layout.do_bytes), len(layout.ai)
        self.polarity = [0] * n_di
        self.filter = [filter_default] * n_do
        self.trigger = [trigger_default] * n_ai
        self.upper = [0] * n_ai
        self.lower = [0] * n_ai
        self.delta = [0] * n_ai
        self.interrupt_enable = False
        self.interrupt_source = [0] * ((n_ai + 31) // 32)
        self._last_reported = [0] * n_ai
        self._di_sub = {
            ch.id: n + 1
            for n, slots in enumerate(layout.di_bytes)
            for ch in slots
            if ch is not None
        }
        self._di_bit = {
            ch.id: 8 * n + bit
            for n, slots in enumerate(layout.di_bytes)
            for bit, ch in enumerate(slots)
            if ch is not None
        }
        # what a DI change fires: its byte of 0x6000, and its bit object's entry when served
        self._di_events: dict[str, dict[tuple[int, int], None]] = {}
        for cid, sub in self._di_sub.items():
            events = {(DI_OBJECT, sub): None}
            if bit_objects:
                offset, bit_sub, _ = bit_position(self._di_bit[cid])
                events[(DI_BIT_OBJECT + offset, bit_sub)] = None
            self._di_events[cid] = events
        self._si_sub = {ch.id: n + 1 for n, ch in enumerate(layout.si)}
        self._ai_number = {ch.id: n + 1 for n, ch in enumerate(layout.ai)}
        self._do_bits = [
            [(bit, ch.id) for bit, ch in enumerate(slots) if ch is not None]
            for slots in layout.do_bytes
        ]
        self._subscriptions: list[Subscription] = []
        self._event: Callable[[int, int, float], None] | None = None
        self._staged: dict[str, Value] | None = None  # output writes of the open batch
        self._batch = _OutputBatch(self)

    # -- output batches ---------------------------------------------------------------
    def batch(self) -> _OutputBatch:
        """A context: the output writes made inside it reach the image as one batch."""
        return self._batch

    def _write(self, values: dict[str, Value]) -> None:
        if self._staged is not None:
            self._staged.update(values)
        elif values:
            self.image.write_outputs(values, self.origin)

    # -- events ---------------------------------------------------------------------
    def attach(self, event: Callable[[int, int, float], None]) -> None:
        """Start reporting application events as ``event(index, sub, now)``."""
        self.detach()
        self._event = event
        self._last_reported = [to_int16(ch) for ch in self.layout.ai]
        inputs = [*self._di_sub, *self._ai_number, *self._si_sub]
        if inputs:
            self._subscriptions.append(self.image.subscribe_batch(self._inputs_changed, ids=inputs))

    def detach(self) -> None:
        for sub in self._subscriptions:
            sub.cancel()
        self._subscriptions = []
        self._event = None

    def _inputs_changed(self, changes: list[Change]) -> None:
        """One batch of input changes: each object that changed fires one event."""
        event = self._event
        if event is None:
            return
        fired: dict[tuple[int, int], None] = {}
        di_events = self._di_events
        for change in changes:
            if change.old_value == change.value:  # a quality change alone fires nothing
                continue
            cid = change.id
            objects = di_events.get(cid)
            if objects is not None:
                fired.update(objects)
            elif cid in self._si_sub:
                fired[(SI_OBJECT, self._si_sub[cid])] = None
            elif self._ai_fires(change):
                fired[(AI_OBJECT, self._ai_number[cid])] = None
        if fired:
            now = self.image.clock()
            for index, sub in fired:
                event(index, sub, now)

    def _ai_fires(self, change: Change) -> bool:
        """``analog_events`` "change": every change; "interrupt": 0x6423 on and the new value
        meets the channel's 0x6421 trigger (then it is reported)."""
        if self.analog_events == "change":
            return True
        if not self.interrupt_enable:
            return False
        n = self._ai_number[change.id]
        value = to_int16(change.channel, change.value)
        trigger = self.trigger[n - 1]
        fire = (
            (trigger & TRIGGER_UPPER and value > self.upper[n - 1])
            or (trigger & TRIGGER_LOWER and value < self.lower[n - 1])
            or (
                trigger & TRIGGER_DELTA
                and abs(value - self._last_reported[n - 1]) > self.delta[n - 1]
            )
        )
        if fire:
            self._last_reported[n - 1] = value
            self.interrupt_source[(n - 1) // 32] |= 1 << ((n - 1) % 32)
        return bool(fire)

    # -- digital ----------------------------------------------------------------------
    def read_di(self, n: int) -> int:
        return byte_value(self.layout.di_bytes[n]) ^ self.polarity[n]

    def read_do(self, n: int) -> int:
        return byte_value(self.layout.do_bytes[n])

    def write_do(self, n: int, value: int) -> None:
        mask = self.filter[n]
        self._write(
            {cid: bool(value >> bit & 1) for bit, cid in self._do_bits[n] if mask >> bit & 1}
        )

    def read_di_bit(self, n: int) -> int:
        return self.read_di(n // 8) >> n % 8 & 1

    def read_do_bit(self, n: int) -> int:
        return self.read_do(n // 8) >> n % 8 & 1

    def write_do_bit(self, n: int, value: int) -> None:
        ch = self.layout.do_bytes[n // 8][n % 8]
        if ch is not None and self.filter[n // 8] >> n % 8 & 1:
            self._write({ch.id: bool(value)})

    # -- special bytes ----------------------------------------------------------------
    @staticmethod
    def _special_byte(channels: Sequence[Channel], n: int) -> int:
        return int(channels[n].value)

    def write_so(self, n: int, value: int) -> None:
        self._write({self.layout.so[n].id: value})

    def _write_do_error(self, n: int, value: int, *, mode: bool) -> None:
        for bit, ch in enumerate(self.layout.do_bytes[n]):
            if ch is None:
                continue
            current = ch.error_mode
            flag = bool(value >> bit & 1)
            new = ErrorMode(flag, current.value) if mode else ErrorMode(current.use_value, flag)
            self.image.set_error_mode(ch.id, new)

    # -- analog -----------------------------------------------------------------------
    def write_ao(self, n: int, value: int) -> None:
        ch = self.layout.ao[n]
        self._write({ch.id: from_int16(ch, value)})

    def _write_ao_mode(self, n: int, value: int) -> None:
        if value > 1:
            raise Abort(VALUE_RANGE, "0 = keep the value, 1 = go to the error value")
        ch = self.layout.ao[n]
        self.image.set_error_mode(ch.id, ErrorMode(bool(value), ch.error_mode.value))

    def _write_ao_error_value(self, n: int, value: int) -> None:
        ch = self.layout.ao[n]
        converted = (
            from_int16(ch, value)
            if ch.spec.data_type in (DataType.UINT16, DataType.FLOAT32)
            else value
        )
        try:
            self.image.set_error_mode(ch.id, ErrorMode(ch.error_mode.use_value, converted))
        except ValueError as exc:
            raise Abort(VALUE_RANGE, str(exc)) from None

    def _ao_error_value(self, n: int) -> int:
        ch = self.layout.ao[n]
        v = ch.error_mode.value
        if ch.spec.data_type is DataType.UINT16:
            return to_int16(ch, v)
        return int(round(v))

    def _set_enable(self, value: int) -> None:
        if value and not self.interrupt_enable:
            self._last_reported = [to_int16(ch) for ch in self.layout.ai]
        self.interrupt_enable = bool(value)

    def _read_source(self, bank: int) -> int:
        value, self.interrupt_source[bank] = self.interrupt_source[bank], 0
        return value

    # -- objects ----------------------------------------------------------------------
    def objects(self) -> list[ObjectDef]:
        lay = self.layout
        di, do, ai, ao = (
            range(len(lay.di_bytes)),
            range(len(lay.do_bytes)),
            range(len(lay.ai)),
            range(len(lay.ao)),
        )

        def setter(values: list[int], n: int) -> Callable[[int], None]:
            return lambda v: values.__setitem__(n, v)

        objs: list[ObjectDef] = []
        if lay.di_bytes:
            objs += [
                array(
                    DI_OBJECT,
                    "Read input 8-bit",
                    (
                        Entry(
                            n + 1,
                            f"Read input 8-bit {n + 1}",
                            UNSIGNED8,
                            "ro",
                            partial(self.read_di, n),
                            default=0,
                            mappable=True,
                        )
                        for n in di
                    ),
                ),
                array(
                    DI_POLARITY,
                    "Polarity input 8-bit",
                    (
                        Entry(
                            n + 1,
                            f"Polarity input 8-bit {n + 1}",
                            UNSIGNED8,
                            "rw",
                            partial(self.polarity.__getitem__, n),
                            setter(self.polarity, n),
                            default=0,
                        )
                        for n in di
                    ),
                ),
            ]
        if lay.do_bytes:
            objs += [
                array(
                    DO_OBJECT,
                    "Write output 8-bit",
                    (
                        Entry(
                            n + 1,
                            f"Write output 8-bit {n + 1}",
                            UNSIGNED8,
                            "rw",
                            partial(self.read_do, n),
                            partial(self.write_do, n),
                            default=self.read_do(n),
                            mappable=True,
                        )
                        for n in do
                    ),
                ),
                array(
                    DO_ERROR_MODE,
                    "Error mode output 8-bit",
                    (
                        Entry(
                            n + 1,
                            f"Error mode output 8-bit {n + 1}",
                            UNSIGNED8,
                            "rw",
                            partial(_bits, lay.do_bytes[n], _uses_error_value),
                            partial(self._write_do_error, n, mode=True),
                            default=_bits(lay.do_bytes[n], lambda c: c.error_mode.use_value),
                        )
                        for n in do
                    ),
                ),
                array(
                    DO_ERROR_VALUE,
                    "Error value output 8-bit",
                    (
                        Entry(
                            n + 1,
                            f"Error value output 8-bit {n + 1}",
                            UNSIGNED8,
                            "rw",
                            partial(_bits, lay.do_bytes[n], _error_value_bit),
                            partial(self._write_do_error, n, mode=False),
                            default=_bits(lay.do_bytes[n], lambda c: bool(c.error_mode.value)),
                        )
                        for n in do
                    ),
                ),
                array(
                    DO_FILTER,
                    "Filter mask output 8-bit",
                    (
                        Entry(
                            n + 1,
                            f"Filter mask output 8-bit {n + 1}",
                            UNSIGNED8,
                            "rw",
                            partial(self.filter.__getitem__, n),
                            setter(self.filter, n),
                            default=self.filter[n],
                        )
                        for n in do
                    ),
                ),
            ]
        if lay.ai:
            objs += [
                array(
                    AI_OBJECT,
                    "Read analog input 16-bit",
                    (
                        Entry(
                            n + 1,
                            f"Read analog input {n + 1}",
                            INTEGER16,
                            "ro",
                            partial(to_int16, lay.ai[n]),
                            default=0,
                            mappable=True,
                        )
                        for n in ai
                    ),
                ),
            ]
        if lay.ai and self.analog_events == "interrupt":
            objs += [
                array(
                    AI_TRIGGER,
                    "Analog input interrupt trigger selection",
                    (
                        Entry(
                            n + 1,
                            f"Trigger selection {n + 1}",
                            UNSIGNED8,
                            "rw",
                            partial(self.trigger.__getitem__, n),
                            setter(self.trigger, n),
                            default=self.trigger[n],
                            high=0x07,
                        )
                        for n in ai
                    ),
                ),
                array(
                    AI_SOURCE,
                    "Analog input interrupt source",
                    (
                        Entry(
                            b + 1,
                            f"Interrupt source bank {b + 1}",
                            UNSIGNED32,
                            "ro",
                            partial(self._read_source, b),
                            default=0,
                        )
                        for b in range(len(self.interrupt_source))
                    ),
                ),
                ObjectDef(
                    AI_ENABLE,
                    "Analog input global interrupt enable",
                    "var",
                    [
                        Entry(
                            0,
                            "Analog input global interrupt enable",
                            BOOLEAN,
                            "rw",
                            lambda: int(self.interrupt_enable),
                            self._set_enable,
                            default=0,
                        )
                    ],
                ),
                array(
                    AI_UPPER,
                    "Analog input interrupt upper limit",
                    (
                        Entry(
                            n + 1,
                            f"Upper limit {n + 1}",
                            INTEGER32,
                            "rw",
                            partial(self.upper.__getitem__, n),
                            setter(self.upper, n),
                            default=0,
                        )
                        for n in ai
                    ),
                ),
                array(
                    AI_LOWER,
                    "Analog input interrupt lower limit",
                    (
                        Entry(
                            n + 1,
                            f"Lower limit {n + 1}",
                            INTEGER32,
                            "rw",
                            partial(self.lower.__getitem__, n),
                            setter(self.lower, n),
                            default=0,
                        )
                        for n in ai
                    ),
                ),
                array(
                    AI_DELTA,
                    "Analog input interrupt delta",
                    (
                        Entry(
                            n + 1,
                            f"Delta {n + 1}",
                            UNSIGNED32,
                            "rw",
                            partial(self.delta.__getitem__, n),
                            setter(self.delta, n),
                            default=0,
                        )
                        for n in ai
                    ),
                ),
            ]
        if lay.ao:
            objs += [
                array(
                    AO_OBJECT,
                    "Write analog output 16-bit",
                    (
                        Entry(
                            n + 1,
                            f"Write analog output {n + 1}",
                            INTEGER16,
                            "rw",
                            partial(to_int16, lay.ao[n]),
                            partial(self.write_ao, n),
                            default=to_int16(lay.ao[n]),
                            mappable=True,
                        )
                        for n in ao
                    ),
                ),
                array(
                    AO_ERROR_MODE,
                    "Analog output error mode",
                    (
                        Entry(
                            n + 1,
                            f"Error mode {n + 1}",
                            UNSIGNED8,
                            "rw",
                            partial(_uses_error_value_int, lay.ao[n]),
                            partial(self._write_ao_mode, n),
                            default=int(lay.ao[n].error_mode.use_value),
                        )
                        for n in ao
                    ),
                ),
                array(
                    AO_ERROR_VALUE,
                    "Analog output error value",
                    (
                        Entry(
                            n + 1,
                            f"Error value {n + 1}",
                            INTEGER32,
                            "rw",
                            partial(self._ao_error_value, n),
                            partial(self._write_ao_error_value, n),
                            default=self._ao_error_value(n),
                        )
                        for n in ao
                    ),
                ),
            ]
        if self.bit_objects:
            objs += self._bit_objects()
        objs += self._special_objects()
        return objs

    def _bit_objects(self) -> list[ObjectDef]:
        objs: list[ObjectDef] = []
        for base, n_bits, verb, access in (
            (DI_BIT_OBJECT, 8 * len(self.layout.di_bytes), "Read input", "ro"),
            (DO_BIT_OBJECT, 8 * len(self.layout.do_bytes), "Write output", "rw"),
        ):
            for offset in range((n_bits + BITS_PER_OBJECT - 1) // BITS_PER_OBJECT):
                first = offset * BITS_PER_OBJECT
                last = min(n_bits, first + BITS_PER_OBJECT)
                objs.append(
                    array(
                        base + offset,
                        f"{verb} bit {first + 1} to {first + BITS_PER_OBJECT}",
                        (
                            Entry(
                                n - first + 1,
                                f"{verb} bit {n + 1}",
                                BOOLEAN,
                                access,
                                partial(self.read_di_bit, n)
                                if access == "ro"
                                else partial(self.read_do_bit, n),
                                partial(self.write_do_bit, n) if access == "rw" else None,
                                default=0 if access == "ro" else self.read_do_bit(n),
                                mappable=True,
                            )
                            for n in range(first, last)
                        ),
                    )
                )
        return objs

    def _special_objects(self) -> list[ObjectDef]:
        lay = self.layout
        objs: list[ObjectDef] = []
        if lay.si:
            objs.append(
                array(
                    SI_OBJECT,
                    "Read special input data",
                    (
                        Entry(
                            n + 1,
                            f"Special input byte {n}",
                            UNSIGNED8,
                            "ro",
                            partial(self._special_byte, lay.si, n),
                            default=0,
                            mappable=True,
                        )
                        for n in range(len(lay.si))
                    ),
                )
            )
        if lay.so:
            objs.append(
                array(
                    SO_OBJECT,
                    "Write special output data",
                    (
                        Entry(
                            n + 1,
                            f"Special output byte {n}",
                            UNSIGNED8,
                            "rw",
                            partial(self._special_byte, lay.so, n),
                            partial(self.write_so, n),
                            default=int(lay.so[n].value),
                            mappable=True,
                        )
                        for n in range(len(lay.so))
                    ),
                )
            )
        return objs

    def output_ids(self) -> list[str]:
        return (
            [ch.id for slots in self.layout.do_bytes for ch in slots if ch is not None]
            + [ch.id for ch in self.layout.ao]
            + [ch.id for ch in self.layout.so]
        )


class _OutputBatch:
    """:meth:`Profile401.batch`: collects output writes, writes them as one batch at the end
    of the outermost one (the RPDOs of a SYNC hold the batches of each RPDO)."""

    def __init__(self, profile: Profile401):
        self.profile = profile
        self.depth = 0

    def __enter__(self) -> None:
        if self.depth == 0:
            self.profile._staged = {}
        self.depth += 1

    def __exit__(self, *exc: Any) -> None:
        self.depth -= 1
        if self.depth == 0:
            staged, self.profile._staged = self.profile._staged, None
            if staged:
                self.profile.image.write_outputs(staged, self.profile.origin)
