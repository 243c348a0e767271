"""Who may hold a connection or a session of the OPC UA front: budgets, never a lock-out.

Sans-I/O (time is passed in): the server asks :class:`Admission` when a connection opens,
when a session is created, and at each sweep; it answers which connections or sessions to
close and why. The rules, as the HTTP status server's (core/http/server.py):

* **A new connection is always accepted.** When its peer address holds more than
  ``max_connections_per_peer``, or the server more than ``max_connections``, one other
  connection gives way: of the peer itself when the peer is over its share, else of the
  peer holding the most connections (so a crowd from one address never pushes out another
  address's client). The one that gives way is the least useful: a connection without an
  activated session first (the oldest), then the one whose last message is the oldest. Only
  when no other connection exists to close is the new one refused.
* **A connection must send its Hello** within ``hello_timeout`` and activate a session
  within ``activation_timeout``, or it is closed: a silent socket holds its slot for
  seconds, not for as long as it likes.
* **Sessions** (those whose connection is gone included: asyncua keeps a session with
  subscriptions for its client to come back, Part 4 §6.7) follow the same rule at
  CreateSession with ``max_sessions_per_peer`` and ``max_sessions``: a detached session
  first, then the one idle longest.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Hashable, Iterable
from dataclasses import dataclass, field


@dataclass(frozen=True)
class AdmissionLimits:
    max_connections: int
    max_connections_per_peer: int
    max_sessions: int
    max_sessions_per_peer: int
    hello_timeout: float  # seconds from the connection to a complete Hello
    activation_timeout: float  # seconds from the connection to an activated session


@dataclass
class Slot:
    """A connection (or a session) the server holds."""

    key: Hashable
    peer: str
    opened: float
    last_message: float
    hello_done: bool = False
    activated: bool = False  # a connection: its session is activated
    attached: bool = True  # a session: its connection is still open

    def rank(self) -> tuple[int, float]:
        """Smaller gives way first: not activated (oldest), then idle longest."""
        if not self.activated:
            return (0, self.opened)
        if not self.attached:
            return (1, self.last_message)
        return (2, self.last_message)


@dataclass
class Admission:
    limits: AdmissionLimits
    connections: dict[Hashable, Slot] = field(default_factory=dict)
    sessions: dict[Hashable, Slot] = field(default_factory=dict)

    # -- connections ------------------------------------------------------------------------
    def open(self, key: Hashable, peer: str, now: float) -> list[tuple[Hashable, str]]:
        """A new connection: the connections to close (``(key, reason)``; the new one's own
        key with "too_many_connections" when nothing else could give way)."""
        self.connections[key] = Slot(key, peer, now, now)
        return _make_room(
            self.connections,
            key,
            peer,
            self.limits.max_connections_per_peer,
            self.limits.max_connections,
            "connection",
        )

    def hello(self, key: Hashable) -> None:
        if (slot := self.connections.get(key)) is not None:
            slot.hello_done = True

    def activated(self, key: Hashable) -> None:
        if (slot := self.connections.get(key)) is not None:
            slot.activated = True

    def message(self, key: Hashable, now: float) -> None:
        if (slot := self.connections.get(key)) is not None:
            slot.last_message = now

    def closed(self, key: Hashable) -> None:
        self.connections.pop(key, None)

    def expired(self, now: float) -> list[tuple[Hashable, str]]:
        """Connections past their Hello or activation deadline."""
        out = []
        for slot in self.connections.values():
            if not slot.hello_done and now - slot.opened > self.limits.hello_timeout:
                out.append((slot.key, "hello_timeout"))
            elif not slot.activated and now - slot.opened > self.limits.activation_timeout:
                out.append((slot.key, "activation_timeout"))
        return out

    # -- sessions ---------------------------------------------------------------------------
    def session(self, key: Hashable, peer: str, now: float) -> list[tuple[Hashable, str]]:
        """A session being created from ``peer``: the sessions to close first (the new one's
        own key with "too_many_sessions" when none could)."""
        self.sessions[key] = Slot(key, peer, now, now, hello_done=True)
        return _make_room(
            self.sessions,
            key,
            peer,
            self.limits.max_sessions_per_peer,
            self.limits.max_sessions,
            "session",
        )

    def register_session(self, key: Hashable, peer: str, now: float) -> None:
        """A session that was admitted (under a provisional key) and now exists."""
        self.sessions[key] = Slot(key, peer, now, now, hello_done=True)

    def session_state(
        self, key: Hashable, activated: bool, attached: bool, last_activity: float
    ) -> None:
        if (slot := self.sessions.get(key)) is not None:
            slot.activated = activated
            slot.attached = attached
            slot.last_message = last_activity

    def session_closed(self, key: Hashable) -> None:
        self.sessions.pop(key, None)

    def keep_sessions(self, alive: Iterable[Hashable]) -> None:
        """Forget the sessions that are no longer open (closed by timeout, by the client)."""
        keep = set(alive)
        for key in [k for k in self.sessions if k not in keep]:
            del self.sessions[key]

    def per_peer(self) -> dict[str, int]:
        return dict(Counter(s.peer for s in self.connections.values()))


def _make_room(
    slots: dict[Hashable, Slot], new: Hashable, peer: str, per_peer: int, total: int, what: str
) -> list[tuple[Hashable, str]]:
    victims: list[tuple[Hashable, str]] = []
    counts = Counter(s.peer for s in slots.values())
    if counts[peer] > per_peer:
        victim = _least_useful(s for s in slots.values() if s.peer == peer and s.key != new)
        if victim is None:
            return _refuse_new(slots, new, what)
        victims.append((victim.key, f"{what}_evicted"))
        counts[peer] -= 1
        del slots[victim.key]
    if len(slots) > total:
        crowded = max(counts, key=lambda p: (counts[p], p == peer))
        victim = _least_useful(s for s in slots.values() if s.peer == crowded and s.key != new)
        if victim is None:
            victim = _least_useful(s for s in slots.values() if s.key != new)
        if victim is None:
            return victims + _refuse_new(slots, new, what)
        victims.append((victim.key, f"{what}_evicted"))
        del slots[victim.key]
    return victims


def _refuse_new(
    slots: dict[Hashable, Slot], new: Hashable, what: str
) -> list[tuple[Hashable, str]]:
    del slots[new]
    return [(new, f"too_many_{what}s")]


def _least_useful(candidates: Iterable[Slot]) -> Slot | None:
    return min(candidates, key=Slot.rank, default=None)
