"""Honouring a cancellation that a library swallowed.

Python 3.11's ``asyncio.wait_for`` drops a cancellation that arrives together with the
result it waits for (fixed in 3.12 by its rewrite on ``asyncio.timeout``); pymodbus waits
for every reply that way, so stopping a Modbus line can go unnoticed and the line polls
on. The task's own count of cancel requests (``Task.cancelling()``) still says it was
asked to stop: long-running loops call :func:`raise_if_cancelled` after each step, and
the runtime cancels again a task that goes on (``Gateway._cancel``).
"""

from __future__ import annotations

import asyncio


def raise_if_cancelled() -> None:
    """Raise CancelledError when the current task was cancelled and something swallowed it."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError
