"""Allocate / Release of the Predefined Master/Slave Connection Set (allocation.py): the explicit connection, conflicts, validation."""

from __future__ import annotations

from ...dnet import (
    ALLOCATE,
    CHOICE_EXPLICIT,
    CHOICE_POLL,
    GET,
    CipErrorSeen,
    status_text,
)
from ...framework import Context, Fail, case
from .common import DEVICENET, P, dev, explicit


@case(
    P,
    "allocate_explicit",
    "Allocate explicit through the Group 2 Only unconnected port: [master MAC] CB <body format>",
)
def allocate_explicit(ctx: Context) -> None:
    d = dev(ctx)
    frame = d.allocate(CHOICE_EXPLICIT)
    data = frame.data
    if len(data) != 3 or data[0] != d.master_mac or data[2] > 0x03:
        raise Fail(
            "wrong Allocate response",
            expected=f"{d.g2(3):03X} [3] {d.master_mac:02X} CB <0..3>",
            seen=str(frame),
        )
    choice = d.get(DEVICENET, 1, 5)
    if len(choice) != 2 or not choice[0] & CHOICE_EXPLICIT or choice[1] != d.master_mac:
        raise Fail(
            "DeviceNet object attribute 5 does not show the allocation",
            expected=f"choice with bit 0, master {d.master_mac:02X}",
            seen=choice.hex(" ").upper(),
        )


@case(
    P,
    "allocate_conflict",
    "a second Allocate of the same connection, or by another master, is refused (0x0B / 0x0C)",
)
def allocate_conflict(ctx: Context) -> None:
    d = explicit(ctx)
    for choice, master, codes, what in (
        (CHOICE_EXPLICIT, None, (0x0B,), "explicit allocated twice"),
        (CHOICE_EXPLICIT, (d.master_mac + 1) & 0x3F, (0x0C,), "Allocate by another master"),
    ):
        try:
            frame = d.allocate(choice, master=master)
        except CipErrorSeen as err:
            if err.general not in codes:
                raise Fail(
                    f"{what}: wrong general status",
                    expected=" or ".join(status_text(c) for c in codes),
                    seen=str(err.frame),
                ) from None
            continue
        raise Fail(f"{what}: accepted", expected="an error response [hdr] CB→94", seen=str(frame))


@case(
    P,
    "allocate_validation",
    "invalid Allocate choices are refused 09/02, other services on the unconnected port 02/03",
)
def allocate_validation(ctx: Context) -> None:
    d = dev(ctx)
    for choice, what in (
        (0x00, "Allocate with choice 0"),
        (0x41, "ack suppression without COS or cyclic"),
        (CHOICE_POLL, "poll without the explicit connection"),
    ):
        d.expect_unconnected_error(ALLOCATE, bytes([choice, d.master_mac]), (0x09, 0x02), what)
    d.expect_unconnected_error(
        GET, bytes([1]), (0x02, 0x03), "Get_Attribute_Single on the Group 2 Only unconnected port"
    )
