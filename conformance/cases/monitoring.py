"""Monitoring errors that end (CiA 301 v4.2.0): life guarding and heartbeat-consumer events
(EMCY 0x8130) and SYNC loss (EMCY 81xx) are active only while the monitoring that raised them
runs. When the master switches it off, or resets communication, the error is gone, and the
EMCY state machine (§7.2.7.1) sends the error-reset EMCY 0000 with the error register of the
errors that remain; 0x1001 (§7.5.2.2) drops the communication bit.

Each case raises the error first (SKIP when the device does not offer the monitoring), then
ends it one way and checks the error-reset EMCY and 0x1001.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from ..device import NMT_RESET_COMM
from ..framework import Context, Fail, Info, Skip, case
from ..link import Frame
from .common import (
    EMCY_LIFE_GUARD,
    REGISTER_COMMUNICATION,
    emcy_cob,
    emcy_code,
    error_free,
    error_register,
    expect_emcy,
    expect_error_reset,
    log_mark,
    operational,
    quiet_register,
    require_generic_bit,
)
from .errctl import ERROR, life_guard, require_guarding, resume

SYNC_PRODUCER_BIT = 0x40000000


def sent(direction: str, _frame: Frame) -> bool:
    """``after`` for :func:`expect_error_reset`: the tester's command (an SDO request, a SYNC)."""
    return direction == "→"


def end_by_reset(ctx: Context, before: int | None) -> None:
    """NMT reset communication (§7.3.2) restarts every monitoring: the error ends after the boot-up
    (EMCY cannot be sent in Initialisation)."""
    mark = log_mark(ctx)
    boot = ctx.device.reset(NMT_RESET_COMM)
    if boot is None:
        raise Fail(
            "no boot-up after reset communication",
            expected=f"{0x700 + ctx.device.node_id:03X} [1] 00",
            seen="nothing",
            clause="CiA 301 §7.2.8.3.3 (boot-up protocol)",
        )
    # CiA 301 asks no error-reset EMCY here: the EMCY state machine (§7.2.7.1) starts
    # error-free after initialisation without a message and the boot-up tells the consumers.
    # What it does ask: the monitoring error is gone (0x1001 without it). An error-reset
    # EMCY, if one comes, must still carry the register left.
    interpretation(
        ctx,
        mark,
        lambda direction, frame: frame == boot,
        "reset communication (after the boot-up)",
        before,
        "CiA 301 requires no error-reset EMCY after reset communication: the EMCY state machine"
        " starts error-free after initialisation and the boot-up tells the consumers",
    )


def interpretation(
    ctx: Context,
    mark: int,
    after: Callable[[str, Frame], bool],
    what: str,
    before: int | None,
    why: str,
) -> None:
    """:func:`expect_error_reset` where CiA 301 does not ask for the EMCY: without one, the
    error register decides (FAIL if it still shows the error) and the rest is INFO."""
    try:
        expect_error_reset(ctx, mark, after, what, before)
    except Fail as exc:
        if exc.seen != "no error-reset EMCY":
            raise
        register = error_register(ctx)
        if register is not None and (
            register & REGISTER_COMMUNICATION or (before is not None and register != before)
        ):
            raise Fail(
                f"0x1001 after {what}",
                expected=f"0x{before if before is not None else 0:02X} (the communication bit 4 cleared)",
                seen=f"0x{register:02X}",
                clause="CiA 301 §7.5.2.2 (0x1001 shows the errors present), §7.3.2 (reset communication restarts the monitoring)",
            ) from None
        raise Info(
            f"no error-reset EMCY after {what} ({why})", seen="no error-reset EMCY"
        ) from None


# -- life guarding -----------------------------------------------------------------------
def raise_life_guarding(ctx: Context) -> int | None:
    """Node guarding with guard time = --heartbeat-ms and factor 2, then no RTR: EMCY 0x8130.
    Returns 0x1001 from before the event."""
    require_guarding(ctx, graded=False)
    ctx.device.require(0x1014, why="EMCY shows the life guarding event and its end")
    before = quiet_register(ctx)
    frame, _, life = life_guard(ctx, ctx.timing.heartbeat_ms, 2)
    if frame is None or emcy_code(frame) != EMCY_LIFE_GUARD:
        raise Fail(
            "no life guarding event to end",
            expected=f"EMCY 0x8130 about {life * 1000:.0f} ms after the last RTR",
            seen=str(frame) if frame else "nothing",
            clause="CiA 301 §7.2.8.3.2.1 (life guarding event), Table 21 (8130)",
        )
    require_generic_bit(frame, "life guarding EMCY")
    return before


