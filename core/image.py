"""The protocol-neutral process image at the centre of every gateway.

Concurrency model
-----------------
fieldgate runs on **one asyncio event loop**. Every read and write of the process
image, every subscription callback and every protocol engine runs on that loop's
thread, so no locks are needed and none are taken. Code running in another thread
(for example a python-can Notifier thread) must hand its work to the loop with
``loop.call_soon_threadsafe`` before touching the image.

Subscription callbacks run synchronously inside the write that caused them, in the
same event-loop turn. They must be quick and must not block; a callback that raises
is logged and skipped, it never breaks the writer (a poller or a CAN engine).

Batches
-------
Every write call is one batch: ``update_inputs`` takes all the inputs of a poll reply,
``write_outputs`` all the outputs of an RPDO or a DeviceNet poll request. The image
checks them all, updates them, then calls each subscriber once: a ``subscribe_batch``
callback gets the list of changes it wants (each channel that changed, with its own
value, quality and timestamp), so an event-driven TPDO, a Sparkplug message or a
write-on-change wake-up is prepared once per message rather than once per bit.
``subscribe`` callbacks still get one call per change. The single-channel calls
(``update_input``, ``write_output``) are batches of one.

Direction of data
-----------------
* Inputs (DI, AI, SI) are written by backs (``update_inputs``) and read by fronts.
* Outputs (DO, AO, SO) are written by fronts (``write_outputs``) and read by backs.
* SI/SO channels are the bytes (UINT8) of a module's raw byte block, e.g. a high-speed
  counter's 6 input and 2 output bytes; fronts that know no such area leave them out.
* Analog channels hold integers of 16, 32 or 64 bits, floats of 32 or 64 bits, or text
  (STRING, at most ``ChannelSpec.length`` bytes in UTF-8). A front that cannot carry 64-bit
  values or strings leaves them out (``FrontConfig.carried_types``, :data:`NARROW_TYPES`).

Engineering units
-----------------
Two ways, one per channel:

* :class:`Engineering` (``ChannelSpec.engineering``): the back has converted the value
  already (``raw * gain + offset``, rounded to ``decimals``), once, where it was read; the
  image holds the engineering value and every front serves that. Its ``unit`` and range
  go with it (OPC UA EngineeringUnits and EURange, Sparkplug properties); an input outside
  the range has quality over-/under-range, an output write outside it is refused. A write
  goes back to the device through :meth:`Engineering.to_raw`. The Modbus backs do this.
* :class:`Scaling` (``ChannelSpec.scaling``), display only: the image holds the device's
  raw counts (a DCON module's hex scale, which a CANopen PLC expects) and fronts that show
  engineering values compute them beside the raw one (an OPC UA ``_eng`` twin, the live
  page, Sparkplug's rawLow/engLow properties).
Both sides subscribe to changes, so event-driven PDOs, DeviceNet change-of-state and
write-on-change polling need no busy loops.
"""

from __future__ import annotations

import asyncio
import fnmatch
import logging
import re
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, NoReturn

from .subscriptions import Subscribers
from .subscriptions import Subscription as Subscription  # (part of this module's API)

log = logging.getLogger("fieldgate.image")


class Kind(StrEnum):
    DI = "di"
    DO = "do"
    AI = "ai"
    AO = "ao"
    SI = "si"  # special input: one byte of a module's raw byte block (NA-9161 0x3000)
    SO = "so"  # special output: one byte of a module's raw byte block (NA-9161 0x3200)

    @property
    def is_output(self) -> bool:
        return self in (Kind.DO, Kind.AO, Kind.SO)

    @property
    def is_special(self) -> bool:
        """A byte of a raw block (a counter's data), neither a digital point nor an analog value."""
        return self in (Kind.SI, Kind.SO)

    @property
    def is_digital(self) -> bool:
        return self in (Kind.DI, Kind.DO)


class Quality(StrEnum):
    GOOD = "good"
    NOT_READ = "not-read"  # never read since start
    STALE = "stale"  # last read failed; the value is the last good one
    COMM_FAULT = "comm-fault"  # module offline, or its back end is not running
    OVER_RANGE = "over-range"  # module-reported, or above the channel's engineering range
    UNDER_RANGE = "under-range"  # module-reported, or below the channel's engineering range
    WATCHDOG = "watchdog"  # module sits in its host-watchdog safe state
    CONFIG_ERROR = "config-error"  # the module does not match its declaration


