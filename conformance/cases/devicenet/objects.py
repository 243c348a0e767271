"""The CIP objects (objects.py): Identity (single attributes and Get_Attributes_All), the DeviceNet object."""

from __future__ import annotations

from ...dnet import (
    CipErrorSeen,
    DnetDevice,
)
from ...framework import Context, Fail, Skip, case
from .common import DEVICENET, IDENTITY, IDENTITY_NAMES, IDENTITY_SIZES, P, explicit, short_string


@case(
    P,
    "identity",
    "Identity (class 1 instance 1): vendor, device type, product code, revision, status, serial, product name",
)
def identity(ctx: Context) -> None:
    d = explicit(ctx)
    for attribute, size in IDENTITY_SIZES.items():
        data = d.get(IDENTITY, 1, attribute)
        if len(data) != size:
            raise Fail(
                f"Identity attribute {attribute} ({IDENTITY_NAMES[attribute]}) has the wrong size",
                expected=f"{size} bytes",
                seen=data.hex(" ").upper() or "empty",
            )
    major, minor = d.get(IDENTITY, 1, 4)
    if not 1 <= major <= 127:
        raise Fail(
            "Identity revision: major revision out of range",
            expected="1..127",
            seen=f"{major}.{minor}",
        )
    name = short_string(d.get(IDENTITY, 1, 7), "Identity attribute 7 (product name)")
    if not 1 <= len(name) <= 32:
        raise Fail("product name length", expected="1..32 characters", seen=repr(name))


GET_ATTRIBUTES_ALL = 0x01


def identity_singles(d: DnetDevice) -> bytes:
    """Identity attributes 1-7 read one by one (Get_Attribute_Single), joined in attribute order."""
    return b"".join(d.get(IDENTITY, 1, attribute) for attribute in IDENTITY_NAMES)


@case(
    P,
    "identity_get_all",
    "Get_Attributes_All (0x01) of Identity instance 1 answers attributes 1-7 in the specification's order, equal to their Get_Attribute_Single answers (CIP Vol. 1 §5-2 Identity object)",
)
def identity_get_all(ctx: Context) -> None:
    """The response is vendor ID, device type, product code, revision (major, minor), status,
    serial number, product name (SHORT_STRING), nothing between them. Later CIP editions append
    further attributes (8 state, 9 configuration consistency value, 10 heartbeat interval) for
    devices that have them, so bytes after the product name are allowed. The status word may
    change between two reads: the singles are read before and after."""
    d = explicit(ctx)
    before = identity_singles(d)
    try:
        reply = d.call(
            GET_ATTRIBUTES_ALL, IDENTITY, 1, b"", "Get_Attributes_All of Identity instance 1"
        )
    except CipErrorSeen as err:
        if err.general == 0x08:
            raise Skip(
                "the device does not offer Get_Attributes_All on the Identity object (answers 0x08)"
            ) from None
        raise Fail(
            "Get_Attributes_All of Identity instance 1 refused",
            expected="[hdr] 81 <attributes 1-7>",
            seen=str(err.frame),
        ) from None
    after = identity_singles(d)
    answer = reply.data[: len(before)]
    if answer not in (before, after[: len(before)]) or len(reply.data) < len(before):
        names = ", ".join(IDENTITY_NAMES.values())
        raise Fail(
            f"Get_Attributes_All does not answer {names} in this order",
            expected=before.hex(" ").upper(),
            seen=reply.data.hex(" ").upper() or "empty",
        )


@case(
    P,
    "devicenet_object",
    "DeviceNet object (class 3 instance 1): MAC ID = the device's, baud rate code 0..2",
)
def devicenet_object(ctx: Context) -> None:
    d = explicit(ctx)
    mac, baud = d.get(DEVICENET, 1, 1), d.get(DEVICENET, 1, 2)
    if mac != bytes([d.mac_id]):
        raise Fail(
            "DeviceNet object attribute 1 (MAC ID)",
            expected=f"{d.mac_id:02X}",
            seen=mac.hex(" ").upper(),
        )
    if len(baud) != 1 or baud[0] > 2:
        raise Fail(
            "DeviceNet object attribute 2 (baud rate)",
            expected="one byte 0 (125k), 1 (250k) or 2 (500k)",
            seen=baud.hex(" ").upper(),
        )
