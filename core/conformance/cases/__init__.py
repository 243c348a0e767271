"""Importing this package registers every case, profile by profile."""

from . import cia401, emcy, errctl, lss, nmt, od, pdo, sdo, seed, store  # noqa: F401
