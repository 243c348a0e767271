"""DeviceNet 11-bit CAN identifiers (Group 1-4) and the Predefined Master/Slave set.

Group 1 ``0 MMMM SSSSSS`` (source MAC), Group 2 ``10 MMMMMM mmm`` (MAC + 3-bit message
id), Group 3 ``11 mmm SSSSSS``, Group 4 ``11111 mmmmmm`` (0x7C0-0x7EF).
"""

from __future__ import annotations

# Group 1 message ids (slave -> master)
G1_COS_CYCLIC = 0xD
G1_STROBE_RESPONSE = 0xE
G1_POLL_RESPONSE = 0xF
# Group 2 message ids
G2_STROBE = 0  # MAC field = master's (source) MAC
G2_COS_ACK = 2
G2_EXPLICIT_RESPONSE = 3  # also heartbeat and shutdown
G2_EXPLICIT_REQUEST = 4
G2_POLL = 5
G2_UNCONNECTED_REQUEST = 6
G2_DUP_MAC = 7
# Group 4 (Offline Connection Set)
G4_FAULTED_RESPONSE = 0x2C
G4_FAULTED_REQUEST = 0x2D


def group1_id(message: int, mac: int) -> int:
    return 0x000 | (message & 0xF) << 6 | (mac & 0x3F)


def group2_id(mac: int, message: int) -> int:
    return 0x400 | (mac & 0x3F) << 3 | (message & 0x7)


def group3_id(message: int, mac: int) -> int:
    return 0x600 | (message & 0x7) << 6 | (mac & 0x3F)


def group4_id(message: int) -> int:
    return 0x7C0 | (message & 0x3F)


def decode(can_id: int) -> tuple[int, int, int | None]:
    """``(group, message id, MAC or None)``; group 0 for identifiers outside DeviceNet."""
    if not 0 <= can_id <= 0x7EF:
        return 0, 0, None
    if can_id < 0x400:
        return 1, can_id >> 6, can_id & 0x3F
    if can_id < 0x600:
        return 2, can_id & 0x7, (can_id >> 3) & 0x3F
    if can_id < 0x7C0:
        return 3, (can_id >> 6) & 0x7, can_id & 0x3F
    return 4, can_id & 0x3F, None
