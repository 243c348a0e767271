"""Network access (the engine's netaccess.py): the duplicate MAC ID check, answered and at a reset."""

from __future__ import annotations

import time

from ...dnet import (
    G2_DUP_MAC,
    RESET,
)
from ...framework import Context, Fail, Skip, case
from ...link import Frame
from .common import IDENTITY, TESTER_SERIAL, TESTER_VENDOR, P, dev, explicit


@case(
    P,
    "dup_mac_answer",
    "a duplicate MAC ID request for the device's MAC is answered with a response (vendor, serial)",
)
def dup_mac_answer(ctx: Context) -> None:
    d = dev(ctx)
    request = (
        bytes([0x00]) + TESTER_VENDOR.to_bytes(2, "little") + TESTER_SERIAL.to_bytes(4, "little")
    )
    d.link.flush()
    d.link.send(d.g2(G2_DUP_MAC), request)
    frame = d.link.expect(d.g2(G2_DUP_MAC), ctx.timing.response)
    if frame is None:
        raise Fail(
            "no duplicate MAC ID response",
            expected=f"{d.g2(G2_DUP_MAC):03X} [7] 80 <vendor> <serial>",
            seen="nothing",
        )
    if len(frame.data) != 7 or not frame.data[0] & 0x80:
        raise Fail(
            "malformed duplicate MAC ID response",
            expected="DLC 7, byte 0 bit 7 set (response)",
            seen=str(frame),
        )
    identity = explicit(ctx)
    vendor, serial = identity.get(IDENTITY, 1, 1), identity.get(IDENTITY, 1, 6)
    if frame.data[1:3] != vendor or frame.data[3:7] != serial:
        raise Fail(
            "duplicate MAC ID response does not carry the Identity vendor ID and serial number",
            expected=(vendor + serial).hex(" ").upper(),
            seen=str(frame),
        )


@case(
    P,
    "dup_mac_at_reset",
    "Identity Reset: the device restarts with two duplicate MAC ID requests, then is online again",
)
def dup_mac_at_reset(ctx: Context) -> None:
    d = explicit(ctx)
    reply = d.request(bytes([RESET, IDENTITY, 1]))
    if reply is None:
        raise Fail("no response to Identity Reset", expected="[hdr] 85", seen="nothing")
    if reply.service == 0x94 and reply.data[:1] == b"\x08":
        raise Skip(
            "the device does not support the Identity Reset service (0x08): the power-up check cannot be provoked over the bus"
        )
    if reply.service != RESET | 0x80:
        raise Fail(
            "wrong response to Identity Reset", expected="[hdr] 85", seen=str(reply.frames[-1])
        )
    requests: list[Frame] = []
    deadline = (
        time.monotonic() + ctx.timing.bootup + 2.5
    )  # DeviceNet: one second after each request
    while len(requests) < 2 and time.monotonic() < deadline:
        frame = d.link.expect(d.g2(G2_DUP_MAC), deadline - time.monotonic())
        if frame is not None:
            if len(frame.data) != 7 or frame.data[0] & 0x80:
                raise Fail(
                    "malformed duplicate MAC ID request",
                    expected="DLC 7, byte 0 = 00 (request)",
                    seen=str(frame),
                )
            requests.append(frame)
    if len(requests) < 2:
        raise Fail(
            "the restart did not send two duplicate MAC ID requests",
            expected=f"2 × {d.g2(G2_DUP_MAC):03X} [7] 00 ...",
            seen=f"{len(requests)}",
        )
    if not d.wait_online(ctx.timing.bootup + 1.5):
        raise Fail(
            "the device is not online again after its duplicate MAC ID check",
            expected="a response to Allocate",
            seen="nothing",
        )
