"""Node guarding and life guarding (CiA 301 §7.2.8.3.1), sans-I/O.

* Node guarding: an RTR on 0x700+ID is answered ``[toggle<<7 | state]`` with DLC 1; the
  toggle is 0 in the first answer after boot-up / reset communication. While the
  heartbeat producer time 0x1017 is non-zero, CiA 301 says heartbeat replaces guarding:
  guard RTRs are then counted and not answered, and life guarding is off (error control,
  :mod:`.errctl`, decides that).
* Life guarding: with guard time 0x100C (ms) and life time factor 0x100D both non-zero,
  the node life time starts at the first guard RTR; when it passes with no further RTR,
  the master is lost (error control raises the EMCY and applies 0x1029).
"""

from __future__ import annotations

from .od import Dictionary

GUARD_TIME, LIFE_TIME_FACTOR = 0x100C, 0x100D


class Guarding:
    """The guarding state of one node: the toggle bit and the life time deadline."""

    def __init__(self, od: Dictionary):
        self.od = od
        self.toggle = 0
        self.life_deadline: float | None = None

    def reset(self) -> None:
        """Reset communication: the next answer has toggle 0, life guarding waits for an RTR."""
        self.toggle = 0
        self.life_deadline = None

    def life_time_s(self) -> float:
        return self.od.integer(GUARD_TIME) * self.od.integer(LIFE_TIME_FACTOR) / 1000.0

    def answer(self, state: int) -> bytes:
        """The answer to a guard RTR (the toggle flips for the next one)."""
        data = bytes([(self.toggle << 7) | state])
        self.toggle ^= 1
        return data

    def rearm(self, now: float, started: bool = False) -> None:
        """A guard RTR (``started``) or new guarding settings: the life time runs again."""
        if not started and self.life_deadline is None:
            return  # not started yet: the first guard RTR starts it
        life = self.life_time_s()
        self.life_deadline = now + life if life > 0 else None

    def stop(self) -> None:
        """Guarding switched off: a later first RTR starts the life time again."""
        self.life_deadline = None

    def expired(self, now: float) -> bool:
        """The life time passed without an RTR (once: the deadline is dropped)."""
        if self.life_deadline is not None and now >= self.life_deadline:
            self.life_deadline = None
            return True
        return False
