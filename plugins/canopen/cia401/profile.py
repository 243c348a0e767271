"""CiA 401 generic I/O over the process image: the channel state and its read/write functions.

The process image is the one source of truth: 0x6000/0x6401 read input channels,
0x6200/0x6411 write output channels, and the error-mode objects 0x6206/0x6207 (DO) and
0x6443/0x6444 (AO) read and write each output channel's :class:`~fieldgate.image.ErrorMode`
(``image.set_error_mode``), which ``context.masters.lost(...)`` applies. Which object
serves which function is a table (:mod:`.objects`); the analog interrupt settings and
their rule are :mod:`.analog`'s, output batches :mod:`.batching`'s.

| Object | Meaning | Per |
|---|---|---|
| 0x6000 | read DI, 8 channels per byte (after 0x6002 polarity) | DI byte |
| 0x6002 | DI polarity, 1 = inverted | DI byte |
| 0x6200 | write DO, 8 channels per byte, only bits set in 0x6208 pass | DO byte |
| 0x6206 / 0x6207 | DO error mode (1 = go to the error value) / error value | DO byte |
| 0x6208 | DO filter mask (1 = the written bit is taken over) | DO byte |
| 0x6401 | read AI, INTEGER16 | AI channel |
| 0x6411 | write AO, INTEGER16 | AO channel |
| 0x6421-0x6426 | AI interrupt trigger, source, enable, limits, delta (:mod:`.analog`) | AI channel |
| 0x6443 / 0x6444 | AO error mode (1 = error value) / error value (INTEGER32) | AO channel |
| 0x6020-0x6027 | read DI bit, BOOLEAN, 128 per object (``bit_objects``) | DI bit |
| 0x6220-0x6227 | write DO bit, BOOLEAN, 128 per object (``bit_objects``) | DO bit |
| 0x3000 / 0x3200 | special input / output byte (NA-9161, :mod:`..na9161.special`) | byte |

Bit sub-index n is bit (n-1) % 8 of 0x6000/0x6200 sub (n-1) // 8 + 1 (padding bits read
0 and ignore writes); the bit objects let a master map single channels (1-bit entries).

Events: a change of a DI value fires ``event(0x6000, byte)`` (and the bit object's entry
when served; the PDO service queues the TPDOs that map it); an AI change fires
``(0x6401, channel)`` when :class:`~.analog.AnalogInterrupts` says so; the inputs given as
``extra_events`` (the NA-9161's special bytes) fire theirs. One process-image batch (a
poll reply) fires each object once, however many of its channels changed.
"""

from __future__ import annotations

from collections.abc import Callable, Sized

from fieldgate.image import Change, Channel, DataType, ErrorMode, ProcessImage, Subscription
from fieldgate.layout import byte_value

from ..cia301.abort import VALUE_RANGE
from ..cia301.entries import Abort
from .analog import AnalogInterrupts
from .batching import OutputWrites
from .layouts import AI_OBJECT, DI_OBJECT, IoLayout, LayoutError
from .values import from_int16, to_int16

DI_BIT_OBJECT, DO_BIT_OBJECT, BITS_PER_OBJECT, BIT_OBJECTS = 0x6020, 0x6220, 128, 8
Events = dict[tuple[int, int], None]  # (index, sub) an input change fires, in order


def bit_position(n: int) -> tuple[int, int, int]:
    """Digital channel n (0-based) -> (bit object offset, its sub-index, 8-bit byte index)."""
    return n // BITS_PER_OBJECT, n % BITS_PER_OBJECT + 1, n // 8


def _bits(slots: list[Channel | None], pick: Callable[[Channel], bool]) -> int:
    return sum(1 << i for i, ch in enumerate(slots) if ch is not None and pick(ch))


