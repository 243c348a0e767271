"""Store and restore parameters (0x1010 / 0x1011) across a reset."""

from __future__ import annotations

from canopen.objectdictionary import ODVariable

from ..device import NMT_RESET_NODE
from ..framework import Context, Fail, Skip, case
from .common import LOAD, SAVE, int_default, other_value, require_store, rw_ints, subindex_numbers

__all__ = ["LOAD", "SAVE", "require_store"]


def reset_node(ctx: Context) -> None:
    if ctx.device.reset(NMT_RESET_NODE) is None:
        raise Fail("no boot-up after reset node", seen="nothing")


@case(
    "store",
    "capabilities",
    "0x1010 and 0x1011 sub 1.. read as capability words (only bits 0-1 used)",
)
def capabilities(ctx: Context) -> None:
    dev = ctx.device
    found = False
    for index in (0x1010, 0x1011):
        if not dev.has(index):
            continue
        found = True
        for sub in subindex_numbers(dev, index):
            if sub == 0:
                continue
            value = dev.read(index, sub)
            if value & ~0x3:
                raise Fail(
                    f"0x{index:04X}:{sub} capability word",
                    expected="only bits 0-1 set",
                    seen=f"0x{value:08X}",
                )
    if not found:
        raise Skip("EDS lists neither 0x1010 nor 0x1011")


@case("store", "wrong_signature", "writing anything but 'save'/'load' is refused with 0800 0020")
def wrong_signature(ctx: Context) -> None:
    dev = ctx.device
    done = False
    for index in (0x1010, 0x1011):
        if dev.has(index, 1):
            done = True
            dev.expect_write_abort(
                index,
                1,
                (0x12345678).to_bytes(4, "little"),
                (0x08000020,),
                f"0x{index:04X}:1 with a wrong signature",
            )
    if not done:
        raise Skip("EDS lists neither 0x1010:1 nor 0x1011:1")


def _target(ctx: Context) -> ODVariable:
    avoid = (0x1005, 0x1010, 0x1011, 0x1014, 0x1016, 0x1200)
    vars_ = [v for v in rw_ints(ctx.device, 0x1000, 0x1FFF, avoid) if int_default(v) is not None]
    if not vars_:
        raise Skip("EDS lists no writable communication entry with a default")
    return vars_[0]


@case(
    "store",
    "save_across_reset",
    "a value saved with 'save' survives reset node; 'load' brings the default back at the next reset",
)
def save_across_reset(ctx: Context) -> None:
    require_store(ctx)
    dev = ctx.device
    dev.require(0x1011, 1, why="restore default parameters")
    var = _target(ctx)
    value = other_value(var)

    def restore() -> None:
        dev.write(0x1011, 1, LOAD)
        dev.reset(NMT_RESET_NODE)

    ctx.cleanup(restore)
    dev.write(var.index, var.subindex, value)
    dev.write(0x1010, 1, SAVE)
    reset_node(ctx)
    seen = dev.read(var.index, var.subindex)
    if seen != value:
        raise Fail(
            f"0x{var.index:04X}:{var.subindex} after save and reset node",
            expected=str(value),
            seen=str(seen),
        )
    dev.write(0x1011, 1, LOAD)
    reset_node(ctx)
    seen = dev.read(var.index, var.subindex)
    if seen != var.default:
        raise Fail(
            f"0x{var.index:04X}:{var.subindex} after load and reset node",
            expected=f"{var.default} (EDS default)",
            seen=str(seen),
        )


@case("store", "unsaved_lost", "a value written but not saved is lost at reset node")
def unsaved_lost(ctx: Context) -> None:
    dev = ctx.device
    var = _target(ctx)
    ctx.cleanup(lambda: dev.write(var.index, var.subindex, var.default))
    dev.write(var.index, var.subindex, other_value(var))
    reset_node(ctx)
    seen = dev.read(var.index, var.subindex)
    if seen != var.default:
        raise Fail(
            f"0x{var.index:04X}:{var.subindex} after reset node without save",
            expected=str(var.default),
            seen=str(seen),
        )
