"""The case modules, listed once, and the selection of cases from the registry.

Each module under :mod:`.cases` registers its cases with :func:`.framework.case` when it is
imported; this module imports them all (an explicit list: a new case module is added here),
so nothing below it depends on the cases. Add a module to the import line and to
``CASE_MODULES``.
"""

from __future__ import annotations

import fnmatch

from .cases import (
    cia401,
    devicenet,
    emcy,
    errctl,
    lss,
    mapping,
    monitoring,
    na9161,
    nmt,
    od,
    pdo,
    profiles,
    sdo,
    seed,
    store,
)
from .framework import (
    CASES,
    DEVICENET_PROFILES,
    MASTER_PROFILES,
    OPT_IN,
    PROFILES,
    PROTOCOL_PROFILES,
    Case,
)

CASE_MODULES = (
    cia401,
    devicenet,
    emcy,
    errctl,
    lss,
    mapping,
    monitoring,
    na9161,
    nmt,
    od,
    pdo,
    profiles,
    sdo,
    seed,
    store,
)


def select(
    profiles: list[str] | None = None, patterns: list[str] | None = None, protocol: str = "canopen"
) -> list[Case]:
    """Cases of the given profiles whose id matches any -k pattern. No profiles: every profile
    of the protocol but the opt-in ones (``seed``); ``"all"``: every profile of the protocol
    but the master-fit ones (``delta-as300``), which run only when named (beside ``all`` too)."""
    available = PROTOCOL_PROFILES[protocol]
    if not profiles:
        wanted = set(available) - set(OPT_IN)
    elif "all" in profiles:
        wanted = (set(available) - set(MASTER_PROFILES)) | (set(profiles) & set(available))
    else:
        wanted = set(profiles) & set(available)
    chosen = []
    for c in CASES.values():
        if c.profile not in wanted:
            continue
        if patterns and not any(_matches(c.id, p) for p in patterns):
            continue
        chosen.append(c)
    order = PROFILES + DEVICENET_PROFILES
    return sorted(chosen, key=lambda c: order.index(c.profile))


def _matches(case_id: str, pattern: str) -> bool:
    if any(ch in pattern for ch in "*?["):
        return fnmatch.fnmatchcase(case_id, pattern)
    return pattern in case_id