class Profile401:
    """The CiA 401 channel state of one front, over ``image``; ``origin`` labels its output writes."""

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
        extra_events: dict[str, Events] | None = None,
    ):
        self.image = image
        self.layout = layout
        self.bit_objects = bit_objects
        if bit_objects and 8 * max(len(layout.di_bytes), len(layout.do_bytes)) > (
            BITS_PER_OBJECT * BIT_OBJECTS
        ):
            raise LayoutError(
                f"bit_mapping: the bit objects hold at most {BITS_PER_OBJECT * BIT_OBJECTS} digital channels per direction"
            )
        self.outputs = OutputWrites(image, origin)
        self.analog = AnalogInterrupts(layout.ai, analog_events, trigger_default=trigger_default)
        self.polarity = [0] * len(layout.di_bytes)
        self.filter = [filter_default] * len(layout.do_bytes)
        self._events = self._input_events(layout, bit_objects, extra_events or {})
        self._do_bits = [
            [(bit, ch.id) for bit, ch in enumerate(slots) if ch is not None]
            for slots in layout.do_bytes
        ]
        self._subscriptions: list[Subscription] = []
        self._event: Callable[[int, int, float], None] | None = None

    @staticmethod
    def _input_events(layout: IoLayout, bits: bool, extra: dict[str, Events]) -> dict[str, Events]:
        """What a DI change fires: its byte of 0x6000, and its bit object's entry when served."""
        events: dict[str, Events] = {}
        for n, slots in enumerate(layout.di_bytes):
            for bit, ch in enumerate(slots):
                if ch is None:
                    continue
                fired: Events = {(DI_OBJECT, n + 1): None}
                if bits:
                    offset, bit_sub, _ = bit_position(8 * n + bit)
                    fired[(DI_BIT_OBJECT + offset, bit_sub)] = None
                events[ch.id] = fired
        return {**events, **extra}

    def items(self, over: str) -> range:
        """The positions an object table row of :mod:`.objects` serves."""
        lay = self.layout
        sizes: dict[str, Sized] = {
            "di": lay.di_bytes,
            "do": lay.do_bytes,
            "ai": lay.ai,
            "ao": lay.ao,
        }
        return range(len(sizes[over]))

    # -- events ---------------------------------------------------------------------
    def attach(self, event: Callable[[int, int, float], None]) -> None:
        """Start reporting application events as ``event(index, sub, now)``."""
        self.detach()
        self._event = event
        self.analog.restart()
        inputs = [*self._events, *self.analog.number]
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
        fired: Events = {}
        events, analog = self._events, self.analog
        for change in changes:
            if change.old_value == change.value:  # a quality change alone fires nothing
                continue
            objects = events.get(change.id)
            if objects is not None:
                fired.update(objects)
            elif analog.fires(change):
                fired[(AI_OBJECT, analog.number[change.id])] = None
        if fired:
            now = self.image.clock()
            for index, sub in fired:
                event(index, sub, now)

    # -- digital ----------------------------------------------------------------------
    def read_di(self, n: int) -> int:
        return byte_value(self.layout.di_bytes[n]) ^ self.polarity[n]

    def read_do(self, n: int) -> int:
        return byte_value(self.layout.do_bytes[n])

    def write_do(self, n: int, value: int) -> None:
        mask = self.filter[n]
        self.outputs.write(
            {cid: bool(value >> bit & 1) for bit, cid in self._do_bits[n] if mask >> bit & 1}
        )

    def read_di_bit(self, n: int) -> int:
        return self.read_di(n // 8) >> n % 8 & 1

    def read_do_bit(self, n: int) -> int:
        return self.read_do(n // 8) >> n % 8 & 1

    def write_do_bit(self, n: int, value: int) -> None:
        ch = self.layout.do_bytes[n // 8][n % 8]
        if ch is not None and self.filter[n // 8] >> n % 8 & 1:
            self.outputs.write({ch.id: bool(value)})

    def do_error_modes(self, n: int) -> int:
        return _bits(self.layout.do_bytes[n], lambda c: c.error_mode.use_value)

    def do_error_values(self, n: int) -> int:
        return _bits(self.layout.do_bytes[n], lambda c: bool(c.error_mode.value))

    def write_do_error(self, n: int, value: int, *, mode: bool) -> None:
        for bit, ch in enumerate(self.layout.do_bytes[n]):
            if ch is None:
                continue
            current = ch.error_mode
            flag = bool(value >> bit & 1)
            new = ErrorMode(flag, current.value) if mode else ErrorMode(current.use_value, flag)
            self.image.set_error_mode(ch.id, new)

    # -- analog -----------------------------------------------------------------------
    def read_ai(self, n: int) -> int:
        return to_int16(self.layout.ai[n])

    def read_ao(self, n: int) -> int:
        return to_int16(self.layout.ao[n])

    def write_ao(self, n: int, value: int) -> None:
        ch = self.layout.ao[n]
        self.outputs.write({ch.id: from_int16(ch, value)})

    def ao_error_mode(self, n: int) -> int:
        return int(self.layout.ao[n].error_mode.use_value)

    def write_ao_error_mode(self, n: int, value: int) -> None:
        if value > 1:
            raise Abort(VALUE_RANGE, "0 = keep the value, 1 = go to the error value")
        ch = self.layout.ao[n]
        self.image.set_error_mode(ch.id, ErrorMode(bool(value), ch.error_mode.value))

    def ao_error_value(self, n: int) -> int:
        ch = self.layout.ao[n]
        v = ch.error_mode.value
        if ch.spec.data_type is DataType.UINT16:
            return to_int16(ch, v)
        return int(round(v))

    def write_ao_error_value(self, n: int, value: int) -> None:
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

    def output_ids(self) -> list[str]:
        return (
            [ch.id for slots in self.layout.do_bytes for ch in slots if ch is not None]
            + [ch.id for ch in self.layout.ao]
            + [ch.id for ch in self.layout.so]
        )
