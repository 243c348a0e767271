"""DATA messages handed to the adapter and not yet confirmed by the broker.

Each DDATA, live or historical, gets a token. At QoS 1 its PUBACK confirms it; at QoS 0 a
:class:`~.actions.Sync` emitted after it does (the broker reads a connection's packets in
order). Until then a live message keeps its samples (journaled if the connection drops) and
a historical one its journal rows (deleted only when confirmed).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .actions import Sync
from .model import Sample


@dataclass
class InFlight:
    historical: bool
    samples: list[Sample] = field(default_factory=list)  # live: re-journaled when lost
    ids: list[int] = field(default_factory=list)  # historical: journal rows to delete
    qos: int = 0


class Delivery:
    def __init__(self) -> None:
        self.inflight: dict[int, InFlight] = {}
        self._token = 0
        self._unsynced: list[int] = []  # QoS 0 DATA tokens handed out since the last Sync
        self._sync_token: int | None = None  # the Sync awaiting on_synced
        self._sync_covers: list[int] = []  # the tokens it confirms

    def new_token(self) -> int:
        self._token += 1
        return self._token

    def track(self, flight: InFlight) -> int:
        """A token for a DATA message, remembered until confirmed, discarded or lost."""
        token = self.new_token()
        self.inflight[token] = flight
        if flight.qos == 0:
            self._unsynced.append(token)
        return token

    def sync(self) -> Sync | None:
        """A :class:`Sync` covering the QoS 0 DATA handed out, unless one is awaited."""
        if not self._unsynced or self._sync_token is not None:
            return None
        self._sync_token = self.new_token()
        self._sync_covers, self._unsynced = self._unsynced, []
        return Sync(self._sync_token)

    def synced(self, token: int) -> list[int] | None:
        """The tokens Sync ``token`` confirms; None for a Sync of a connection that is gone."""
        if token != self._sync_token:
            return None
        self._sync_token = None
        covered, self._sync_covers = self._sync_covers, []
        return covered

    def pop(self, token: int) -> InFlight | None:
        return self.inflight.pop(token, None)

    def historical(self) -> int:
        """Replayed messages not yet confirmed (the replay window counts them)."""
        return sum(1 for f in self.inflight.values() if f.historical)

    def drop_all(self) -> list[Sample]:
        """The connection is gone: forget everything; returns the live samples, oldest first."""
        lost: list[Sample] = []
        for token in sorted(self.inflight):
            flight = self.inflight[token]
            if not flight.historical:
                lost.extend(flight.samples)
        self.inflight.clear()
        self._unsynced.clear()
        self._sync_covers.clear()
        self._sync_token = None
        return lost
