"""What the DeviceNet cases share: the device, its allocation, connection attributes, identifiers."""

from __future__ import annotations

from ...dnet import (
    CHOICE_EXPLICIT,
    CHOICE_POLL,
    CipErrorSeen,
    DnetDevice,
    status_text,
)
from ...framework import Context, Fail, Skip

P = "devicenet"


IDENTITY, DEVICENET, CONNECTION = 0x01, 0x03, 0x05


POLL_INSTANCE = 2


STATE_ESTABLISHED, STATE_TIMED_OUT = 3, 4


TESTER_VENDOR, TESTER_SERIAL = (
    0xFFFE,
    0x7E57C0DE,
)  # the tester's "own" identity in a duplicate MAC ID request


IDENTITY_SIZES = {1: 2, 2: 2, 3: 2, 4: 2, 5: 2, 6: 4}


IDENTITY_NAMES = {
    1: "vendor ID",
    2: "device type",
    3: "product code",
    4: "revision",
    5: "status",
    6: "serial number",
    7: "product name",
}


def dev(ctx: Context) -> DnetDevice:
    return ctx.dnet


def explicit(ctx: Context) -> DnetDevice:
    d = dev(ctx)
    d.allocate(CHOICE_EXPLICIT)
    return d


def short_string(data: bytes, what: str) -> str:
    if not data or data[0] != len(data) - 1:
        raise Fail(
            f"{what} is not a SHORT_STRING (length byte + characters)",
            seen=data.hex(" ").upper() or "empty",
        )
    return data[1:].decode("latin-1")


def io_sizes(d: DnetDevice, instance: int) -> tuple[int, int]:
    produced = int.from_bytes(d.get(CONNECTION, instance, 7), "little")
    consumed = int.from_bytes(d.get(CONNECTION, instance, 8), "little")
    return produced, consumed


def allocate_poll(d: DnetDevice) -> None:
    """Explicit + poll, or SKIP if the device refuses poll as unsupported."""
    try:
        d.allocate(CHOICE_EXPLICIT | CHOICE_POLL)
    except CipErrorSeen as err:
        if err.general in (0x02, 0x09):
            raise Skip(
                f"the device refuses a poll connection ({status_text(err.general)}): poll not supported"
            ) from None
        raise Fail(
            "Allocate explicit + poll refused", expected="[hdr] CB 00", seen=str(err.frame)
        ) from None


def set_epr(d: DnetDevice, instance: int, ms: int) -> int:
    granted = d.set(CONNECTION, instance, 9, ms.to_bytes(2, "little"))
    value = int.from_bytes(granted, "little") if len(granted) == 2 else None
    if value is None or value < ms:
        raise Fail(
            "Set expected packet rate: the response must carry the granted rate (≥ the requested one)",
            expected=f"2 bytes ≥ {ms}",
            seen=granted.hex(" ").upper() or "empty",
        )
    return value


# -- I/O connection paths, change of state / cyclic both ways, the I-7241D's object 0x64 ------
STROBE_INSTANCE, COS_INSTANCE = 3, 4


ASSEMBLY = 0x04


APPLICATION = 0x64


def number(data: bytes) -> int:
    return int.from_bytes(data, "little")
