"""Logging of every fieldgate process: the text or JSON format, and for north-facing children
a budget, so a client that makes a library log a traceback per request cannot fill the
journal (docs/architecture.md, "Process layout").
"""

from __future__ import annotations

import logging
import sys
import time
import traceback
from collections.abc import Callable
from types import TracebackType
from typing import Any

LOG_FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"
LOG_FORMATS = ("text", "json")
TRACEBACK_FRAMES = 8  # the innermost frames a budgeted process logs of a traceback

ExcInfo = tuple[type[BaseException], BaseException, TracebackType | None]


def setup_logging(
    level: str, fmt: str = "text", *, budget: LogBudget | None = None, prefix: str = ""
) -> None:
    """The root logger on standard error in ``fmt`` (text or json). With ``budget`` (a child):
    at most its lines per window, tracebacks cut to their innermost frames; ``prefix`` goes
    before every logger name (``opcua[1234]:``) so the journal tells the processes apart."""
    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format=LOG_FORMAT.replace("%(name)s", f"{prefix}%(name)s"),
        stream=sys.stderr,
        force=True,
    )
    for handler in logging.getLogger().handlers:
        base: type[logging.Formatter] = logging.Formatter
        if fmt == "json":
            from .logjson import JsonFormatter

            base = JsonFormatter
        if budget is not None:
            handler.addFilter(budget)
            base = _short_tracebacks(base)
        handler.setFormatter(base(handler.formatter._fmt if handler.formatter else None))


def _short_tracebacks(base: type[logging.Formatter]) -> type[logging.Formatter]:
    """``base`` writing only the innermost frames of a traceback."""

    class Short(base):  # type: ignore[valid-type,misc]  # a class made from a variable base
        def formatException(self, ei: Any) -> str:  # noqa: N802  (logging's name)
            return _short_traceback(ei) if ei and ei[1] is not None else ""

    return Short


def _short_traceback(exc_info: ExcInfo) -> str:
    """The innermost frames of a traceback: a RecursionError is one line and a few frames,
    not a thousand."""
    _, exc, tb = exc_info
    frames = traceback.extract_tb(tb)
    skipped = len(frames) - TRACEBACK_FRAMES
    lines = ["Traceback (innermost frames):\n"]
    if skipped > 0:
        lines.append(f"  ... {skipped} outer frame(s) left out\n")
    lines += traceback.format_list(frames[-TRACEBACK_FRAMES:])
    lines += traceback.format_exception_only(type(exc), exc)
    return "".join(lines).rstrip("\n")


class LogBudget(logging.Filter):
    """At most ``lines`` records per ``window_s`` (warnings and errors first: a burst of debug
    lines never hides one); what goes over is counted, and the first record after the window
    says how many were left out."""

    def __init__(
        self, lines: int, window_s: float = 60.0, clock: Callable[[], float] = time.monotonic
    ):
        super().__init__()
        self.lines = lines
        self.window_s = window_s
        self.clock = clock
        self.suppressed_total = 0
        self._window_start = clock()
        self._used = 0
        self._suppressed = 0

    def filter(self, record: logging.LogRecord) -> bool:
        now = self.clock()
        if now - self._window_start >= self.window_s:
            self._window_start, self._used = now, 0
            if self._suppressed:
                record.msg = (
                    f"[{self._suppressed} log line(s) left out in the last "
                    f"{self.window_s:.0f} s: over the budget of {self.lines}] {record.msg}"
                )
                self._suppressed = 0
        reserve = self.lines // 4 if record.levelno < logging.WARNING else 0
        if self._used >= self.lines - reserve:
            self._suppressed += 1
            self.suppressed_total += 1
            return False
        self._used += 1
        return True


def current_settings() -> tuple[str, str]:
    """(level, format) of this process's logging, for a child to log the same way."""
    root = logging.getLogger()
    level = logging.getLevelName(root.getEffectiveLevel()).lower()
    fmt = "text"
    for handler in root.handlers:
        if type(handler.formatter).__name__ == "JsonFormatter":
            fmt = "json"
    return (level if level in ("debug", "info", "warning", "error") else "info"), fmt
