"""What a case and a device under test share: how a check fails or skips, and the timing knobs.

The bottom layer of the conformance tool: the devices (:mod:`.device`, :mod:`.dnet`) raise
these, the framework (:mod:`.framework`) turns them into verdicts. Imports nothing of the tool.
"""

from __future__ import annotations

from dataclasses import dataclass


class Fail(Exception):
    """The device does not do what the clause requires (``clause``: where the standard says so)."""

    def __init__(
        self,
        message: str,
        expected: str | None = None,
        seen: str | None = None,
        clause: str | None = None,
    ):
        super().__init__(message)
        self.message = message
        self.expected = expected
        self.seen = seen
        self.clause = clause


class Skip(Exception):
    """The case does not apply: an optional service or object is absent (say which, and why)."""


class Inconclusive(Exception):
    """A precondition of the case is not met (the device reports an error before the case, the
    bench lacks something it needs half-way): the case can neither pass nor fail."""


class Info(Exception):
    """Every requirement of the case was met, but the device does not do what the case's
    reading of the standard expects where the standard leaves room (an interpretation)."""

    def __init__(self, message: str, seen: str | None = None):
        super().__init__(message)
        self.message = message
        self.seen = seen


STOPPED_ANSWERING = "the device stopped answering"  # a note that ends a run's graded cases


class DeviceSilent(Exception):
    """The device does not answer at all: wrong node-ID, wrong bus, or not running."""


@dataclass
class Timing:
    """Timing knobs; every one has a command-line option."""

    response: float = 0.5  # how long to wait for an answer that must come
    silence: float = 0.3  # how long to watch for a frame that must not come
    tolerance_ms: float = 25.0  # absolute slack on measured periods and delays
    tolerance_pct: float = 15.0  # relative slack on measured periods and delays
    heartbeat_ms: int = 100  # producer time used by the heartbeat cases
    bootup: float = 2.0  # how long a reset may take until the boot-up message
    sdo_server_timeout: float = 2.0  # how long the server may take to abort a stalled transfer

    @property
    def server_wait(self) -> float:
        """How long to wait for an answer a server may give only when its own SDO timeout runs
        out (a block acknowledgement after a lost segment, an abort of a stalled transfer):
        its timeout (declared or given) plus the answer time; never less than ``response``."""
        return max(self.response, self.sdo_server_timeout + self.response)

    def slack(self, nominal_s: float) -> float:
        return self.tolerance_ms / 1000 + nominal_s * self.tolerance_pct / 100

    def within(self, measured_s: float, nominal_s: float) -> bool:
        return abs(measured_s - nominal_s) <= self.slack(nominal_s)