class DataType(StrEnum):
    BOOL = "bool"
    UINT8 = "uint8"  # the bytes of special blocks (Kind.SI / Kind.SO)
    INT16 = "int16"
    UINT16 = "uint16"
    INT32 = "int32"
    UINT32 = "uint32"
    FLOAT32 = "float32"
    INT64 = "int64"
    UINT64 = "uint64"
    FLOAT64 = "float64"
    STRING = "string"  # text, at most ChannelSpec.length bytes in UTF-8

    @property
    def is_float(self) -> bool:
        return self is DataType.FLOAT32 or self is DataType.FLOAT64

    @property
    def is_integer(self) -> bool:
        return self in _INT_RANGES

    def check(self, value: object) -> Value:
        """Return ``value`` converted to this type, or raise ValueError naming the range."""
        if self is DataType.BOOL:
            if isinstance(value, bool) or value in (0, 1):
                return bool(value)
            raise ValueError(f"expected a bool (0 or 1), got {value!r}")
        if self is DataType.FLOAT32 or self is DataType.FLOAT64:
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                return float(value)
            raise ValueError(f"expected a number, got {value!r}")
        if self is DataType.STRING:
            if isinstance(value, str):
                return value
            raise ValueError(f"expected text, got {value!r}")
        if not isinstance(value, int) or isinstance(value, bool):
            raise ValueError(f"expected an integer for {self.value}, got {value!r}")
        low, high = _INT_RANGES[self]
        if not low <= value <= high:
            raise ValueError(f"{value} is outside {self.value} range {low}..{high}")
        return value


def integer_range(dtype: DataType) -> tuple[int, int]:
    """(lowest, highest) value of an integer data type."""
    return _INT_RANGES[dtype]


_INT_RANGES = {
    DataType.UINT8: (0, 0xFF),
    DataType.INT16: (-0x8000, 0x7FFF),
    DataType.UINT16: (0, 0xFFFF),
    DataType.INT32: (-0x8000_0000, 0x7FFF_FFFF),
    DataType.UINT32: (0, 0xFFFF_FFFF),
    DataType.INT64: (-0x8000_0000_0000_0000, 0x7FFF_FFFF_FFFF_FFFF),
    DataType.UINT64: (0, 0xFFFF_FFFF_FFFF_FFFF),
}

NARROW_TYPES = frozenset(
    {
        DataType.BOOL,
        DataType.UINT8,
        DataType.INT16,
        DataType.UINT16,
        DataType.INT32,
        DataType.UINT32,
        DataType.FLOAT32,
    }
)
"""The types of at most 32 bits: what a front carries unless it says it carries more (the CAN
fronts' 16-bit analog words: ``FrontConfig.carried_types``). 64-bit values and strings are
left out of such a front's default order, and naming one in its ``expose`` is an error."""


@dataclass(frozen=True)
class ErrorMode:
    """What an output does when its master is lost (or on shutdown).

    ``use_value`` False means *hold* the last value; ``value`` is kept even then, so a
    CANopen master can write 0x6207/0x6444 before it enables 0x6206/0x6443.
    """

    use_value: bool = False
    value: bool | int | float = 0

    @classmethod
    def hold(cls, value: bool | int | float = 0) -> ErrorMode:
        return cls(False, value)

    @classmethod
    def to(cls, value: bool | int | float) -> ErrorMode:
        return cls(True, value)

    def describe(self) -> str:
        return f"value {self.value}" if self.use_value else "hold"


@dataclass(frozen=True)
class Source:
    """Where a channel lives: back-end name, module address, channel index in the module."""

    back: str
    module: int
    index: int


@dataclass(frozen=True)
class Scaling:
    """Display-only metadata mapping raw counts to engineering units."""

    raw_min: float
    raw_max: float
    eng_min: float
    eng_max: float
    unit: str = ""

    def to_engineering(self, raw: float) -> float:
        span = self.raw_max - self.raw_min
        return self.eng_min + (raw - self.raw_min) * (self.eng_max - self.eng_min) / span