# -- heartbeat consumer --------------------------------------------------------------------
def raise_consumer_error(ctx: Context) -> int | None:
    """0x1016:1 watches a spare node-ID at 2 × --heartbeat-ms; one heartbeat starts the
    supervision (§7.2.8.3.2.2), then silence: EMCY 0x8130. Returns 0x1001 from before."""
    dev = ctx.device
    dev.require(0x1016, 1, why="heartbeat consumer")
    dev.require(0x1014, why="EMCY shows the consumer event and its end")
    before = quiet_register(ctx)
    other = ctx.options.lss_spare_node_id or dev.node_id % 127 + 1
    consumer_ms = 2 * ctx.timing.heartbeat_ms
    dev.write(0x1016, 1, other << 16 | consumer_ms)
    ctx.cleanup(lambda: dev.reset(NMT_RESET_COMM))
    ctx.cleanup(lambda: dev.write(0x1016, 1, 0))
    ctx.cleanup(
        lambda: resume(ctx, lambda: dev.link.send(0x700 + other, b"\x05"))
    )  # the producer comes back first
    dev.link.send(0x700 + other, b"\x05")
    wait = consumer_ms / 1000 + ctx.timing.slack(consumer_ms / 1000) + ctx.timing.response
    frame = expect_emcy(ctx, ERROR, wait)
    if frame is None or emcy_code(frame) != EMCY_LIFE_GUARD:
        raise Fail(
            "no heartbeat-consumer event to end",
            expected=f"EMCY 0x8130 about {consumer_ms} ms after the heartbeat of node {other}",
            seen=str(frame) if frame else "nothing",
            clause="CiA 301 §7.2.8.3.2.2 (heartbeat consumer event), Table 21 (8130)",
        )
    require_generic_bit(frame, "heartbeat-consumer EMCY")
    return before


# -- SYNC loss -------------------------------------------------------------------------------
def sync_frame(ctx: Context) -> tuple[int, bytes]:
    """The SYNC the device consumes: CAN-ID from 0x1005, a counter byte if 0x1019 > 1."""
    dev = ctx.device
    overflow = dev.read(0x1019, 0) if dev.has(0x1019) else 0
    return dev.read(0x1005, 0) & 0x7FF, bytes([1]) if overflow > 1 else b""


def raise_sync_loss(ctx: Context) -> int | None:
    """0x1006 = --heartbeat-ms, Operational, three SYNCs one period apart, then none: the SYNC
    consumer misses SYNC (§7.2.5, §7.5.2.6) and reports it with a communication EMCY (81xx).
    Returns 0x1001 from before."""
    dev = ctx.device
    dev.require(0x1005, why="SYNC consumer")
    dev.require(0x1006, why="communication cycle period: SYNC loss supervision")
    dev.require(0x1014, why="EMCY shows the SYNC loss and its end")
    cob_id = dev.read(0x1005, 0)
    if cob_id & SYNC_PRODUCER_BIT:
        raise Skip("the device produces SYNC itself (0x1005 bit 30): there is no SYNC to lose")
    before = quiet_register(ctx)
    # the Start below needs a device without error; checked before 0x1006 is set (canopend
    # reports a SYNC loss at once when it is, before any SYNC)
    error_free(ctx, "before the case (a device with an error may refuse Operational)")
    ctx.error_checked = True
    sync = sync_frame(ctx)
    period = ctx.timing.heartbeat_ms / 1000
    ctx.cleanup(lambda: dev.reset(NMT_RESET_COMM))
    dev.patch(ctx, 0x1006, 0, ctx.timing.heartbeat_ms * 1000)
    operational(ctx)
    for _ in range(3):
        last = dev.link.send(*sync)
        time.sleep(period)
    wait = 3 * period + ctx.timing.slack(period) + ctx.timing.response
    # the loss is the EMCY after the last SYNC: canopend reports one at once when 0x1006 is
    # set (no SYNC seen yet) and ends it at the first SYNC; that one is not the loss to end
    cob = emcy_cob(dev)
    frame = dev.link.expect(
        lambda f: (
            f.cob == cob and not f.rtr and emcy_code(f) != 0 and f.timestamp >= last.timestamp
        ),
        wait,
    )
    if frame is None:
        raise Skip(
            f"no EMCY within {wait * 1000:.0f} ms after SYNC stopped (0x1006 = {ctx.timing.heartbeat_ms} ms): the device does not report SYNC loss"
        )
    if emcy_code(frame) >> 8 != 0x81:
        raise Fail(
            "SYNC loss EMCY",
            expected="[8] xx 81 ... (81xx communication; CANopenNode and fieldgate send 8100)",
            seen=str(frame),
            clause="CiA 301 §7.2.7.1, Table 21 (81xx communication errors)",
        )
    require_generic_bit(frame, "SYNC-loss EMCY")
    return before


