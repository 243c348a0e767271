"""NMT: boot-up, every state and transition, services gated per state, reset node vs reset communication."""

from __future__ import annotations

import time
from functools import partial

from canopen.objectdictionary import ODVariable

from ..device import (
    NMT_PREOP,
    NMT_RESET_COMM,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
    SdoAbort,
    StateProbe,
    mux,
)
from ..framework import Context, Fail, Inconclusive, Skip, case
from ..link import Frame
from .common import error_free, int_default, other_value, rw_ints

PREOP, OPERATIONAL, STOPPED = 0x7F, 0x05, 0x04


def expect_bootup(ctx: Context, cs: int, what: str, graded: bool = True) -> Frame:
    """The boot-up after a reset; ``graded`` False: the case needs a reset as a step, and
    nmt.bootup_* grade a missing boot-up, so it gives no verdict then."""
    frame = ctx.device.reset(cs)
    if frame is None and not graded:
        raise Inconclusive(f"no boot-up message after {what} (nmt.bootup_* grade that)")
    if frame is None:
        raise Fail(
            f"no boot-up message after {what}",
            expected=f"{0x700 + ctx.device.node_id:03X} [1] 00",
            seen="nothing",
            clause="CiA 301 §7.2.8.3.3 (boot-up protocol), §7.3.2.2 (reset ends in Pre-operational via the boot-up)",
        )
    if len(frame.data) != 1:
        raise Fail(
            f"boot-up message after {what} with DLC {len(frame.data)}",
            expected=f"{0x700 + ctx.device.node_id:03X} [1] 00",
            seen=str(frame),
        )
    return frame


@case("nmt", "bootup_reset_node", "reset node ends in a boot-up message (DLC 1, 00)")
def bootup_reset_node(ctx: Context) -> None:
    expect_bootup(ctx, NMT_RESET_NODE, "reset node")


@case("nmt", "bootup_reset_comm", "reset communication ends in a boot-up message (DLC 1, 00)")
def bootup_reset_comm(ctx: Context) -> None:
    expect_bootup(ctx, NMT_RESET_COMM, "reset communication")


@case("nmt", "preop_after_bootup", "after boot-up the node is Pre-operational by itself")
def preop_after_bootup(ctx: Context) -> None:
    expect_bootup(ctx, NMT_RESET_COMM, "reset communication", graded=False)
    probe = StateProbe(ctx)
    probe.expect(PREOP, "boot-up")


@case("nmt", "transitions", "every NMT transition between Pre-operational, Operational and Stopped")
def transitions(ctx: Context) -> None:
    dev = ctx.device
    error_free(ctx, "before the case (a device with an error may refuse Operational)")
    probe = StateProbe(ctx)
    dev.nmt(NMT_PREOP)
    probe.expect(PREOP, "enter pre-operational")
    for cs, state, name in (
        (NMT_START, OPERATIONAL, "start (pre-op → operational)"),
        (NMT_STOP, STOPPED, "stop (operational → stopped)"),
        (NMT_PREOP, PREOP, "enter pre-op (stopped → pre-op)"),
        (NMT_STOP, STOPPED, "stop (pre-op → stopped)"),
        (NMT_START, OPERATIONAL, "start (stopped → operational)"),
        (NMT_PREOP, PREOP, "enter pre-op (operational → pre-op)"),
        (NMT_PREOP, PREOP, "enter pre-op again (no change)"),
    ):
        dev.nmt(cs)
        probe.expect(state, name)


@case("nmt", "broadcast", "NMT commands to node 0 reach every node")
def broadcast(ctx: Context) -> None:
    dev = ctx.device
    error_free(ctx, "before the case (a device with an error may refuse Operational)")
    probe = StateProbe(ctx)
    dev.nmt(NMT_START, node=0)
    probe.expect(OPERATIONAL, "start to all nodes")
    dev.nmt(NMT_PREOP, node=0)
    probe.expect(PREOP, "enter pre-op to all nodes")


