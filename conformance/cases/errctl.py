"""Error control: heartbeat producer and consumer, node guarding, life guarding."""

from __future__ import annotations

import time
from collections.abc import Callable
from itertools import pairwise

from ..device import NMT_PREOP, NMT_RESET_COMM, NMT_START, NMT_STOP, SdoAbort, abort_text
from ..framework import Context, Fail, Inconclusive, Skip, case
from ..link import Frame
from .common import EMCY_LIFE_GUARD, emcy_code, expect_emcy, require_generic_bit

ERROR = -1  # expect_emcy: any EMCY except an error reset


def resume(ctx: Context, poke: Callable[[], object]) -> None:
    """Let a lost master or producer come back so that the device can clear the error it raised."""
    poke()
    time.sleep(0.02)
    ctx.device.link.flush()


def heartbeats(ctx: Context, duration: float) -> list[Frame]:
    dev = ctx.device
    return dev.link.collect(lambda f: f.cob == 0x700 + dev.node_id and not f.rtr, duration)


def check_period(ctx: Context, stamps: list[float], period_s: float, what: str) -> None:
    gaps = [b - a for a, b in pairwise(stamps)]
    bad = [g for g in gaps if not ctx.timing.within(g, period_s)]
    if bad:
        raise Fail(
            f"{what}: {len(bad)} of {len(gaps)} intervals off",
            expected=f"{period_s * 1000:.0f} ms ± {ctx.timing.slack(period_s) * 1000:.0f} ms",
            seen=", ".join(f"{g * 1000:.0f}" for g in gaps) + " ms",
        )


@case(
    "errctl",
    "heartbeat_period",
    "heartbeat producer: period as written to 0x1017, DLC 1, state byte",
)
def heartbeat_period(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1017, why="heartbeat producer")
    period = ctx.timing.heartbeat_ms / 1000
    dev.patch(ctx, 0x1017, 0, ctx.timing.heartbeat_ms)
    dev.link.expect(0x700 + dev.node_id, period + ctx.timing.response)  # the first may be early
    frames = heartbeats(ctx, 5.5 * period)
    if len(frames) < 3:
        raise Fail(
            "too few heartbeats", expected=f"5 in {5.5 * period:.2f} s", seen=f"{len(frames)}"
        )
    for f in frames:
        if len(f.data) != 1 or f.data[0] != 0x7F:
            raise Fail(
                "heartbeat in Pre-operational",
                expected=f"{0x700 + dev.node_id:03X} [1] 7F",
                seen=str(f),
            )
    check_period(ctx, [f.timestamp for f in frames], period, "heartbeat period")


@case("errctl", "heartbeat_disable", "heartbeat producer stops when 0x1017 is written 0")
def heartbeat_disable(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1017, why="heartbeat producer")
    dev.patch(ctx, 0x1017, 0, ctx.timing.heartbeat_ms)
    if (
        dev.link.expect(
            0x700 + dev.node_id, 2 * ctx.timing.heartbeat_ms / 1000 + ctx.timing.response
        )
        is None
    ):
        raise Fail("no heartbeat after 0x1017 was set", expected="heartbeats", seen="nothing")
    dev.write(0x1017, 0, 0)
    time.sleep(0.01)
    dev.link.flush()
    frames = heartbeats(ctx, 3 * ctx.timing.heartbeat_ms / 1000)
    if frames:
        raise Fail("heartbeats after 0x1017 = 0", expected="none", seen=str(frames[0]))


@case(
    "errctl",
    "heartbeat_consumer",
    "heartbeat consumer (0x1016): a missing producer raises EMCY 0x8130",
)
def heartbeat_consumer(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1016, 1, why="heartbeat consumer")
    dev.require(0x1014, why="EMCY shows the consumer event")
    other = ctx.options.lss_spare_node_id or dev.node_id % 127 + 1
    period = ctx.timing.heartbeat_ms / 1000
    consumer_ms = 3 * ctx.timing.heartbeat_ms
    dev.write(0x1016, 1, other << 16 | consumer_ms)
    ctx.cleanup(lambda: dev.reset(NMT_RESET_COMM))
    ctx.cleanup(lambda: dev.write(0x1016, 1, 0))
    ctx.cleanup(
        lambda: resume(ctx, lambda: dev.link.send(0x700 + other, b"\x05"))
    )  # the producer comes back first
    deadline = time.monotonic() + 4 * period
    while time.monotonic() < deadline:
        dev.link.send(0x700 + other, b"\x05")
        early = expect_emcy(ctx, None, period)
        if early is not None:
            raise Fail(
                "EMCY while the monitored node still sends heartbeats",
                expected="none",
                seen=str(early),
            )
    t0 = time.time()
    frame = expect_emcy(
        ctx, ERROR, consumer_ms / 1000 + ctx.timing.slack(consumer_ms / 1000) + ctx.timing.response
    )
    if frame is None or emcy_code(frame) != EMCY_LIFE_GUARD:
        raise Fail(
            "no heartbeat-consumer EMCY",
            expected=f"EMCY 0x8130 about {consumer_ms} ms after the last heartbeat",
            seen=str(frame) if frame else "nothing",
        )
    require_generic_bit(frame, "heartbeat-consumer EMCY")
    if frame.timestamp - t0 < consumer_ms / 1000 - period - ctx.timing.slack(consumer_ms / 1000):
        raise Fail(
            "heartbeat-consumer EMCY too early",
            expected=f"≥ {consumer_ms} ms after the last heartbeat",
            seen=f"{(frame.timestamp - t0) * 1000:.0f} ms",
        )


