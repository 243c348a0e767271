"""Gateway events for people and monitoring: module offline/online, master lost/back, NMT
state changes, EMCY sent, bus-off, ... (protocol-neutral).

Fronts and backs publish through ``context.events.publish(kind, source, text, **data)``;
core itself publishes module health and master state. Subscribers (the HTTP event stream)
get each event synchronously on the event loop; the hub keeps the last ``history`` events
for a page that opens later. Publishing costs a deque append and one call per subscriber:
events are rare (state changes), never per frame.
"""

from __future__ import annotations

import logging
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger("fieldgate.events")

HISTORY = 200

# The kinds fieldgate's own components publish (plugins may add their own).
MODULE_OFFLINE = "module-offline"
MODULE_ONLINE = "module-online"
MASTER_LOST = "master-lost"
MASTER_BACK = "master-back"
NMT_STATE = "nmt-state"
EMCY_SENT = "emcy-sent"
BUS_OFF = "bus-off"
BUS_ON = "bus-recovered"
CAN_STATE = "can-state"  # the CAN controller's error state: error-active, warning, passive
CAN_OVERRUN = "can-overrun"  # frames lost: a receive, transmit or controller queue overran
PORT_LOST = "port-lost"  # a back's serial port is missing or failed: its modules are offline
PORT_BACK = "port-back"
FAULT = "fault"  # a front stopped communicating by itself (DeviceNet duplicate MAC ID, ...)
COMPONENT_FAILED = "component-failed"
COMPONENT_RESTARTED = "component-restarted"

WARNING_KINDS = frozenset(
    {MODULE_OFFLINE, MASTER_LOST, BUS_OFF, CAN_OVERRUN, PORT_LOST, COMPONENT_FAILED, FAULT}
)


@dataclass(frozen=True)
class Event:
    seq: int
    time: float  # wall clock (seconds since the epoch), for display
    kind: str
    source: str  # component or module, e.g. "can" or "rs485/m3"
    text: str
    data: dict[str, Any] = field(default_factory=dict)

    @property
    def level(self) -> str:
        return "warning" if self.kind in WARNING_KINDS else "info"

    def as_dict(self) -> dict[str, Any]:
        return {
            "seq": self.seq,
            "time": self.time,
            "kind": self.kind,
            "level": self.level,
            "source": self.source,
            "text": self.text,
            "data": self.data,
        }


Listener = Callable[[Event], None]


class EventHub:
    """Publish/subscribe of :class:`Event` on the event loop, with a short history."""

    def __init__(self, history: int = HISTORY, wall: Callable[[], float] = time.time):
        self._recent: deque[Event] = deque(maxlen=history)
        self._listeners: list[Listener] = []
        self._wall = wall
        self._seq = 0
        self.counts: Counter[str] = Counter()

    def publish(self, kind: str, source: str, text: str, **data: Any) -> Event:
        self._seq += 1
        event = Event(self._seq, self._wall(), kind, source, text, data)
        self._recent.append(event)
        self.counts[kind] += 1
        self._tell(event)
        return event

    def mirror(self, event: Event) -> None:
        """Take an event another process's hub published, as it was (seq, time): a
        north-facing child's copy of the fieldbus process's events."""
        self._seq = max(self._seq, event.seq)
        self._recent.append(event)
        self.counts[event.kind] += 1
        self._tell(event)

    def _tell(self, event: Event) -> None:
        for listener in list(self._listeners):
            try:
                listener(event)
            except Exception:  # a bad subscriber never stops the publisher (a CAN engine)
                log.exception("event listener %r failed", listener)

    def subscribe(self, listener: Listener) -> Callable[[], None]:
        """Call ``listener(event)`` for every event from now on; returns the unsubscribe call."""
        self._listeners.append(listener)

        def cancel() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return cancel

    def recent(self, limit: int | None = None) -> list[Event]:
        events = list(self._recent)
        return events if limit is None else events[-limit:]
