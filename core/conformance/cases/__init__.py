"""Importing this package registers every case, profile by profile."""

from . import (  # noqa: F401  # noqa: F401  (granularity and dummy entries; NA-9161 profile)
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
    sdo,
    seed,
    store,
)
