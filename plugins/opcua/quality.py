"""fieldgate quality -> OPC UA StatusCode: the one table (docs/opcua.md, "Quality").

Plain numbers (OPC UA Part 4 §7.39 / Part 6 StatusCode.csv), so the table is library-free and
the tests check it against an independent client's names for the same codes.
"""

from __future__ import annotations

from fieldgate.image import Quality

GOOD = 0x0000_0000
UNCERTAIN_LAST_USABLE_VALUE = 0x4090_0000
UNCERTAIN_SUBSTITUTE_VALUE = 0x4091_0000
UNCERTAIN_ENGINEERING_UNITS_EXCEEDED = 0x4094_0000
# OPC DA's "Bad - Comm Failure" (the Bad_CommunicationFailure): OPC UA has no code of that
# name; the OPC Foundation's DA -> UA quality mapping gives Bad_NoCommunication. Bad_CommunicationError
# (0x80050000) is a fault of the UA connection itself, not of the data source.
BAD_NO_COMMUNICATION = 0x8031_0000
BAD_WAITING_FOR_INITIAL_DATA = 0x8032_0000
BAD_CONFIGURATION_ERROR = 0x8089_0000
LIMIT_LOW = 0x0100  # the value is at its low limit (Part 4 §7.39.2, LimitBits)
LIMIT_HIGH = 0x0200

STATUS_OF: dict[Quality, int] = {
    Quality.GOOD: GOOD,
    Quality.STALE: UNCERTAIN_LAST_USABLE_VALUE,  # last read failed; the value is the last good one
    Quality.COMM_FAULT: BAD_NO_COMMUNICATION,  # module offline or its back not running
    Quality.OVER_RANGE: UNCERTAIN_ENGINEERING_UNITS_EXCEEDED | LIMIT_HIGH,
    Quality.UNDER_RANGE: UNCERTAIN_ENGINEERING_UNITS_EXCEEDED | LIMIT_LOW,
    # the module sits in its host-watchdog safe state: its outputs hold their safe values, not
    # what was written; its inputs are read but the module is in a substitute state
    Quality.WATCHDOG: UNCERTAIN_SUBSTITUTE_VALUE,
    Quality.CONFIG_ERROR: BAD_CONFIGURATION_ERROR,  # the module does not match its declaration
    Quality.NOT_READ: BAD_WAITING_FOR_INITIAL_DATA,  # not read since the gateway started
}

NAMES: dict[int, str] = {
    GOOD: "Good",
    UNCERTAIN_LAST_USABLE_VALUE: "Uncertain_LastUsableValue",
    UNCERTAIN_SUBSTITUTE_VALUE: "Uncertain_SubstituteValue",
    UNCERTAIN_ENGINEERING_UNITS_EXCEEDED: "Uncertain_EngineeringUnitsExceeded",
    BAD_NO_COMMUNICATION: "Bad_NoCommunication",
    BAD_WAITING_FOR_INITIAL_DATA: "Bad_WaitingForInitialData",
    BAD_CONFIGURATION_ERROR: "Bad_ConfigurationError",
}


def status_code(quality: Quality) -> int:
    return STATUS_OF[quality]


def status_name(code: int) -> str:
    """``Uncertain_EngineeringUnitsExceeded (High)``: the code's name with its limit bits."""
    name = NAMES.get(code & 0xFFFF_0000, f"0x{code:08X}")
    limit = code & (LIMIT_LOW | LIMIT_HIGH)
    if limit == LIMIT_HIGH:
        return f"{name} (High)"
    if limit == LIMIT_LOW:
        return f"{name} (Low)"
    return name
