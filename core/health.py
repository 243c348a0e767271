"""Health and statistics of back-end modules and serial lines.

One :class:`ModuleHealth` per module of a back end. Pollers record every transaction
here; fronts read it (CANopen object 0x2000, EMCY 0xFF81, DeviceNet status) and
subscribe to the online/offline transitions.

Offline rule (the seeds' "times out or has receive-data errors more than three
times"): a module is declared offline when its consecutive failures *exceed*
``fail_threshold`` (default 3, so on the 4th consecutive failure). One success brings
it back online. See README "Design notes".
"""

from __future__ import annotations

import logging
from bisect import bisect_left
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

log = logging.getLogger("fieldgate.health")

COUNTER_WRAP = 0x10000  # the I-7232D's 0x2000 counters are UNSIGNED16

# Upper bounds (seconds) of the poll round-trip histogram: around the wire time of RS-485
# transactions from 115200 down to 1200 baud (a Prometheus client's defaults suit web services).
RTT_BUCKETS = (0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)


class ErrorKind(StrEnum):
    TIMEOUT = "timeout"
    CRC = "crc"  # bad CRC or checksum
    EXCEPTION = (
        "exception"  # the module answered with a protocol error (Modbus exception, DCON '?')
    )
    GARBAGE = "garbage"  # short, truncated or unparsable reply
    WRONG_ADDRESS = "wrong-address"  # reply from another module
    WATCHDOG = "watchdog"  # module reports host-watchdog timeout
    IO = "io"  # the port itself failed


class HealthEvent(StrEnum):
    FAILURE = "failure"
    OFFLINE = "offline"
    ONLINE = "online"
    COUNTER_CLEARED = "counter-cleared"


@dataclass
class ModuleHealth:
    back: str
    address: int
    model: str = ""
    fail_threshold: int = 3
    online: bool = True  # optimistic until proven otherwise; inputs start as not-read
    consecutive_failures: int = 0
    error_counter: int = 0  # wraps at 16 bits
    last_error: str = ""
    last_error_kind: ErrorKind | None = None
    requests: int = 0
    errors: Counter[str] = field(default_factory=Counter)
    last_rtt: float | None = None
    last_success: float | None = None
    # successful transactions by round trip: rtt_counts[i] for RTT_BUCKETS[i-1] < rtt <= RTT_BUCKETS[i],
    # the last one above every bucket (not cumulative; /metrics sums them up)
    rtt_counts: list[int] = field(default_factory=lambda: [0] * (len(RTT_BUCKETS) + 1))
    rtt_sum: float = 0.0
    _listeners: list[Callable[[ModuleHealth, HealthEvent], None]] = field(
        default_factory=list, repr=False
    )

    @property
    def key(self) -> tuple[str, int]:
        return (self.back, self.address)

    def record_success(self, rtt: float | None = None, now: float | None = None) -> bool:
        """Count a good transaction. Returns True when the module came back online."""
        self.requests += 1
        self.last_rtt = rtt
        self.last_success = now
        if rtt is not None:
            self.rtt_counts[bisect_left(RTT_BUCKETS, rtt)] += 1
            self.rtt_sum += rtt
        self.consecutive_failures = 0
        if not self.online:
            self.online = True
            log.info("module %s/%d is back online", self.back, self.address)
            self._emit(HealthEvent.ONLINE)
            return True
        return False

    def record_failure(self, kind: ErrorKind, text: str) -> bool:
        """Count a failed transaction. Returns True when this failure took the module offline."""
        self.requests += 1
        self.errors[kind] += 1
        self.error_counter = (self.error_counter + 1) % COUNTER_WRAP
        self.consecutive_failures += 1
        self.last_error, self.last_error_kind = text, kind
        self._emit(HealthEvent.FAILURE)
        if self.online and self.consecutive_failures > self.fail_threshold:
            self.online = False
            log.warning(
                "module %s/%d offline after %d consecutive failures: %s",
                self.back,
                self.address,
                self.consecutive_failures,
                text,
            )
            self._emit(HealthEvent.OFFLINE)
            return True
        return False

    def record_line_loss(self, text: str) -> bool:
        """The module's port is gone: one failure, and offline at once whatever the count.
        Returns True when this took the module offline."""
        self.requests += 1
        self.errors[ErrorKind.IO] += 1
        self.error_counter = (self.error_counter + 1) % COUNTER_WRAP
        self.consecutive_failures = max(self.consecutive_failures + 1, self.fail_threshold + 1)
        self.last_error, self.last_error_kind = text, ErrorKind.IO
        self._emit(HealthEvent.FAILURE)
        if not self.online:
            return False
        self.online = False
        log.warning("module %s/%d offline: port lost: %s", self.back, self.address, text)
        self._emit(HealthEvent.OFFLINE)
        return True

    def clear_error_counter(self) -> None:
        self.error_counter = 0
        self._emit(HealthEvent.COUNTER_CLEARED)

    def subscribe(self, listener: Callable[[ModuleHealth, HealthEvent], None]) -> None:
        self._listeners.append(listener)

    def announce(self, event: HealthEvent) -> None:
        """Tell the listeners of an event that happened elsewhere (a north-facing child's
        mirror of a module, after it copied the module's state)."""
        self._emit(event)

    def _emit(self, event: HealthEvent) -> None:
        for listener in list(self._listeners):
            try:
                listener(self, event)
            except Exception:
                log.exception("health listener failed for %s/%d", self.back, self.address)

    def as_dict(self) -> dict[str, Any]:
        return {
            "back": self.back,
            "address": self.address,
            "model": self.model,
            "online": self.online,
            "consecutive_failures": self.consecutive_failures,
            "error_counter": self.error_counter,
            "last_error": self.last_error,
            "requests": self.requests,
            "errors": {str(k): v for k, v in self.errors.items()},
            "last_rtt_ms": None if self.last_rtt is None else round(self.last_rtt * 1000, 3),
        }