# -- the cases: each error, ended each way ----------------------------------------------------
def by_write(index: int, sub: int, what: str) -> Callable[[Context, int | None], None]:
    """End the error with an SDO write of 0 to ``index:sub``."""

    def end(ctx: Context, before: int | None) -> None:
        mark = log_mark(ctx)
        ctx.device.write(index, sub, 0)
        expect_error_reset(ctx, mark, sent, f"0x{index:04X}:{sub} ({what}) was written 0", before)

    return end


def by_period_0(ctx: Context, before: int | None) -> None:
    """End the SYNC loss with 0x1006 = 0: whether a device supervises SYNC at all, and so
    whether it ends a SYNC-loss error when told no SYNC is expected, is its choice (CiA 301
    §7.5.2.6 defines the period, not an error for its absence): INFO when it does not."""
    mark = log_mark(ctx)
    ctx.device.write(0x1006, 0, 0)
    try:
        expect_error_reset(
            ctx, mark, sent, "0x1006 (communication cycle period) was written 0", before
        )
    except Fail as exc:
        raise Info(
            f"SYNC loss not ended by 0x1006 = 0 ({exc.message}; CiA 301 leaves SYNC-loss supervision to the device)",
            seen=exc.seen,
        ) from None


def by_sync(ctx: Context, before: int | None) -> None:
    """End the SYNC loss with one SYNC."""
    sync = sync_frame(ctx)
    mark = log_mark(ctx)
    ctx.device.link.send(*sync)
    expect_error_reset(ctx, mark, sent, "a SYNC came again", before)


CASES = (
    (
        "errctl",
        "guard_off_ends_error",
        raise_life_guarding,
        by_write(0x100C, 0, "guard time"),
        "life guarding error (0x8130) ended by 0x100C = 0: EMCY 0000 with the register left, 0x1001 bit 4 clear (CiA 301 §7.2.7.1, §7.2.8.3.2.1, §7.5.2.2)",
    ),
    (
        "errctl",
        "guard_reset_ends_error",
        raise_life_guarding,
        end_by_reset,
        "life guarding error (0x8130) ended by reset communication: EMCY 0000 after the boot-up, 0x1001 bit 4 clear (CiA 301 §7.2.7.1, §7.3.2, §7.5.2.2)",
    ),
    (
        "errctl",
        "consumer_off_ends_error",
        raise_consumer_error,
        by_write(0x1016, 1, "consumer heartbeat time"),
        "heartbeat-consumer error (0x8130) ended by its 0x1016 entry = 0: EMCY 0000, 0x1001 bit 4 clear (CiA 301 §7.2.7.1, §7.2.8.3.2.2, §7.5.2.19)",
    ),
    (
        "errctl",
        "consumer_reset_ends_error",
        raise_consumer_error,
        end_by_reset,
        "heartbeat-consumer error (0x8130) ended by reset communication: EMCY 0000 after the boot-up, 0x1001 bit 4 clear (CiA 301 §7.2.7.1, §7.3.2)",
    ),
    (
        "sync-pdo",
        "sync_loss_ends_on_sync",
        raise_sync_loss,
        by_sync,
        "SYNC loss (EMCY 81xx with 0x1006 set and SYNC stopped) ended by the next SYNC: EMCY 0000, 0x1001 as before (CiA 301 §7.2.5, §7.2.7.1, §7.5.2.6)",
    ),
    (
        "sync-pdo",
        "sync_loss_ends_period_0",
        raise_sync_loss,
        by_period_0,
        "SYNC loss (EMCY 81xx) ended by 0x1006 = 0 (no SYNC expected): EMCY 0000, 0x1001 as before (CiA 301 §7.2.7.1, §7.5.2.6)",
    ),
)


def _raise_and_end(
    raise_error: Callable[[Context], int | None], end: Callable[[Context, int | None], None]
) -> Callable[[Context], None]:
    def run(ctx: Context) -> None:
        end(ctx, raise_error(ctx))

    return run


for profile, name, raise_error, end, title in CASES:
    case(profile, name, title)(_raise_and_end(raise_error, end))
