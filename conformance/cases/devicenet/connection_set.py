"""The allocated connections' watchdogs (connection_set.py): expected packet rate, inactivity timeout, release."""

from __future__ import annotations

import time

from ...dnet import (
    CHOICE_EXPLICIT,
    CHOICE_POLL,
    GET,
    CipErrorSeen,
    status_text,
)
from ...framework import Context, Fail, case
from .common import (
    CONNECTION,
    IDENTITY,
    POLL_INSTANCE,
    STATE_ESTABLISHED,
    STATE_TIMED_OUT,
    P,
    allocate_poll,
    dev,
    io_sizes,
    set_epr,
)


@case(
    P,
    "epr_keeps_alive",
    "polls faster than the expected packet rate keep the poll connection Established",
)
def epr_keeps_alive(ctx: Context) -> None:
    d = dev(ctx)
    allocate_poll(d)
    _, consumed = io_sizes(d, POLL_INSTANCE)
    epr = set_epr(d, POLL_INSTANCE, ctx.timing.heartbeat_ms)
    end = time.monotonic() + 6 * epr / 1000
    while time.monotonic() < end:
        if d.poll(bytes(consumed)) is None:
            raise Fail("poll not answered while polling at half the expected packet rate")
        time.sleep(epr / 2000)
    state = d.get(CONNECTION, POLL_INSTANCE, 1)
    if state != bytes([STATE_ESTABLISHED]):
        raise Fail(
            "the poll connection left Established although polled in time",
            expected="state 3",
            seen=state.hex(),
        )


@case(
    P,
    "inactivity_timeout",
    "no poll for 4 × the expected packet rate: the poll connection times out and polls are not answered",
)
def inactivity_timeout(ctx: Context) -> None:
    d = dev(ctx)
    allocate_poll(d)
    _, consumed = io_sizes(d, POLL_INSTANCE)
    epr = set_epr(d, POLL_INSTANCE, ctx.timing.heartbeat_ms)
    if d.poll(bytes(consumed)) is None:
        raise Fail("no poll response before the timeout")
    time.sleep(4 * epr / 1000 + ctx.timing.slack(4 * epr / 1000))
    try:
        state = d.get(CONNECTION, POLL_INSTANCE, 1)
    except CipErrorSeen as err:
        if err.general != 0x16:
            raise
        state = b"deleted"
    if state not in (bytes([STATE_TIMED_OUT]), b"deleted"):
        raise Fail(
            f"poll connection still alive after 4 × {epr} ms without a poll",
            expected="state 4 (timed out) or deleted",
            seen=state.hex(),
        )
    answer = d.poll(bytes(consumed), ctx.timing.silence)
    if answer is not None:
        raise Fail(
            "a timed-out poll connection still answers polls",
            expected="no poll response",
            seen=answer.hex(" ").upper(),
        )


@case(
    P,
    "release",
    "Release poll then explicit: CC responses; the released connections no longer answer; a second Release is refused",
)
def release(ctx: Context) -> None:
    d = dev(ctx)
    allocate_poll(d)
    _, consumed = io_sizes(d, POLL_INSTANCE)
    set_epr(d, POLL_INSTANCE, 1000)
    for choice in (CHOICE_POLL, CHOICE_EXPLICIT):
        frame = d.release(choice)
        if len(frame.data) != 2 or frame.data[0] != d.master_mac:
            raise Fail(
                f"wrong Release 0x{choice:02X} response",
                expected=f"[2] {d.master_mac:02X} CC",
                seen=str(frame),
            )
        if choice == CHOICE_POLL:
            answer = d.poll(bytes(consumed), ctx.timing.silence)
            if answer is not None:
                raise Fail(
                    "a released poll connection still answers",
                    expected="no poll response",
                    seen=answer.hex(" ").upper(),
                )
    reply = d.request(bytes([GET, IDENTITY, 1, 1]), ctx.timing.silence)
    if reply is not None:
        raise Fail(
            "a released explicit connection still answers",
            expected="no response",
            seen=str(reply.frames[-1]),
        )
    try:
        frame = d.release(CHOICE_EXPLICIT)
    except CipErrorSeen as err:
        if err.general != 0x0B:
            raise Fail(
                "second Release: wrong general status",
                expected=status_text(0x0B),
                seen=str(err.frame),
            ) from None
    else:
        raise Fail(
            "a Release of a connection not allocated is accepted",
            expected="error 0x0B",
            seen=str(frame),
        )
    other = (
        d.master_mac + 1
    ) & 0x3F  # with nothing allocated the set has no owner: another master may allocate
    ctx.cleanup(lambda: d.unconnected(0x4C, bytes([CHOICE_EXPLICIT]), master=other))
    try:
        d.allocate(CHOICE_EXPLICIT, master=other)
    except CipErrorSeen as err:
        raise Fail(
            "after releasing everything the set still has an owner: Allocate by another master refused",
            expected=f"{other:02X} CB 00",
            seen=str(err.frame),
        ) from None