@case("nmt", "other_node_ignored", "NMT commands for another node-ID are ignored")
def other_node_ignored(ctx: Context) -> None:
    dev = ctx.device
    probe = StateProbe(ctx)
    dev.nmt(NMT_START, node=dev.node_id % 127 + 1)
    probe.expect(PREOP, "start addressed to another node")


@case("nmt", "unknown_command", "an unknown NMT command specifier is ignored")
def unknown_command(ctx: Context) -> None:
    dev = ctx.device
    probe = StateProbe(ctx)
    dev.nmt(0x55)
    dev.link.send(0x000, bytes([NMT_START]))  # DLC 1: malformed, must be ignored
    probe.expect(PREOP, "NMT cs 0x55 and a 1-byte NMT frame")
    dev.upload(0x1000, 0)


@case("nmt", "sdo_gated", "SDO is served in Pre-operational and Operational, not in Stopped")
def sdo_gated(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1000)
    dev.upload(0x1000, 0)
    dev.nmt(NMT_START)
    time.sleep(0.02)
    dev.upload(0x1000, 0)
    dev.nmt(NMT_STOP)
    time.sleep(0.02)
    answer = dev.sdo_request(bytes([0x40]) + mux(0x1000, 0), timeout=ctx.timing.silence)
    if answer is not None:
        raise Fail(
            "SDO answered in Stopped",
            expected="no answer (CiA 301: no SDO in Stopped)",
            seen=str(answer),
        )
    dev.nmt(NMT_PREOP)
    time.sleep(0.02)
    dev.upload(0x1000, 0)


def _write_other(ctx: Context, candidates: list[ODVariable], what: str) -> ODVariable:
    """Give the first candidate that accepts it a value other than its default; restored at the end."""
    dev = ctx.device
    for var in candidates:
        try:
            dev.write(var.index, var.subindex, other_value(var))
        except SdoAbort:
            continue
        ctx.cleanup(partial(dev.write, var.index, var.subindex, var.default))
        return var
    raise Skip(f"EDS lists no writable {what} entry with a default that takes another value")


@case(
    "nmt",
    "reset_comm_vs_node",
    "reset communication restores 0x1000-0x1FFF only; reset node restores the application area too",
)
def reset_comm_vs_node(ctx: Context) -> None:
    dev = ctx.device
    avoid = (0x1005, 0x1010, 0x1011, 0x1014, 0x1016, 0x1017, 0x1200)
    comm = _write_other(
        ctx,
        [v for v in rw_ints(dev, 0x1000, 0x1FFF, avoid) if int_default(v) is not None],
        "communication",
    )
    # The device profile area first: its reset semantics are CiA's. A manufacturer object may
    # hold what lives in an I/O module (ICP DAS 0x2001: a module's host watchdog) or a setting
    # applied at reset node (NA-9161 0x4500:2), which a reset node cannot undo.
    apps = [v for v in rw_ints(dev, 0x6000, 0x9FFF) if int_default(v) is not None] or [
        v for v in rw_ints(dev, 0x2000, 0x5FFF) if int_default(v) is not None
    ]
    app = _write_other(ctx, sorted(apps, key=lambda v: v.pdo_mappable), "application")
    expect_bootup(ctx, NMT_RESET_COMM, "reset communication", graded=False)
    for var, want, what in (
        (comm, comm.default, "reset to its default"),
        (app, other_value(app), "kept"),
    ):
        seen = dev.read(var.index, var.subindex)
        if seen != want:
            raise Fail(
                f"after reset communication 0x{var.index:04X}:{var.subindex} should be {what}",
                expected=str(want),
                seen=str(seen),
            )
    expect_bootup(ctx, NMT_RESET_NODE, "reset node", graded=False)
    seen = dev.read(app.index, app.subindex)
    if seen != app.default:
        raise Fail(
            f"after reset node 0x{app.index:04X}:{app.subindex} should be back to its default",
            expected=str(app.default),
            seen=str(seen),
        )
