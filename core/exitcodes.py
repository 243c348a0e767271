"""The exit codes of every ``fieldgate`` command, in one place.

What each means is the table "Exit codes" in README.md; tests/core/test_core_exit_codes.py
checks that table against this enum and that commands return these, never bare numbers.
A plugin's commands use them too.
"""

from __future__ import annotations

from enum import IntEnum


class ExitCode(IntEnum):
    OK = 0  # done
    FAILED = 1  # the answer is no: invalid topology, not ready, none found, a plugin failed
    CANNOT_RUN = 2  # could not run: a start failure, unreachable, a wrong command line
    INTERRUPTED = 130  # Ctrl-C before it finished (128 + SIGINT): a partial result