class HealthRegistry:
    """All modules of all backs; fronts subscribe here to every module at once."""

    def __init__(self) -> None:
        self._modules: dict[tuple[str, int], ModuleHealth] = {}
        self._listeners: list[Callable[[ModuleHealth, HealthEvent], None]] = []
        self.ports_lost: dict[str, str] = {}  # back -> why its serial port is missing
        self._port_listeners: list[Callable[[str, bool, str], None]] = []
        self.back_errors: dict[str, str] = {}  # back -> what it reports as wrong with it
        self._back_listeners: list[Callable[[str, str | None], None]] = []

    # -- a back's own error: protocol-neutral, each front shows it its way --------------------
    def back_error(self, back: str, error: str | None) -> None:
        """A back reports an error of its own, beyond a module or its port (``error``: one line,
        e.g. "DCON modules init error: no module answered ..."), or that it ended (None). The
        fronts serving the back show it the way their device does (a CANopen EMCY 0x5000, the
        DeviceNet Identity status); listeners (:meth:`subscribe_backs`) hear each change once."""
        if self.back_errors.get(back) == error:
            return
        if error is None:
            del self.back_errors[back]
        else:
            self.back_errors[back] = error
        for listener in list(self._back_listeners):
            try:
                listener(back, error)
            except Exception:
                log.exception("back error listener failed for %s", back)

    def subscribe_backs(self, listener: Callable[[str, str | None], None]) -> None:
        """``listener(back, error)`` on every change of a back's own error (None: it ended)."""
        self._back_listeners.append(listener)

    # -- serial ports: a back's whole line, missing at start or lost at run time -------------
    def port_state(self, back: str, ok: bool, text: str = "") -> None:
        """A back's port is missing (``ok`` False, ``text`` why) or open again; listeners
        (``subscribe_ports``) hear each change once."""
        if ok == (back not in self.ports_lost):
            return
        if ok:
            del self.ports_lost[back]
        else:
            self.ports_lost[back] = text
        for listener in list(self._port_listeners):
            try:
                listener(back, ok, text)
            except Exception:
                log.exception("port listener failed for %s", back)

    def subscribe_ports(self, listener: Callable[[str, bool, str], None]) -> None:
        """``listener(back, ok, text)`` on every change of a back's port state."""
        self._port_listeners.append(listener)

    def add(self, health: ModuleHealth) -> ModuleHealth:
        if health.key in self._modules:
            raise ValueError(f"module {health.back}/{health.address} declared twice")
        self._modules[health.key] = health
        health.subscribe(self._forward)
        return health

    def get(self, back: str, address: int) -> ModuleHealth:
        return self._modules[(back, address)]

    def modules(self, back: str | None = None) -> list[ModuleHealth]:
        return [m for m in self._modules.values() if back is None or m.back == back]

    def subscribe(self, listener: Callable[[ModuleHealth, HealthEvent], None]) -> None:
        self._listeners.append(listener)

    def _forward(self, health: ModuleHealth, event: HealthEvent) -> None:
        for listener in list(self._listeners):
            try:
                listener(health, event)
            except Exception:
                log.exception("health listener failed for %s/%d", health.back, health.address)


@dataclass
class LineStats:
    """Statistics of one serial line's scheduler."""

    name: str
    cycles: int = 0
    last_cycle_time: float | None = None
    requests: int = 0
    errors: Counter[str] = field(default_factory=Counter)
    writes: int = 0
    port_losses: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "line": self.name,
            "cycles": self.cycles,
            "last_cycle_ms": None
            if self.last_cycle_time is None
            else round(self.last_cycle_time * 1000, 3),
            "requests": self.requests,
            "writes": self.writes,
            "port_losses": self.port_losses,
            "errors": {str(k): v for k, v in self.errors.items()},
        }
