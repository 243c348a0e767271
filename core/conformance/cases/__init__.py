"""Importing this package registers every case, profile by profile."""

from . import (  # noqa: F401
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
