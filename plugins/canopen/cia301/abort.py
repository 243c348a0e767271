"""SDO abort codes (CiA 301 table 22) and the exception that carries one."""

from __future__ import annotations

TOGGLE = 0x05030000
TIMEOUT = 0x05040000
BAD_COMMAND = 0x05040001
BAD_BLOCK_SIZE = 0x05040002
BAD_SEQUENCE = 0x05040003
CRC_ERROR = 0x05040004
OUT_OF_MEMORY = 0x05040005
UNSUPPORTED_ACCESS = 0x06010000
WRITE_ONLY = 0x06010001
READ_ONLY = 0x06010002
NO_OBJECT = 0x06020000
NOT_MAPPABLE = 0x06040041
PDO_TOO_LONG = 0x06040042
INCOMPATIBLE_PARAMETER = 0x06040043
INTERNAL_INCOMPATIBILITY = 0x06040047
HARDWARE_ERROR = 0x06060000
LENGTH_MISMATCH = 0x06070010
LENGTH_TOO_HIGH = 0x06070012
LENGTH_TOO_LOW = 0x06070013
NO_SUBINDEX = 0x06090011
VALUE_RANGE = 0x06090030
VALUE_TOO_HIGH = 0x06090031
VALUE_TOO_LOW = 0x06090032
MAX_BELOW_MIN = 0x06090036
GENERAL = 0x08000000
CANNOT_STORE = 0x08000020
LOCAL_CONTROL = 0x08000021
DEVICE_STATE = 0x08000022
NO_DICTIONARY = 0x08000023
NO_DATA = 0x08000024


class SdoAbort(Exception):
    """Raised by the object dictionary (or a validator/setter) to refuse an access."""

    def __init__(self, code: int, text: str = ""):
        super().__init__(f"SDO abort 0x{code:08X}" + (f": {text}" if text else ""))
        self.code = code


class Deferred(Exception):
    """Raised by the dictionary when an access waits on application code (a hook of an EDS
    device, :mod:`..device.hooks`): the SDO server holds its answer, keeps serving other
    channels and frames, and replays the request when :meth:`.sdo.SdoServer.resolve` is
    called with ``ticket``; at ``timeout_s`` it aborts with ``code`` instead."""

    def __init__(self, ticket: int, index: int, subindex: int, timeout_s: float, code: int):
        super().__init__(f"0x{index:04X}:{subindex} waits on ticket {ticket}")
        self.ticket = ticket
        self.index = index
        self.subindex = subindex
        self.timeout_s = timeout_s
        self.code = code