@dataclass(frozen=True)
class Engineering:
    """A value the back converted to engineering units where it read it: ``raw * gain +
    offset``, rounded to ``decimals`` (None: not rounded). ``raw_type`` is what the device
    holds; ``low``/``high`` the range (None: open on that side), ``unit`` its unit.

    Inputs outside the range keep their value with quality over-/under-range
    (:meth:`range_quality`); outputs outside it are refused (:meth:`check_output`), and an
    output goes back to the device as :meth:`to_raw` of its value.
    """

    raw_type: DataType
    gain: float = 1.0
    offset: float = 0.0
    decimals: int | None = None
    unit: str = ""
    low: float | None = None
    high: float | None = None
    divider: float | None = None  # instead of gain: raw / divider (exact for 10, 100, ...)

    @property
    def converts(self) -> bool:
        """True when the value differs from the raw one (a gain, a divider or an offset)."""
        return self.gain != 1.0 or self.offset != 0.0 or self.divider not in (None, 1.0)

    @property
    def eu_range(self) -> tuple[float, float] | None:
        return (self.low, self.high) if self.low is not None and self.high is not None else None

    def from_raw(self, raw: float) -> float:
        if not self.converts:
            value = float(raw)
        elif self.divider is not None:
            value = raw / self.divider + self.offset
        else:
            value = raw * self.gain + self.offset
        return round(value, self.decimals) if self.decimals is not None else value

    def to_raw(self, value: float) -> int | float:
        """The device's raw value for ``value``; ValueError when the raw type cannot hold it."""
        raw: int | float = value
        if self.divider is not None:
            raw = (value - self.offset) * self.divider
        elif self.converts:
            raw = (value - self.offset) / self.gain
        if self.raw_type.is_integer:
            raw = round(raw)
        return self.raw_type.check(raw)  # type: ignore[return-value]  # (a number type)

    def range_quality(self, value: float) -> Quality | None:
        if self.high is not None and value > self.high:
            return Quality.OVER_RANGE
        if self.low is not None and value < self.low:
            return Quality.UNDER_RANGE
        return None

    def check_output(self, value: Value) -> None:
        """ValueError when an output value is outside the range or beyond the raw type."""
        if isinstance(value, str | bool):
            return
        if self.range_quality(value) is not None:
            raise ValueError(f"{value} is outside the range {self.low}..{self.high}")
        self.to_raw(value)

    def describe(self) -> str:
        parts = []
        if self.divider is not None:
            parts.append(f"raw {self.raw_type.value} / {self.divider:g} + {self.offset:g}")
        elif self.converts:
            parts.append(f"raw {self.raw_type.value} x {self.gain:g} + {self.offset:g}")
        if self.decimals is not None:
            parts.append(f"{self.decimals} decimals")
        if self.eu_range is not None or self.low is not None or self.high is not None:
            parts.append(f"range {self.low}..{self.high}")
        if self.unit:
            parts.append(self.unit)
        return ", ".join(parts)


@dataclass(frozen=True)
class ChannelSpec:
    """Declaration of one channel, produced by a back end from its configuration."""

    id: str
    kind: Kind
    source: Source
    dtype: DataType | None = None  # default: bool for digital, int16 for analog
    error_mode: ErrorMode = ErrorMode()
    shutdown_mode: ErrorMode | None = None  # None: outputs are left as they are on shutdown
    scaling: Scaling | None = None  # display only: the image holds raw counts
    initial: bool | int | float | str | None = None  # outputs only: value before any front writes
    engineering: Engineering | None = None  # the back converted the value to these units
    length: int | None = None  # STRING: at most this many bytes (UTF-8)
    label: str = ""  # what the device's manual calls it ("Voltage L1"), for descriptions

    @property
    def data_type(self) -> DataType:
        if self.dtype is not None:
            return self.dtype
        if self.kind.is_special:
            return DataType.UINT8
        return DataType.BOOL if self.kind.is_digital else DataType.INT16


def channel_id(back: str, address: int, kind: Kind, index: int) -> str:
    """The stable channel id, e.g. ``rs485/m3/do0``. One place for the format."""
    return f"{back}/m{address}/{kind.value}{index}"


Value = bool | int | float | str
MirroredState = tuple[str, Value, str, float | None, str]
"""One channel as another image holds it: (id, value, quality name, timestamp, written_by)."""
Reading = Value | tuple[Value, Quality]
"""What a back reports for one input: its value, or (value, Quality) when the module itself
reports a quality for it (over-range, config error...)."""