def guard_replies(ctx: Context, count: int) -> list[int]:
    dev = ctx.device
    replies = []
    for _ in range(count):
        frame = dev.guard()
        if frame is None:
            raise Fail(
                "no node guarding reply",
                expected=f"{0x700 + dev.node_id:03X} [1] toggle|state",
                seen="nothing",
                clause="CiA 301 §7.2.8.3.2.1 (node guarding: the NMT slave answers the remote frame); the EDS lists 0x100C",
            )
        if len(frame.data) != 1:
            raise Fail("node guarding reply with the wrong DLC", expected="DLC 1", seen=str(frame))
        replies.append(frame.data[0])
    return replies


def require_guarding(ctx: Context, graded: bool = True) -> None:
    """0x100C listed, the device in guarding mode; ``graded`` False: the case needs guard
    replies as a step (errctl.guarding_state grades a device that gives none)."""
    ctx.device.require(0x100C, why="node guarding")
    guarding_mode(ctx)
    if not graded and ctx.device.guard() is None:
        raise Inconclusive("no node guarding reply (errctl.guarding_state grades that)")


def guarding_mode(ctx: Context) -> None:
    """Switch a device with a running heartbeat producer to node guarding, as a master does:
    CiA 301 (§7.2.8.3.2) uses guarding only while 0x1017 is 0. Needed again after every reset
    communication of a device whose 0x1017 default is not 0; 0x1017 is restored at the end."""
    dev = ctx.device
    if not dev.has(0x1017):
        return
    period = dev.read(0x1017, 0)
    if not period:
        return
    try:
        dev.write(0x1017, 0, 0)
    except SdoAbort as exc:
        raise Skip(
            f"heartbeat producer on ({period} ms) and 0x1017 = 0 refused ({abort_text(exc.code)}):"
            " node guarding is not used while it runs (CiA 301 §7.2.8.3.2)"
        ) from None
    ctx.cleanup(lambda: dev.write(0x1017, 0, period))
    dev.link.collect(0x700 + dev.node_id, 0.02)  # a heartbeat already under way is not a reply


@case(
    "errctl",
    "guarding_toggle",
    "node guarding: the toggle bit alternates, starting at 0 after reset communication",
)
def guarding_toggle(ctx: Context) -> None:
    require_guarding(ctx)
    dev = ctx.device
    if dev.reset(NMT_RESET_COMM) is None:
        raise Inconclusive(
            "no boot-up after reset communication (nmt.bootup_reset_comm grades that)"
        )
    guarding_mode(ctx)  # the reset brought a heartbeat producer default back
    replies = guard_replies(ctx, 4)
    toggles = [r >> 7 for r in replies]
    if toggles != [0, 1, 0, 1]:
        raise Fail("guarding toggle bits", expected="0 1 0 1", seen=" ".join(map(str, toggles)))


@case("errctl", "guarding_state", "node guarding reports Pre-operational, Operational and Stopped")
def guarding_state(ctx: Context) -> None:
    require_guarding(ctx)
    dev = ctx.device
    for cs, state, name in (
        (None, 0x7F, "Pre-operational"),
        (NMT_START, 0x05, "Operational"),
        (NMT_STOP, 0x04, "Stopped"),
    ):
        if cs is not None:
            dev.nmt(cs)
            time.sleep(0.02)
        reply = guard_replies(ctx, 1)[0]
        if reply & 0x7F != state:
            raise Fail(
                f"guarding state in {name}", expected=f"{state:#04x}", seen=f"{reply & 0x7F:#04x}"
            )


