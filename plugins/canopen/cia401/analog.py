"""When an analog input change is a TPDO event (CiA 401 0x6421-0x6426, or every change).

Two modes (``analog_events``):

* ``interrupt`` (CiA 401, the ICP DAS style): only with 0x6423 (global interrupt enable,
  default FALSE: the I-7232D's "analog changes do not trigger a TPDO") and when the new
  value meets the channel's 0x6421 trigger: bit 0 above the 0x6424 upper limit, bit 1
  below the 0x6425 lower limit, bit 2 more than the 0x6426 delta away from the value last
  reported. A change that fires sets the channel's bit in 0x6422 (interrupt source, 32
  channels per bank, cleared when read) and becomes the value last reported.
* ``change`` (the NA-9161, which has no 0x6421-0x6426: they are not served): every change.
"""

from __future__ import annotations

from collections.abc import Sequence

from fieldgate.image import Change, Channel

from ..cia301.entries import BOOLEAN, INTEGER32, UNSIGNED8, UNSIGNED32, ObjectSpec, item
from .values import to_int16

AI_TRIGGER, AI_SOURCE, AI_ENABLE, AI_UPPER, AI_LOWER, AI_DELTA = (
    0x6421,
    0x6422,
    0x6423,
    0x6424,
    0x6425,
    0x6426,
)
TRIGGER_UPPER, TRIGGER_LOWER, TRIGGER_DELTA = 0x01, 0x02, 0x04


class AnalogInterrupts:
    """The interrupt settings of a front's analog inputs and the rule that reads them."""

    def __init__(self, ai: Sequence[Channel], mode: str, *, trigger_default: int = 0x07):
        self.ai = ai
        self.mode = mode  # "interrupt" or "change"
        n = len(ai)
        self.number = {ch.id: k + 1 for k, ch in enumerate(ai)}  # channel id -> 0x6401 sub
        self.trigger = [trigger_default] * n
        self.upper = [0] * n
        self.lower = [0] * n
        self.delta = [0] * n
        self.enabled = False
        self.source = [0] * ((n + 31) // 32)
        self._last_reported = [0] * n

    @property
    def banks(self) -> range:
        return range(len(self.source))

    def restart(self) -> None:
        """The values now are the values last reported (events start, or 0x6423 turns on)."""
        self._last_reported = [to_int16(ch) for ch in self.ai]

    def fires(self, change: Change) -> bool:
        """Whether this change of an analog input is a TPDO event (then it is reported)."""
        if self.mode == "change":
            return True
        if not self.enabled:
            return False
        k = self.number[change.id] - 1
        value = to_int16(change.channel, change.value)
        trigger = self.trigger[k]
        fire = (
            (trigger & TRIGGER_UPPER and value > self.upper[k])
            or (trigger & TRIGGER_LOWER and value < self.lower[k])
            or (trigger & TRIGGER_DELTA and abs(value - self._last_reported[k]) > self.delta[k])
        )
        if fire:
            self._last_reported[k] = value
            self.source[k // 32] |= 1 << (k % 32)
        return bool(fire)

    def read_enable(self) -> int:
        return int(self.enabled)

    def write_enable(self, value: int) -> None:
        if value and not self.enabled:
            self.restart()
        self.enabled = bool(value)

    def read_source(self, bank: int) -> int:
        value, self.source[bank] = self.source[bank], 0
        return value


# The interrupt objects (``interrupt`` mode only), over the analog inputs ("ai") or the
# 0x6422 banks: (index, object name, entry name, type, access, over, get, put, default, ...).
INTERRUPT_OBJECTS: tuple[ObjectSpec[AnalogInterrupts], ...] = (
    ObjectSpec(
        AI_TRIGGER,
        "Analog input interrupt trigger selection",
        "Trigger selection {n}",
        UNSIGNED8,
        "rw",
        "ai",
        *item("trigger"),
        high=0x07,
    ),
    ObjectSpec(
        AI_SOURCE,
        "Analog input interrupt source",
        "Interrupt source bank {n}",
        UNSIGNED32,
        "ro",
        "banks",
        lambda a, bank: a.read_source(bank),  # looked up per read: cleared when read
        default=0,
    ),
    ObjectSpec(
        AI_ENABLE,
        "Analog input global interrupt enable",
        "Analog input global interrupt enable",
        BOOLEAN,
        "rw",
        None,
        lambda a, _: a.read_enable(),
        lambda a, _, value: a.write_enable(value),
        default=0,
    ),
    ObjectSpec(
        AI_UPPER,
        "Analog input interrupt upper limit",
        "Upper limit {n}",
        INTEGER32,
        "rw",
        "ai",
        *item("upper"),
        default=0,
    ),
    ObjectSpec(
        AI_LOWER,
        "Analog input interrupt lower limit",
        "Lower limit {n}",
        INTEGER32,
        "rw",
        "ai",
        *item("lower"),
        default=0,
    ),
    ObjectSpec(
        AI_DELTA,
        "Analog input interrupt delta",
        "Delta {n}",
        UNSIGNED32,
        "rw",
        "ai",
        *item("delta"),
        default=0,
    ),
)
