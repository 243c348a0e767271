"""Heartbeat producer and consumer (CiA 301 §7.2.8.3.2), sans-I/O.

* Producer 0x1017 (ms): ``[state]`` on 0x700+ID in every state after the boot-up; a write
  restarts the period. A node without 0x1017 (the I-7232D: guarding only) produces none.
* Consumer 0x1016:1..N (bits 23-16 node-ID, 15-0 time in ms): monitoring of a node starts
  at its first heartbeat (a boot-up restarts it); a timeout is a master-lost event (error
  control, :mod:`.errctl`, raises EMCY 0x8130 ``07 <node-ID>`` and applies 0x1029); its next
  heartbeat clears it. Two entries with the same node-ID and non-zero times abort
  0604 0043. An entry rewritten with another time restarts that node's monitoring at its
  next heartbeat; unchanged entries keep running.
"""

from __future__ import annotations

from collections.abc import Iterable

from canopen.objectdictionary import datatypes as dt

from . import abort
from .abort import SdoAbort
from .od import Dictionary

PRODUCER_TIME, CONSUMER_TIMES = 0x1017, 0x1016


class HeartbeatProducer:
    def __init__(self, od: Dictionary, served: bool):
        self.od = od
        self.served = served  # 0x1017 in the dictionary
        self.due: float | None = None

    def period_ms(self) -> int:
        """0x1017 now; 0 when the node has no heartbeat producer."""
        return self.od.integer(PRODUCER_TIME) if self.served else 0

    def restart(self, now: float, running: bool) -> None:
        """The period starts again now (``running``: the node may send, else none is due)."""
        period = self.period_ms()
        self.due = now + period / 1000.0 if period and running else None

    def take_due(self, now: float) -> bool:
        """Whether a heartbeat is due now; if so, the next one is scheduled."""
        if self.due is None or now < self.due:
            return False
        period = self.period_ms() / 1000.0
        self.due = (self.due + period) if self.due + period > now else now + period
        return True


class HeartbeatConsumer:
    """The 0x1016 entries and the monitoring of each producer they name."""

    def __init__(self, entries: int, defaults: Iterable[int] = ()):
        self.defaults = list(defaults)  # 0x1016:1.. defaults (node << 16 | ms)
        self.entries = max(entries, len(self.defaults))
        self.od: Dictionary | None = None
        self.times: dict[int, int] = {}  # producer node-ID -> consumer time (ms), from 0x1016
        self.watched: dict[int, float | None] = {}  # producer -> deadline (None: not yet heard)

    def add_objects(self, od: Dictionary) -> None:
        self.od = od
        if not self.entries:
            return
        od.add_array(
            CONSUMER_TIMES,
            "Consumer heartbeat time",
            [
                (
                    i,
                    f"Consumer heartbeat time {i}",
                    dt.UNSIGNED32,
                    "rw",
                    self.defaults[i - 1] if i <= len(self.defaults) else 0,
                    {"maximum": 0x00FFFFFF},
                )
                for i in range(1, self.entries + 1)
            ],
        )
        od.add_validator(CONSUMER_TIMES, self._check)

    def _entry(self, sub: int) -> int:
        assert self.od is not None
        return self.od.integer(CONSUMER_TIMES, sub)

    def configured_times(self) -> dict[int, int]:
        times = {}
        for sub in range(1, self.entries + 1):
            entry = self._entry(sub)
            producer, period = (entry >> 16) & 0xFF, entry & 0xFFFF
            if 1 <= producer <= 127 and period:
                times[producer] = period
        return times

    def _check(self, sub: int, value: int) -> None:
        producer, period = (value >> 16) & 0xFF, value & 0xFFFF
        if not period or sub == 0:
            return
        for other in range(1, self.entries + 1):
            entry = self._entry(other)
            if other != sub and (entry >> 16) & 0xFF == producer and entry & 0xFFFF:
                raise SdoAbort(
                    abort.INCOMPATIBLE_PARAMETER,
                    f"node {producer} is already monitored at sub {other}",
                )

    def reset(self) -> None:
        """Reset communication: each producer restarts at its first heartbeat."""
        self.times = self.configured_times()
        self.watched = dict.fromkeys(self.times)

    def rewritten(self) -> None:
        """0x1016 written: a producer whose time changed restarts at its next heartbeat; the
        others keep running."""
        times = self.configured_times()
        self.watched = {
            p: self.watched.get(p) if self.times.get(p) == t else None for p, t in times.items()
        }
        self.times = times

    def heard(self, producer: int, state: int, now: float) -> None:
        """A heartbeat of ``producer`` (``state`` 0: its boot-up, monitoring restarts)."""
        self.watched[producer] = None if state == 0x00 else now + self.times[producer] / 1000.0

    def timed_out(self, now: float) -> list[int]:
        """The producers whose time passed now (each once: watched again at its next heartbeat)."""
        late = [p for p, due in self.watched.items() if due is not None and now >= due]
        for producer in late:
            self.watched[producer] = None
        return late

    def deadline(self) -> float | None:
        earliest = None
        for t in self.watched.values() if self.watched else ():
            if t is not None and (earliest is None or t < earliest):
                earliest = t
        return earliest
