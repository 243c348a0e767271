"""The COB-ID rules shared by every object that holds one (0x1005 SYNC, 0x1014 EMCY,
PDO communication sub 1).

* Only 11-bit identifiers: bit 29 (29-bit frame) and bits 11-28 set abort 0609 0030.
* CiA 301 restricted CAN-IDs (§7.3.5, table "restricted CAN-IDs") must not be used by a
  configurable COB-ID: 0x000, 0x001-0x07F, 0x101-0x180, 0x581-0x5FF, 0x601-0x67F,
  0x6E0-0x6FF, 0x701-0x77F, 0x780-0x7FF; writing one aborts 0609 0030 while the
  identifier is in use (a PDO or EMCY with bit 31 "invalid" set does not use it).
"""

from __future__ import annotations

from .abort import VALUE_RANGE, SdoAbort

EXTENDED_BIT = 1 << 29
NOT_11_BIT = EXTENDED_BIT | 0x1FFF_F800
RESTRICTED_CAN_IDS = (
    (0x000, 0x000),
    (0x001, 0x07F),
    (0x101, 0x180),
    (0x581, 0x5FF),
    (0x601, 0x67F),
    (0x6E0, 0x6FF),
    (0x701, 0x77F),
    (0x780, 0x7FF),
)


def restricted(can_id: int) -> bool:
    return any(lo <= can_id <= hi for lo, hi in RESTRICTED_CAN_IDS)


def check_cob_id(value: int, what: str, *, in_use: bool = True) -> int:
    """The 11-bit CAN-ID of ``value``; SdoAbort 0609 0030 when it breaks a rule above."""
    if value & NOT_11_BIT:
        raise SdoAbort(VALUE_RANGE, f"only 11-bit {what} COB-IDs are supported")
    can_id = value & 0x7FF
    if in_use and restricted(can_id):
        raise SdoAbort(
            VALUE_RANGE, f"{what} COB-ID 0x{can_id:03X} is a restricted CAN-ID (CiA 301)"
        )
    return can_id
