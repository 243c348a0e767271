"""Stopping a long-running command: SIGINT and SIGTERM as an event, and an optional time limit.

Ctrl-C (or a service manager's SIGTERM) is how ``fieldgate run`` and the simulators are
normally stopped: the command cleans up and exits 0, with no traceback. Where the loop
cannot take signal handlers (Windows), Ctrl-C raises KeyboardInterrupt instead, which the
command line turns into its exit code.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Iterator


@contextlib.contextmanager
def stopped_by_signals() -> Iterator[asyncio.Event]:
    """An event that SIGINT and SIGTERM set while the block runs (in the running loop)."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    handled = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
        except (NotImplementedError, RuntimeError):
            continue
        handled.append(sig)
    try:
        yield stop
    finally:
        for sig in handled:
            loop.remove_signal_handler(sig)


async def wait_until(stop: asyncio.Event, duration: float | None) -> None:
    """Until ``stop`` is set or ``duration`` seconds have passed (None or 0: no limit)."""
    try:
        await asyncio.wait_for(stop.wait(), duration or None)
    except TimeoutError:
        pass
