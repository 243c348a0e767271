"""Restart delays of a supervised part: a front, a back, a north-facing child."""

from __future__ import annotations

MAX_BACKOFF = 60.0
STABLE_RUN_S = 60.0  # a part that ran this long before failing restarts after the first delay again


class Backoff:
    """Restart delays of one component: the topology's first delay, doubling on each
    failure up to MAX_BACKOFF (or the first delay, when that is longer), and back to the
    first after a run of STABLE_RUN_S without failure."""

    def __init__(self, first: float):
        self.first = self.delay = first
        self.cap = max(first, MAX_BACKOFF)

    def ran(self, seconds: float) -> None:
        """The component ran this long before it failed."""
        if seconds >= STABLE_RUN_S:
            self.delay = self.first

    def next(self) -> float:
        """The delay before the next restart attempt."""
        delay, self.delay = self.delay, min(self.delay * 2, self.cap)
        return delay