@dataclass
class Channel:
    spec: ChannelSpec
    value: Value
    quality: Quality
    timestamp: float | None = None  # monotonic time of the last good update
    error_mode: ErrorMode = field(default_factory=ErrorMode)
    last_good: Value | None = None  # value at the last good update
    written_by: str = ""  # origin of the last output write
    # from the spec, once: the write path reads them for every value
    dtype: DataType = field(init=False, repr=False, compare=False)
    is_output: bool = field(init=False, repr=False, compare=False)
    limited: bool = field(init=False, repr=False, compare=False)  # more to check than the type

    def __post_init__(self) -> None:
        self.dtype = self.spec.data_type
        self.is_output = self.spec.kind.is_output
        self.limited = self.spec.length is not None or (
            self.is_output and self.spec.engineering is not None
        )

    def check(self, value: object) -> Value:
        """``value`` as this channel holds it, or ValueError: its data type, a string's length,
        an output's engineering range (:meth:`Engineering.check_output`)."""
        checked = self.dtype.check(value)
        if self.limited:
            spec = self.spec
            if spec.length is not None and isinstance(checked, str):
                size = len(checked.encode())
                if size > spec.length:
                    raise ValueError(
                        f"text of {size} bytes is longer than the {spec.length} bytes it has"
                    )
            if self.is_output and spec.engineering is not None:
                spec.engineering.check_output(checked)
        return checked

    @property
    def id(self) -> str:
        return self.spec.id

    @property
    def kind(self) -> Kind:
        return self.spec.kind

    @property
    def source(self) -> Source:
        return self.spec.source


class Change:
    """One channel's change of value or quality, as subscribers receive it.

    A snapshot taken when the change was written: ``value``, ``quality`` and ``timestamp``
    are the channel's right after this change (``timestamp``: the image-clock time of its
    last good value; for a good value, the time the batch gave), ``old_value`` and
    ``old_quality`` what it had before, ``origin`` who wrote it. A later change of the same
    channel comes as a Change of its own. Subscribers must not modify it.
    """

    __slots__ = (
        "channel",
        "id",
        "value",
        "quality",
        "timestamp",
        "old_value",
        "old_quality",
        "origin",
    )

    def __init__(self, channel: Channel, old_value: Value, old_quality: Quality, origin: str):
        self.channel = channel
        self.id = channel.spec.id
        self.value = channel.value
        self.quality = channel.quality
        self.timestamp = channel.timestamp
        self.old_value = old_value
        self.old_quality = old_quality
        self.origin = origin

    @property
    def value_changed(self) -> bool:
        return self.old_value != self.value

    def __repr__(self) -> str:
        return (
            f"Change({self.id}: {self.old_value!r} {self.old_quality} -> {self.value!r} "
            f"{self.quality} at {self.timestamp}, by {self.origin})"
        )


Callback = Callable[[Change], None]
BatchCallback = Callable[[list[Change]], None]


_Staged = tuple[Channel, Value, Quality]


