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

Direction of data
-----------------
* Inputs (DI, AI, SI) are written by backs (``update_input``) and read by fronts.
* Outputs (DO, AO, SO) are written by fronts (``write_output``) and read by backs.
* SI/SO channels are the bytes (UINT8) of a module's raw byte block, e.g. a high-speed
  counter's 6 input and 2 output bytes; fronts that know no such area leave them out.
Both sides subscribe to changes, so event-driven PDOs, DeviceNet change-of-state and
write-on-change polling need no busy loops.
"""

from __future__ import annotations

import asyncio
import fnmatch
import logging
import re
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

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
    OVER_RANGE = "over-range"  # module-reported
    UNDER_RANGE = "under-range"  # module-reported
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

    def check(self, value: object) -> bool | int | float:
        """Return ``value`` converted to this type, or raise ValueError naming the range."""
        if self is DataType.BOOL:
            if isinstance(value, bool) or value in (0, 1):
                return bool(value)
            raise ValueError(f"expected a bool (0 or 1), got {value!r}")
        if self is DataType.FLOAT32:
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                return float(value)
            raise ValueError(f"expected a number, got {value!r}")
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
}


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
class ChannelSpec:
    """Declaration of one channel, produced by a back end from its configuration."""

    id: str
    kind: Kind
    source: Source
    dtype: DataType | None = None  # default: bool for digital, int16 for analog
    error_mode: ErrorMode = ErrorMode()
    shutdown_mode: ErrorMode | None = None  # None: outputs are left as they are on shutdown
    scaling: Scaling | None = None
    initial: bool | int | float | None = None  # outputs only: value before any front writes

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


@dataclass
class Channel:
    spec: ChannelSpec
    value: bool | int | float
    quality: Quality
    timestamp: float | None = None  # monotonic time of the last good update
    error_mode: ErrorMode = field(default_factory=ErrorMode)
    last_good: bool | int | float | None = None  # value at the last good update
    written_by: str = ""  # origin of the last output write

    @property
    def id(self) -> str:
        return self.spec.id

    @property
    def kind(self) -> Kind:
        return self.spec.kind

    @property
    def source(self) -> Source:
        return self.spec.source


@dataclass(frozen=True)
class Change:
    """One change of value or quality, passed to subscribers."""

    channel: Channel
    old_value: bool | int | float
    old_quality: Quality
    origin: str

    @property
    def value(self) -> bool | int | float:
        return self.channel.value

    @property
    def quality(self) -> Quality:
        return self.channel.quality

    @property
    def value_changed(self) -> bool:
        return self.old_value != self.channel.value


Callback = Callable[[Change], None]


class Subscription:
    """Handle returned by :meth:`ProcessImage.subscribe`; call :meth:`cancel` to stop."""

    def __init__(
        self,
        image: ProcessImage,
        callback: Callback,
        kinds: frozenset[Kind] | None,
        ids: frozenset[str] | None,
    ):
        self._image = image
        self.callback = callback
        self.kinds = kinds
        self.ids = ids

    def wants(self, channel: Channel) -> bool:
        if self.kinds is not None and channel.kind not in self.kinds:
            return False
        return self.ids is None or channel.id in self.ids

    def cancel(self) -> None:
        self._image._subscriptions = [s for s in self._image._subscriptions if s is not self]


class ProcessImage:
    """All channels of one gateway, with quality, timestamps, error modes and subscriptions."""

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self._channels: dict[str, Channel] = {}
        self._subscriptions: list[Subscription] = []
        self.clock = clock

    # -- building -------------------------------------------------------------
    def add(self, spec: ChannelSpec) -> Channel:
        if spec.id in self._channels:
            raise ValueError(f"duplicate channel id {spec.id!r}")
        dtype = spec.data_type
        if spec.kind.is_output and spec.initial is not None:
            value = dtype.check(spec.initial)
        else:
            value = False if dtype is DataType.BOOL else 0
        quality = Quality.GOOD if spec.kind.is_output else Quality.NOT_READ
        channel = Channel(spec, value, quality, error_mode=spec.error_mode)
        self._channels[spec.id] = channel
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

    def value(self, channel_id: str) -> bool | int | float:
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
    def update_input(
        self,
        channel_id: str,
        value: bool | int | float,
        quality: Quality = Quality.GOOD,
        origin: str = "back",
    ) -> bool:
        """A back end reports a fresh reading. Returns True when value or quality changed."""
        channel = self[channel_id]
        if channel.kind.is_output:
            raise ValueError(f"{channel_id} is an output; backs write inputs only")
        return self._set(channel, channel.spec.data_type.check(value), quality, origin)

    def write_output(
        self, channel_id: str, value: bool | int | float, origin: str = "front"
    ) -> bool:
        """A front (or an error mode) sets an output. Returns True when the value changed."""
        channel = self[channel_id]
        if not channel.kind.is_output:
            raise ValueError(f"{channel_id} is an input; only outputs can be written")
        channel.written_by = origin
        return self._set(channel, channel.spec.data_type.check(value), channel.quality, origin)

    def set_quality(
        self, channel_ids: Iterable[str], quality: Quality, origin: str = "back"
    ) -> None:
        """Change the quality of channels and keep their last values (stale, comm fault, ...)."""
        for cid in channel_ids:
            channel = self[cid]
            self._set(channel, channel.value, quality, origin)

    def _set(
        self, channel: Channel, value: bool | int | float, quality: Quality, origin: str
    ) -> bool:
        if quality is Quality.GOOD:
            channel.timestamp = self.clock()
            channel.last_good = value
        old_value, old_quality = channel.value, channel.quality
        if old_value == value and old_quality is quality and type(old_value) is type(value):
            return False
        channel.value, channel.quality = value, quality
        change = Change(channel, old_value, old_quality, origin)
        for sub in list(self._subscriptions):
            if sub.wants(channel):
                try:
                    sub.callback(change)
                except Exception:  # a bad subscriber must never stop a writer
                    log.exception("subscriber %r failed on %s", sub.callback, channel.id)
        return True

    # -- subscriptions --------------------------------------------------------
    def subscribe(
        self,
        callback: Callback,
        *,
        kinds: Iterable[Kind] | None = None,
        ids: Iterable[str] | None = None,
    ) -> Subscription:
        sub = Subscription(
            self,
            callback,
            frozenset(kinds) if kinds is not None else None,
            frozenset(ids) if ids is not None else None,
        )
        self._subscriptions.append(sub)
        return sub

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

        def put(change: Change) -> None:
            nonlocal dropped
            try:
                q.put_nowait(change)
                dropped = False
            except asyncio.QueueFull:
                if not dropped:
                    log.warning("change queue full, dropping changes of %s", change.channel.id)
                dropped = True

        return q, self.subscribe(put, kinds=kinds, ids=ids)

    # -- error modes ----------------------------------------------------------
    def set_error_mode(self, channel_id: str, mode: ErrorMode) -> None:
        channel = self[channel_id]
        if not channel.kind.is_output:
            raise ValueError(f"{channel_id} is an input; error modes apply to outputs")
        channel.error_mode = ErrorMode(mode.use_value, channel.spec.data_type.check(mode.value))

    def apply_error_modes(
        self, channel_ids: Iterable[str] | None = None, origin: str = "error-mode"
    ) -> list[str]:
        """Drive every output whose error mode says so to its error value.

        Called when a front loses its master. Returns the ids whose value changed.
        """
        outputs = self._outputs(channel_ids)
        return [
            c.id
            for c in outputs
            if c.error_mode.use_value and self.write_output(c.id, c.error_mode.value, origin)
        ]

    def apply_shutdown_modes(self, origin: str = "shutdown") -> list[str]:
        changed = []
        for c in self._outputs(None):
            mode = c.spec.shutdown_mode
            if mode is not None and mode.use_value and self.write_output(c.id, mode.value, origin):
                changed.append(c.id)
        return changed

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


def _natural_key(text: str) -> list[int | str]:
    """Sort ``m10`` after ``m9``: digits compare as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]
