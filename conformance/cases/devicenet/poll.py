"""Poll I/O (io_messaging.py): sizes, the response to each poll, outputs looped back to inputs."""

from __future__ import annotations

import time

from ...framework import Context, Fail, Skip, case
from .common import (
    CONNECTION,
    POLL_INSTANCE,
    STATE_ESTABLISHED,
    P,
    allocate_poll,
    dev,
    io_sizes,
    set_epr,
)


@case(
    P,
    "poll_io",
    "allocate poll, set its expected packet rate; a poll of the consumed size answers the produced size",
)
def poll_io(ctx: Context) -> None:
    d = dev(ctx)
    allocate_poll(d)
    produced, consumed = io_sizes(d, POLL_INSTANCE)
    granted = set_epr(d, POLL_INSTANCE, 1000)
    if int.from_bytes(d.get(CONNECTION, POLL_INSTANCE, 9), "little") != granted:
        raise Fail("expected packet rate does not read back as granted", expected=str(granted))
    state = d.get(CONNECTION, POLL_INSTANCE, 1)
    if state != bytes([STATE_ESTABLISHED]):
        raise Fail(
            "poll connection not Established after its EPR was set",
            expected="state 3",
            seen=state.hex(),
        )
    first = d.poll(bytes(consumed))  # all-zero outputs: the safe value
    if first is None:
        raise Fail(
            "no poll response",
            expected=f"{d.poll_response_id:03X} with {produced} bytes",
            seen="nothing",
        )
    data = d.poll_fragments(first, produced)
    if len(data) != produced:
        raise Fail(
            "poll response has the wrong size",
            expected=f"{produced} bytes (connection attribute 7)",
            seen=f"{len(data)} bytes",
        )


@case(
    P,
    "loopback_poll",
    "--loopback: outputs sent by poll come back in the poll response (same layout both ways)",
)
def loopback_poll(ctx: Context) -> None:
    if not ctx.options.loopback:
        raise Skip("needs --loopback (a bench whose outputs are wired to its inputs)")
    d = dev(ctx)
    allocate_poll(d)
    produced, consumed = io_sizes(d, POLL_INSTANCE)
    if produced != consumed or not consumed:
        raise Skip(
            f"produced ({produced} bytes) and consumed ({consumed} bytes) sizes differ: the layout cannot be compared"
        )
    set_epr(d, POLL_INSTANCE, 1000)
    pattern = bytes((0xA5, 0x5A, 0x3C)[i % 3] for i in range(consumed))
    try:
        seen = b""
        deadline = time.monotonic() + 4 * ctx.timing.response
        while seen != pattern and time.monotonic() < deadline:  # the loop may take a few polls
            first = d.poll(pattern)
            seen = d.poll_fragments(first, produced) if first is not None else b""
            time.sleep(0.02)
        if seen != pattern:
            raise Fail(
                "the outputs did not come back through the loopback",
                expected=pattern.hex(" ").upper(),
                seen=seen.hex(" ").upper() or "no poll response",
            )
    finally:
        d.poll(bytes(consumed))  # outputs back to zero