class ProcessImage:
    """All channels of one gateway, with quality, timestamps, error modes and subscriptions.

    Writing, one channel or many at once:

    * backs: :meth:`update_inputs` (every input of one reply, with its quality and the
      time it was acquired), :meth:`update_input` (one), :meth:`set_quality`;
    * fronts: :meth:`write_outputs` (every output one message carries: an RPDO, a
      DeviceNet poll request), :meth:`write_output` (one).

    Each call is one *batch*: every id and value is checked first (nothing is written
    when one is wrong), then the channels are updated, then subscribers are told once:
    a :meth:`subscribe_batch` callback gets one list with the changes it wants, a
    :meth:`subscribe` callback one call per change. A channel whose value and quality
    stay the same notifies nobody (a good value still refreshes its timestamp).

    A back reporting one reply, and a front that sends one message per reply::

        image.update_inputs(
            {"rs485/m1/di0": True, "rs485/m1/ai0": (32767, Quality.OVER_RANGE)},
            timestamp=reply_time,  # image.clock() when the reply came in
        )

        def changed(changes: list[Change]) -> None:
            for c in changes:  # only what changed: c.id, c.value, c.quality, c.timestamp
                ...
            send_one_message()

        image.subscribe_batch(changed, ids=my_input_ids)
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self._channels: dict[str, Channel] = {}
        self._subscribers = Subscribers()
        self._subscriptions = self._subscribers.subscriptions  # the same list, kept in place
        self._notify = self._subscribers.notify  # (bound once: the writes' hot path)
        self.clock = clock

    # -- building -------------------------------------------------------------
    def add(self, spec: ChannelSpec) -> Channel:
        if spec.id in self._channels:
            raise ValueError(f"duplicate channel id {spec.id!r}")
        dtype = spec.data_type
        value: Value
        if spec.kind.is_output and spec.initial is not None:
            value = dtype.check(spec.initial)
        else:
            value = zero_of(dtype)
        quality = Quality.GOOD if spec.kind.is_output else Quality.NOT_READ
        channel = Channel(spec, value, quality, error_mode=spec.error_mode)
        self._channels[spec.id] = channel
        self._subscribers.forget_routes()
        return channel

    # -- reading --------------------------------------------------------------
    def __contains__(self, channel_id: str) -> bool:
        return channel_id in self._channels

    def __len__(self) -> int:
        return len(self._channels)

    def __getitem__(self, channel_id: str) -> Channel:
        try:
            return self._channels[channel_id]
        except KeyError:
            raise KeyError(f"no channel {channel_id!r} in the process image") from None

    def value(self, channel_id: str) -> Value:
        return self[channel_id].value

    def channels(
        self, kind: Kind | None = None, back: str | None = None, module: int | None = None
    ) -> list[Channel]:
        return [
            c
            for c in self._channels.values()
            if (kind is None or c.kind is kind)
            and (back is None or c.source.back == back)
            and (module is None or c.source.module == module)
        ]

    def match(self, patterns: Iterable[str]) -> list[Channel]:
        """Channels whose id matches any glob pattern, in pattern order, each once."""
        seen: dict[str, Channel] = {}
        for pattern in patterns:
            for cid in sorted(fnmatch.filter(self._channels, pattern), key=_natural_key):
                seen.setdefault(cid, self._channels[cid])
        return list(seen.values())

    def __iter__(self) -> Iterator[Channel]:
        return iter(self._channels.values())

    # -- writing --------------------------------------------------------------
    def update_inputs(
        self,
        readings: Mapping[str, Reading],
        quality: Quality = Quality.GOOD,
        origin: str = "back",
        timestamp: float | None = None,
    ) -> list[Change]:
        """A back reports the inputs of one reply, in one batch.

        ``readings`` maps channel ids to values, or to ``(value, Quality)`` for a channel
        whose module reports its own quality (over-range, config error); ``quality``
        applies to the others. ``timestamp`` is when the values were acquired, on the
        image's clock (default: now); every good value gets it as its channel's
        timestamp. Raises KeyError (unknown id) or ValueError (an output, a value outside
        the channel's data type) before anything is written. Returns the changes of
        value or quality, in the order given.
        """
        channels = self._channels
        staged: list[_Staged] = []
        for cid, reading in readings.items():
            channel = channels.get(cid)
            if channel is None or channel.is_output:
                self._refuse(cid, "an output; backs write inputs only")
            if reading.__class__ is bool and channel.dtype is _BOOL:  # the common case, inline
                staged.append((channel, reading, quality))
            elif isinstance(reading, tuple):
                value, own = reading
                staged.append((channel, _checked(channel, value), own))
            else:
                staged.append((channel, _checked(channel, reading), quality))
        return self._commit(staged, origin, timestamp)

    def update_input(
        self,
        channel_id: str,
        value: Value,
        quality: Quality = Quality.GOOD,
        origin: str = "back",
    ) -> bool:
        """A back reports one fresh reading. Returns True when value or quality changed."""
        return bool(self.update_inputs({channel_id: value}, quality, origin))

    def write_outputs(self, values: Mapping[str, Value], origin: str = "front") -> list[Change]:
        """A front (or an error mode) sets the outputs of one message, in one batch.

        ``values`` maps output channel ids to values; every output keeps its quality (the
        back that drives the module owns it) and remembers ``origin`` as its writer.
        Raises KeyError (unknown id) or ValueError (an input, a value outside the
        channel's data type) before anything is written. Returns the changes, in the
        order given.
        """
        channels = self._channels
        staged: list[_Staged] = []
        for cid, value in values.items():
            channel = channels.get(cid)
            if channel is None or not channel.is_output:
                self._refuse(cid, "an input; only outputs can be written")
            if value.__class__ is bool and channel.dtype is _BOOL:  # the common case, inline
                staged.append((channel, value, channel.quality))
            else:
                staged.append((channel, _checked(channel, value), channel.quality))
        return self._commit(staged, origin, None, written=True)

    def write_output(self, channel_id: str, value: Value, origin: str = "front") -> bool:
        """A front (or an error mode) sets one output. Returns True when the value changed."""
        return bool(self.write_outputs({channel_id: value}, origin))

    def set_quality(
        self, channel_ids: Iterable[str], quality: Quality, origin: str = "back"
    ) -> list[Change]:
        """Change the quality of channels and keep their last values (stale, comm fault, ...),
        in one batch. Returns the changes."""
        staged = [(self[cid], self[cid].value, quality) for cid in channel_ids]
        return self._commit(staged, origin, None)

    def mirror(self, states: Iterable[MirroredState], origin: str = "mirror") -> list[Change]:
        """Set channels to what another image holds, in one batch: a north-facing child keeps
        its copy of the fieldbus process's image this way (``fieldgate.isolation``).

        Each state is ``(id, value, quality, timestamp, written_by)`` as the other image has
        it, inputs and outputs alike, nothing checked but the id (unknown ids are skipped);
        subscribers get the changes as from any other write, with ``origin`` as their origin
        when the state names none."""
        changes: list[Change] = []
        good = Quality.GOOD
        for cid, value, quality_name, timestamp, written_by in states:
            channel = self._channels.get(cid)
            if channel is None:
                continue
            quality = Quality(quality_name)
            if timestamp is not None:
                channel.timestamp = timestamp
            if quality is good:
                channel.last_good = value
            if channel.is_output and written_by:
                channel.written_by = written_by
            old_value, old_quality = channel.value, channel.quality
            if old_value == value and old_quality is quality and type(old_value) is type(value):
                continue
            channel.value, channel.quality = value, quality
            changes.append(Change(channel, old_value, old_quality, written_by or origin))
        if changes and self._subscriptions:
            self._notify(changes)
        return changes

    def refresh_times(self, times: Iterable[tuple[str, float | None]]) -> None:
        """Set read times another image refreshed without a change (the mirror's side of
        ``fieldgate.isolation``); a good channel's last good value is its value. No one is
        notified: nothing changed."""
        for cid, timestamp in times:
            channel = self._channels.get(cid)
            if channel is not None and timestamp is not None:
                channel.timestamp = timestamp
                if channel.quality is Quality.GOOD:
                    channel.last_good = channel.value

    def _refuse(self, channel_id: str, what: str) -> NoReturn:
        if channel_id not in self._channels:
            raise KeyError(f"no channel {channel_id!r} in the process image")
        raise ValueError(f"{channel_id} is {what}")

    def _commit(
        self, staged: list[_Staged], origin: str, timestamp: float | None, written: bool = False
    ) -> list[Change]:
        """Write what was checked; ``written``: outputs, which remember their writer."""
        now = self.clock() if timestamp is None else timestamp
        changes: list[Change] = []
        append, good = changes.append, Quality.GOOD
        for channel, value, quality in staged:
            if written:
                channel.written_by = origin
            if quality is good:
                channel.timestamp = now
                channel.last_good = value
            old_value, old_quality = channel.value, channel.quality
            if old_value == value and old_quality is quality and type(old_value) is type(value):
                continue
            channel.value, channel.quality = value, quality
            append(Change(channel, old_value, old_quality, origin))
        if changes and self._subscriptions:
            self._notify(changes)
        return changes

    # -- subscriptions --------------------------------------------------------
    def subscribe(
        self,
        callback: Callback,
        *,
        kinds: Iterable[Kind] | None = None,
        ids: Iterable[str] | None = None,
    ) -> Subscription:
        """Call ``callback(change)`` for each change of a channel of these kinds / ids.

        Inside a batch each change is its own call, in the order written, after the
        whole batch is in the image. Reacting once per batch is cheaper:
        :meth:`subscribe_batch`.
        """
        return self._subscribers.add(callback, kinds, ids, batch=False)

    def subscribe_batch(
        self,
        callback: BatchCallback,
        *,
        kinds: Iterable[Kind] | None = None,
        ids: Iterable[str] | None = None,
    ) -> Subscription:
        """Call ``callback(changes)`` once per write call that changed channels it wants.

        ``changes`` is a list (the subscriber's to keep) of the :class:`Change` of every
        wanted channel whose value or quality changed, each with its own value, quality
        and timestamp, in the order written; channels that did not change are not in it,
        and a call that changed none of them makes no call. Subscribers are called in
        the order they subscribed, synchronously, after the batch is in the image (a
        subscriber reads the whole message's values); what they write in turn is a new
        batch, delivered before the next subscriber of this one. A callback that raises
        is logged and the others are still called.
        """
        return self._subscribers.add(callback, kinds, ids, batch=True)

    def queue(
        self,
        *,
        kinds: Iterable[Kind] | None = None,
        ids: Iterable[str] | None = None,
        maxsize: int = 0,
    ) -> tuple[asyncio.Queue[Change], Subscription]:
        """Changes delivered to an asyncio queue instead of a callback.

        A full queue drops the change and logs it once per burst; the caller owns the
        subscription and cancels it when done.
        """
        q: asyncio.Queue[Change] = asyncio.Queue(maxsize)
        dropped = False

        def put(changes: list[Change]) -> None:
            nonlocal dropped
            for change in changes:
                try:
                    q.put_nowait(change)
                    dropped = False
                except asyncio.QueueFull:
                    if not dropped:
                        log.warning("change queue full, dropping changes of %s", change.id)
                    dropped = True

        return q, self.subscribe_batch(put, kinds=kinds, ids=ids)

    # -- error modes ----------------------------------------------------------
    def set_error_mode(self, channel_id: str, mode: ErrorMode) -> None:
        channel = self[channel_id]
        if not channel.kind.is_output:
            raise ValueError(f"{channel_id} is an input; error modes apply to outputs")
        value = channel.check(mode.value)
        if isinstance(value, str):
            raise ValueError(f"{channel_id} is text; its error mode can only hold it")
        channel.error_mode = ErrorMode(mode.use_value, value)

    def apply_error_modes(
        self, channel_ids: Iterable[str] | None = None, origin: str = "error-mode"
    ) -> list[str]:
        """Drive every output whose error mode says so to its error value, in one batch.

        Called when a front loses its master. Returns the ids whose value changed.
        """
        values = {
            c.id: c.error_mode.value for c in self._outputs(channel_ids) if c.error_mode.use_value
        }
        return [change.id for change in self.write_outputs(values, origin)]

    def apply_shutdown_modes(self, origin: str = "shutdown") -> list[str]:
        values = {
            c.id: mode.value
            for c in self._outputs(None)
            if (mode := c.spec.shutdown_mode) is not None and mode.use_value
        }
        return [change.id for change in self.write_outputs(values, origin)]

    def _outputs(self, channel_ids: Iterable[str] | None) -> list[Channel]:
        if channel_ids is None:
            return [c for c in self._channels.values() if c.kind.is_output]
        return [c for c in (self[cid] for cid in channel_ids) if c.kind.is_output]

    def snapshot(self) -> list[dict[str, Any]]:
        """Plain data for status displays and tests."""
        return [
            {
                "id": c.id,
                "kind": c.kind.value,
                "value": c.value,
                "quality": c.quality.value,
                "timestamp": c.timestamp,
            }
            for c in self._channels.values()
        ]


_BOOL = DataType.BOOL


def zero_of(dtype: DataType) -> Value:
    """What a channel of ``dtype`` holds before its first value."""
    if dtype is DataType.BOOL:
        return False
    if dtype is DataType.STRING:
        return ""
    return 0


def _checked(channel: Channel, value: Value) -> Value:
    """``value`` in the channel's data type (a bool for a digital channel needs no work)."""
    if value.__class__ is bool and channel.dtype is _BOOL:
        return value
    try:
        return channel.check(value) if channel.limited else channel.dtype.check(value)
    except ValueError as exc:
        raise ValueError(f"{channel.spec.id}: {exc}") from None


def _natural_key(text: str) -> list[int | str]:
    """Sort ``m10`` after ``m9``: digits compare as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]
