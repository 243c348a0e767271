"""EMCY: COB-ID 0x1014 and its valid bit, error register 0x1001, history 0x1003, inhibit 0x1015.

The device is made to raise an error it must report under CiA 301: an RPDO shorter than its
mapping (EMCY 0x8210), cleared by the next RPDO of the right length (EMCY 0x0000).
"""

from __future__ import annotations

import time

from ..device import NMT_RESET_COMM, SdoAbort, abort_text
from ..framework import Context, Fail, Inconclusive, Info, Skip, case
from .common import (
    EMCY_LENGTH_ERROR,
    LengthError,
    emcy_code,
    error_free,
    expect_emcy,
    require_generic_bit,
)

# the EMCY cases provoke an error with a short RPDO; without its EMCY only
# emcy.error_and_reset and sync-pdo.rpdo_length grade the device, the others give no verdict
NO_TRIGGER = "no EMCY 0x8210 for a short RPDO, the error these cases provoke (emcy.error_and_reset and sync-pdo.rpdo_length grade that)"


@case("emcy", "cobid", "0x1014 holds 0x80 + node-ID with the valid bit clear")
def cobid(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1014, why="EMCY producer")
    value = dev.read(0x1014, 0)
    if value != 0x80 + dev.node_id:
        raise Fail("EMCY COB-ID", expected=f"0x{0x80 + dev.node_id:08X}", seen=f"0x{value:08X}")


@case(
    "emcy",
    "error_register_idle",
    "0x1001 is 0 after reset communication on a device without errors",
)
def error_register_idle(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1001)
    if dev.reset(NMT_RESET_COMM) is None:
        raise Inconclusive(
            "no boot-up after reset communication (nmt.bootup_reset_comm grades that)"
        )
    error_free(ctx, "after the boot-up")
    value = dev.read(0x1001, 0)
    if value != 0:
        raise Fail("error register after reset communication", expected="0", seen=f"0x{value:02X}")


@case(
    "emcy",
    "error_and_reset",
    "an error sends EMCY (DLC 8, code, register = 0x1001); its end sends EMCY 0000 and 0x1001 = 0",
)
def error_and_reset(ctx: Context) -> None:
    dev = ctx.device
    trigger = LengthError(ctx)
    frame = trigger.raise_error()
    if frame is None:
        raise Fail(
            f"no EMCY for a short {trigger.rpdo.name}",
            expected=f"EMCY 0x8210 on 0x{dev.od_default(0x1014, 0, 0x80 + dev.node_id):03X}",
            seen="nothing",
        )
    require_generic_bit(frame, f"EMCY for a short {trigger.rpdo.name}")
    if dev.has(0x1001) and dev.read(0x1001, 0) != frame.data[2]:
        raise Fail(
            "0x1001 does not match the EMCY's error register",
            expected=f"0x{frame.data[2]:02X}",
            seen=f"0x{dev.read(0x1001, 0):02X}",
        )
    cleared = trigger.clear()
    if cleared is None:
        raise Fail(
            f"no error-reset EMCY after a correct {trigger.rpdo.name}",
            expected="EMCY 0x0000",
            seen="nothing",
        )
    if dev.has(0x1001) and dev.read(0x1001, 0) != 0:
        raise Fail(
            "0x1001 after the error cleared", expected="0", seen=f"0x{dev.read(0x1001, 0):02X}"
        )


@case("emcy", "same_error_once", "a recurring active error does not repeat its EMCY")
def same_error_once(ctx: Context) -> None:
    trigger = LengthError(ctx)
    if trigger.raise_error() is None:
        raise Inconclusive(NO_TRIGGER)
    again = trigger.raise_error()
    trigger.clear()
    if again is not None:
        raise Info(
            "EMCY repeated for a short RPDO while the first one's error is still active: CiA 301"
            " §7.2.7.1 sends one EMCY per error event, and leaves open whether each short RPDO is one",
            seen=str(again),
        )


@case(
    "emcy", "history", "0x1003: newest error at sub 1 (code in bits 0-15), sub 0 counts the entries"
)
def history(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1003, 1, why="pre-defined error field")
    trigger = LengthError(ctx)
    if trigger.raise_error() is None:
        raise Inconclusive(NO_TRIGGER)
    count = dev.read(0x1003, 0)
    newest = dev.read(0x1003, 1)
    trigger.clear()
    if count < 1:
        raise Fail("0x1003:0 after an error", expected="≥ 1", seen=str(count))
    if newest & 0xFFFF != EMCY_LENGTH_ERROR:
        raise Fail("0x1003:1 after EMCY 0x8210", expected="0x....8210", seen=f"0x{newest:08X}")


