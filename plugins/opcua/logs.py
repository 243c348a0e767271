"""Log lines about clients' faults: one line each, and never a flood.

A client decides how often the server fails on its input: every refusal logged in full
would let it fill the disk (issue 29 measured 3.6 MB/s of 1,000-frame tracebacks). So:

* :class:`LogBudget` lets a given message through at most ``burst`` times per ``window``
  seconds; the lines it holds back are counted and the next line that passes says how many
  ("(37 similar lines suppressed)"). The front's counters have the exact numbers.
* :class:`ClientFaultFilter`, installed on asyncua's server loggers, turns a record with a
  traceback into one line (the exception's type and message appended) and applies a budget;
  asyncua's line for every ServiceFault it answers comes down from ERROR to INFO. A fault
  of ours still shows as the exception type and message in that line.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from fieldgate.plugin import one_line

# asyncua's loggers that speak of what clients send (their records pass through the filter)
ASYNCUA_SERVER_LOGGERS = (
    "asyncua.server.binary_server_asyncio",
    "asyncua.server.uaprocessor",
    "asyncua.server.internal_session",
    "asyncua.server.internal_server",
    "asyncua.server.internal_subscription",
    "asyncua.server.subscription_service",
    "asyncua.server.monitored_item_service",
    "asyncua.server.address_space",
    "asyncua.server.user_managers",
    "asyncua.uaprotocol",
    "asyncua.crypto.security_policies",
    "asyncua.crypto.uacrypto",
)

# asyncua logs every ServiceFault it answers at ERROR: a client's mistake (a wrong
# subscription id) is not the server's error; the front counts them by status
DEMOTED = ("sending service fault response",)


@dataclass
class LogBudget:
    """At most ``burst`` lines per key per ``window`` seconds (clock injectable)."""

    burst: int = 5
    window: float = 60.0
    clock: Callable[[], float] = time.monotonic
    _spent: dict[str, tuple[float, int, int]] = field(default_factory=dict)  # start, used, held

    def admit(self, key: str) -> tuple[bool, int]:
        """(may this line be logged, how many lines of this key were held back before it)."""
        now = self.clock()
        start, used, held = self._spent.get(key, (now, 0, 0))
        if now - start >= self.window:
            start, used = now, 0
        if used < self.burst:
            self._spent[key] = (start, used + 1, 0)
            return True, held
        self._spent[key] = (start, used, held + 1)
        if len(self._spent) > 1024:  # keys are message templates: few; never let them grow
            self._spent.pop(next(iter(self._spent)))
        return False, 0


class ClientFaultFilter(logging.Filter):
    """One line per record (no traceback) within a :class:`LogBudget` per message template."""

    def __init__(self, budget: LogBudget | None = None):
        super().__init__()
        self.budget = budget or LogBudget()

    def filter(self, record: logging.LogRecord) -> bool:
        key = f"{record.name}:{record.msg}"
        if isinstance(record.msg, str) and record.msg.startswith(DEMOTED):
            record.levelno, record.levelname = logging.INFO, "INFO"
        ok, held = self.budget.admit(key)
        if not ok:
            return False
        if record.exc_info and record.exc_info[1] is not None:
            record.msg = f"{record.getMessage()}: {one_line(record.exc_info[1])}"
            record.args = None
            record.exc_info = None
            record.exc_text = None
            record.stack_info = None
        if held:
            record.msg = f"{record.getMessage()} ({held} similar lines suppressed)"
            record.args = None
        return True


_FILTER = ClientFaultFilter()


def install() -> ClientFaultFilter:
    """Put the filter on asyncua's server loggers (idempotent; one filter per process)."""
    for name in ASYNCUA_SERVER_LOGGERS:
        logger = logging.getLogger(name)
        if _FILTER not in logger.filters:
            logger.addFilter(_FILTER)
    return _FILTER