def life_guard(
    ctx: Context, guard_ms: int, factor: int
) -> tuple[Frame | None, float | None, float]:
    """Arm life guarding with one RTR and wait for the life guarding EMCY; returns (frame, delay)."""
    dev = ctx.device
    dev.require(0x100D, why="life time factor")
    dev.require(0x1014, why="EMCY shows the life guarding event")
    guarding_mode(ctx)  # first: its restore runs after the others
    ctx.cleanup(lambda: dev.reset(NMT_RESET_COMM))
    ctx.cleanup(lambda: dev.write(0x100D, 0, 0))
    ctx.cleanup(lambda: dev.write(0x100C, 0, 0))
    ctx.cleanup(lambda: resume(ctx, dev.guard))  # the master comes back first
    dev.write(0x100C, 0, guard_ms)
    dev.write(0x100D, 0, factor)
    if dev.guard() is None:
        raise Fail("no node guarding reply", seen="nothing")
    t0 = time.time()
    life = guard_ms * factor / 1000
    frame = expect_emcy(ctx, ERROR, life + ctx.timing.slack(life) + ctx.timing.response)
    return frame, (frame.timestamp - t0 if frame else None), life


@case(
    "errctl",
    "life_guarding",
    "life guarding: no RTR for guard time × factor raises EMCY 0x8130 with error register bit 4",
)
def life_guarding(ctx: Context) -> None:
    require_guarding(ctx, graded=False)
    frame, delay, life = life_guard(ctx, ctx.timing.heartbeat_ms, 3)
    if frame is None:
        raise Fail(
            "no life guarding EMCY",
            expected=f"EMCY 0x8130 about {life * 1000:.0f} ms after the last RTR",
            seen="nothing",
        )
    if emcy_code(frame) != EMCY_LIFE_GUARD or len(frame.data) != 8 or not frame.data[2] & 0x10:
        raise Fail(
            "life guarding EMCY",
            expected="[8] 30 81 <reg with bit 4> ..",
            seen=str(frame),
            clause="CiA 301 §7.2.8.3.2.1, Table 21 (8130 life guard error), §7.5.2.2 (bit 4 communication error)",
        )
    require_generic_bit(frame, "life guarding EMCY")
    assert delay is not None  # (there is a frame)
    if not ctx.timing.within(delay, life) and delay < life:
        raise Fail(
            "life guarding EMCY too early",
            expected=f"{life * 1000:.0f} ms",
            seen=f"{delay * 1000:.0f} ms",
        )


@case("errctl", "guarding_off_no_life_guard", "with guard time 0 no life guarding event is raised")
def guarding_off(ctx: Context) -> None:
    require_guarding(ctx, graded=False)
    dev = ctx.device
    dev.require(0x1014, why="EMCY would show a life guarding event")
    if dev.read(0x100C, 0) != 0:
        raise Skip("0x100C is not 0 by default")
    if dev.guard() is None:
        raise Fail("no node guarding reply", seen="nothing")
    frame = expect_emcy(ctx, None, max(ctx.timing.silence, 0.3))
    if frame is not None:
        raise Fail("EMCY with guarding disabled (0x100C = 0)", expected="none", seen=str(frame))


@case(
    "errctl",
    "error_behaviour",
    "0x1029:1 decides the NMT state after a communication error: 0 pre-op, 1 no change, 2 stopped",
)
def error_behaviour(ctx: Context) -> None:
    require_guarding(ctx, graded=False)
    dev = ctx.device
    dev.require(0x1029, 1, why="error behaviour")
    for value, state, name in (
        (0, 0x7F, "Pre-operational"),
        (2, 0x04, "Stopped"),
        (1, 0x05, "Operational (no change)"),
    ):
        dev.write(0x1029, 1, value)
        dev.nmt(NMT_START)
        time.sleep(0.02)
        frame, _, _ = life_guard(ctx, max(20, ctx.timing.heartbeat_ms // 2), 2)
        if frame is None:
            raise Fail("no life guarding event", seen="nothing")
        reply = dev.guard()
        if reply is None or reply.data[0] & 0x7F != state:
            raise Fail(
                f"state after a life guarding event with 0x1029:1 = {value}",
                expected=f"{state:#04x} {name}",
                seen=str(reply) if reply else "no guarding reply",
            )
        dev.nmt(NMT_PREOP)  # SDO again, also from Stopped
        time.sleep(0.02)
        dev.write(0x100C, 0, 0)
        dev.reset(NMT_RESET_COMM)