@case(
    "emcy",
    "history_clear",
    "writing 0 to 0x1003:0 clears the history; other values are refused with 0609 0030",
)
def history_clear(ctx: Context) -> None:
    dev = ctx.device
    var = dev.require(0x1003, 0, why="pre-defined error field")
    if not var.writable:
        raise Skip("0x1003:0 is read-only in the EDS")
    dev.write(0x1003, 0, 0)
    if dev.read(0x1003, 0) != 0:
        raise Fail("0x1003:0 after writing 0", expected="0", seen=str(dev.read(0x1003, 0)))
    dev.expect_write_abort(0x1003, 0, b"\x01", (0x06090030,), "0x1003:0 = 1")


@case(
    "emcy", "cobid_valid_bit", "with 0x1014 bit 31 set no EMCY is sent; clearing it restores EMCY"
)
def cobid_valid_bit(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1014, why="EMCY producer")
    original = dev.read(0x1014, 0)
    ctx.cleanup(lambda: dev.write(0x1014, 0, original))
    dev.write(0x1014, 0, original | 0x80000000)
    trigger = LengthError(ctx)
    dev.link.flush()
    dev.link.send(trigger.rpdo.cob & 0x7FF, trigger.good[: trigger.rpdo.length - 1])
    silent = expect_emcy(ctx, None, ctx.timing.silence)
    dev.link.send(trigger.rpdo.cob & 0x7FF, trigger.good)
    time.sleep(0.02)
    if silent is not None:
        raise Fail("EMCY sent while 0x1014 is invalid", expected="none", seen=str(silent))
    dev.write(0x1014, 0, original)
    if trigger.raise_error() is None:
        raise Inconclusive(NO_TRIGGER)
    trigger.clear()


@case("emcy", "cobid_change_while_valid", "0x1014 cannot change its CAN-ID while valid")
def cobid_change_while_valid(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1014, why="EMCY producer")
    original = dev.read(0x1014, 0)
    if original & 0x80000000:
        raise Skip("0x1014 is invalid by default")
    ctx.cleanup(lambda: dev.write(0x1014, 0, original))
    new = 0x80 + (
        ctx.options.lss_spare_node_id or dev.node_id % 127 + 1
    )  # another node's EMCY CAN-ID
    code = None
    try:
        dev.write(0x1014, 0, new)
    except SdoAbort as exc:  # the abort is the point
        code = exc.code
    if code is None:
        raise Fail(
            "0x1014 accepted a new CAN-ID while valid",
            expected=f"{abort_text(0x06090030)} (or 0800 0000)",
            seen=f"0x{dev.read(0x1014, 0):08X} written",
        )


@case("emcy", "inhibit", "0x1015 (×100 µs) spaces consecutive EMCYs")
def inhibit(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1015, why="EMCY inhibit time")
    inhibit_s = 0.1
    dev.patch(ctx, 0x1015, 0, int(inhibit_s * 10000))
    trigger = LengthError(ctx)
    first = trigger.raise_error()
    if first is None:
        raise Inconclusive(NO_TRIGGER)
    dev.link.send(trigger.rpdo.cob & 0x7FF, trigger.good)
    second = expect_emcy(ctx, 0x0000, inhibit_s + ctx.timing.slack(inhibit_s) + ctx.timing.response)
    if second is None:
        raise Fail(
            "no error-reset EMCY after the error ended (0x1015 set: it may come late, not never)",
            expected="EMCY 0x0000 after the inhibit time",
            seen="nothing",
            clause="CiA 301 §7.2.7.1 (the error-reset EMCY when the error ends), §7.5.2.17 (the inhibit time delays EMCYs)",
        )
    gap = second.timestamp - first.timestamp
    if gap < inhibit_s - ctx.timing.slack(inhibit_s):
        raise Fail(
            "EMCY inhibit time not respected",
            expected=f"≥ {inhibit_s * 1000:.0f} ms between EMCYs",
            seen=f"{gap * 1000:.1f} ms",
        )
    if emcy_code(second) != 0:
        raise Fail("second EMCY", expected="0x0000", seen=str(second))
