"""Explicit messaging (explicit.py): CIP errors for unknown services, objects, attributes, read-only attributes; fragmented responses."""

from __future__ import annotations

from ...dnet import (
    GET,
    SET,
)
from ...framework import Context, Fail, Skip, case
from .common import IDENTITY, P, explicit, short_string


@case(P, "error_unknown_service", "a service the object does not offer is refused with 0x08")
def error_unknown_service(ctx: Context) -> None:
    explicit(ctx).expect_error(
        bytes([0x06, IDENTITY, 1]), (0x08,), "Start (0x06) to the Identity object"
    )


@case(P, "error_unknown_object", "an unknown class or instance is refused with 0x16 (or 0x05)")
def error_unknown_object(ctx: Context) -> None:
    d = explicit(ctx)
    d.expect_error(bytes([GET, 0xC8, 1, 1]), (0x16, 0x05), "Get of reserved class 0xC8")
    d.expect_error(bytes([GET, IDENTITY, 0x7F, 1]), (0x16, 0x05), "Get of Identity instance 0x7F")


@case(P, "error_unknown_attribute", "an unknown attribute is refused with 0x14")
def error_unknown_attribute(ctx: Context) -> None:
    explicit(ctx).expect_error(
        bytes([GET, IDENTITY, 1, 0x63]), (0x14,), "Get of Identity attribute 99"
    )


@case(
    P, "error_read_only", "a Set of a read-only attribute (Identity vendor ID) is refused with 0x0E"
)
def error_read_only(ctx: Context) -> None:
    d = explicit(ctx)
    vendor = d.get(IDENTITY, 1, 1)
    d.expect_error(bytes([SET, IDENTITY, 1, 1]) + vendor, (0x0E,), "Set of Identity vendor ID")


@case(
    P,
    "fragmented_response",
    "a long attribute (product name) comes as acknowledged fragments: first, middle, last, counts in order",
)
def fragmented_response(ctx: Context) -> None:
    d = explicit(ctx)
    reply = d.call(GET, IDENTITY, 1, bytes([7]), "Get of the product name")
    if len(reply.frames) == 1:
        raise Skip(
            f"the product name ({len(reply.data) - 1} characters) fits one frame: no long attribute to read"
        )
    name = short_string(reply.data, "the reassembled product name")
    if len(reply.frames) != (len(name) + 2 + 5) // 6:
        raise Fail(
            "fragment count",
            expected=f"{(len(name) + 2 + 5) // 6} fragments of 6 bytes",
            seen=f"{len(reply.frames)}",
        )
