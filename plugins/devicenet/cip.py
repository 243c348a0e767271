"""CIP general status codes, service codes and the error a request handler raises."""

from __future__ import annotations

# general status codes
RESOURCE_UNAVAILABLE = 0x02
SERVICE_NOT_SUPPORTED = 0x08
INVALID_ATTRIBUTE_VALUE = 0x09
ALREADY_IN_STATE = 0x0B
OBJECT_STATE_CONFLICT = 0x0C
ATTRIBUTE_NOT_SETTABLE = 0x0E
DEVICE_STATE_CONFLICT = 0x10
REPLY_DATA_TOO_LARGE = 0x11
NOT_ENOUGH_DATA = 0x13
ATTRIBUTE_NOT_SUPPORTED = 0x14
TOO_MUCH_DATA = 0x15
OBJECT_DOES_NOT_EXIST = 0x16
INVALID_PARAMETER = 0x20
ATTRIBUTE_NOT_GETTABLE = 0x2C
NO_ADDITIONAL = 0xFF

# DeviceNet object additional codes (allocation)
ALLOCATION_CONFLICT = 0x01
INVALID_ALLOCATION_CHOICE = 0x02
INVALID_UNCONNECTED_REQUEST = 0x03
POLL_AFTER_COS_CYCLIC = 0x04  # seed-003 §2.10; ODVA: resource for the predefined set unavailable

# services
GET_ATTRIBUTES_ALL = 0x01
RESET = 0x05
GET_ATTRIBUTE_SINGLE = 0x0E
SET_ATTRIBUTE_SINGLE = 0x10
ERROR_RESPONSE = 0x14
ALLOCATE = 0x4B
RELEASE = 0x4C
HEARTBEAT = 0x4D
SHUTDOWN = 0x4E
RESPONSE = 0x80


class CipError(Exception):
    """A request failed: answered ``[hdr] 94 <general> <additional>``."""

    def __init__(self, general: int, additional: int = NO_ADDITIONAL):
        super().__init__(f"CIP error {general:02X}/{additional:02X}")
        self.general = general
        self.additional = additional
