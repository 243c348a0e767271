"""What a process costs, read from /proc (Linux; elsewhere: nothing): resident memory and CPU
time, of this process or a child. The status API shows them for the fieldbus process and
each north-facing child; a child over its memory limit is killed on these figures."""

from __future__ import annotations

import os
from typing import Any

PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def resident_bytes(pid: int | str = "self") -> int | None:
    """Resident set of a process in bytes, or None when /proc cannot say."""
    try:
        with open(f"/proc/{pid}/statm", "rb") as f:
            return int(f.read().split()[1]) * PAGE
    except (OSError, ValueError, IndexError):
        return None


def cpu_seconds(pid: int | str = "self") -> float | None:
    """User and system CPU time of a process in seconds, or None when /proc cannot say."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / TICKS
    except (OSError, ValueError, IndexError):
        return None


def own_process() -> dict[str, Any]:
    """This process (the fieldbus process) for the status API."""
    rss = resident_bytes()
    cpu = cpu_seconds()
    return {
        "pid": os.getpid(),
        "rss_mb": None if rss is None else round(rss / 2**20, 1),
        "cpu_s": None if cpu is None else round(cpu, 2),
    }
