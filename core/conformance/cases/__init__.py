"""Importing this package registers every case, profile by profile."""

from . import cia401, devicenet, emcy, errctl, lss, monitoring, nmt, od, pdo, sdo, seed, store  # noqa: F401
from . import mapping, na9161  # noqa: F401  (granularity and dummy entries; NA-9161 profile)
