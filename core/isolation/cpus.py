"""CPU placement of the fieldbus process and its north-facing children (``gateway.isolation``
``fieldbus_cpus``, ``north_cpus``; docs/architecture.md, "Process layout").

Niceness decides who runs first on a shared CPU; it cannot stop the kernel's work for a
flood of connections (accepts, closes, the loopback's softirqs) from landing on the CPU the
fieldbus process needs. Pinning gives the fieldbus process CPUs of its own: the children and
the network work they cause stay on the others (bench/isolation.py ``--fieldbus-cpus``).

Linux keeps an affinity mask per thread: the fieldbus process pins every thread it has, and
threads started later inherit the mask of the thread that starts them. A child is forked
from a thread moved onto its CPUs (``supervisor._popen_on``), so it is born there, and sets
them again first thing (``apply_north``), which is where a CPU the host refuses is reported.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from typing import Any

log = logging.getLogger("fieldgate.isolation")

_before_pinning: set[int] | None = None  # the fieldbus process's CPUs before it pinned itself


def allowed() -> set[int]:
    """The CPUs this process may run on (its cgroup's and its parent's choice)."""
    return set(os.sched_getaffinity(0))


def pin_process(cpus: Iterable[int]) -> None:
    """Every thread of this process onto ``cpus`` (``sched_setaffinity`` is per thread)."""
    mask = set(cpus)
    tids = (
        [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else [0]
    )
    for tid in tids:
        try:
            os.sched_setaffinity(tid, mask)
        except ProcessLookupError:  # a thread that ended meanwhile
            continue


def apply_fieldbus(settings: Any) -> None:
    """Pin the fieldbus process to ``fieldbus_cpus`` when given; CPUs this process may not use
    are one warning line and it runs on where it was (never a failed start)."""
    global _before_pinning
    _before_pinning = None  # a gateway started before in this process says nothing of this one
    wanted = settings.fieldbus_cpus
    if not wanted:
        return
    have = allowed()
    missing = sorted(set(wanted) - have)
    if missing:
        log.warning(
            "gateway.isolation.fieldbus_cpus %s: CPU %s not available here (allowed: %s); "
            "the fieldbus process runs on all of them",
            cpu_list_text(wanted),
            cpu_list_text(missing),
            cpu_list_text(have),
        )
        return
    _before_pinning = have
    pin_process(wanted)
    log.info("fieldbus process pinned to CPU %s", cpu_list_text(wanted))


def north_set(settings: Any) -> list[int] | None:
    """The CPUs a north-facing child should run on: ``north_cpus`` when given; else, when the
    fieldbus process pinned itself, every CPU it had but those (all of them on a host with no
    other); else None (the child keeps what it inherits)."""
    if settings.north_cpus:
        return sorted(settings.north_cpus)
    if _before_pinning is None:
        return None
    rest = _before_pinning - set(settings.fieldbus_cpus)
    return sorted(rest or _before_pinning)


def apply_north(cpus: list[int] | None) -> None:
    """In a child, before it starts any thread: run on ``cpus`` (the mask it inherited is the
    fieldbus process's, so it is no guide; the kernel refuses CPUs the cgroup does not give)."""
    if not cpus:
        return
    try:
        pin_process(cpus)
    except OSError as exc:
        log.warning(
            "gateway.isolation.north_cpus %s: not available here (%s); left on CPU %s",
            cpu_list_text(cpus),
            exc.strerror or exc,
            cpu_list_text(allowed()),
        )


def cpu_list_text(cpus: Iterable[int]) -> str:
    """{2, 0} -> '0,2': a set of CPUs as the settings and the log show it."""
    return ",".join(str(c) for c in sorted(cpus))
