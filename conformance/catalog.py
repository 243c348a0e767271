"""The case modules, listed once, and the selection of cases from the registry.

Each module under :mod:`.cases` registers its cases with :func:`.framework.case` when it is
imported; this module imports them all (an explicit list: a new case module is added here),
so nothing below it depends on the cases. Add a module to the import line and to
``CASE_MODULES``.
"""

from __future__ import annotations

import fnmatch
from typing import TYPE_CHECKING

from .cases import (  # (the order the cases are registered: each module's after its imports)
    cia401,
    devicenet,
    emcy,
    errctl,
    icpdas,  # after profiles, whose icpdas cases it extends
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

if TYPE_CHECKING:
    from .identity import DeviceFacts

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
    icpdas,
)


def select(
    profiles: list[str] | None = None,
    patterns: list[str] | None = None,
    protocol: str = "canopen",
    facts: DeviceFacts | None = None,
) -> list[Case]:
    """Cases of the given profiles whose id matches any -k pattern. No profiles: every profile
    of the protocol but the device-specific ones (``seed``, ...); ``"all"``: with ``facts``
    (the device's EDS and identity, :mod:`.identity`) the CiA profiles its EDS supports and the
    device-specific ones its identity matches, without: every profile but the master-fit ones
    (``delta-as300``); a profile named beside ``all`` runs too."""
    available = PROTOCOL_PROFILES[protocol]
    if not profiles:
        wanted = set(available) - set(OPT_IN)
    elif "all" in profiles and facts is not None and protocol == "canopen":
        from .identity import chosen_profiles

        runs = {p for p, why in chosen_profiles(facts).items() if why.startswith("runs")}
        wanted = runs | (set(profiles) & set(available))
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
