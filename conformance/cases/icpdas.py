"""More ``icpdas`` profile cases (beside those of :mod:`.profiles`): the rows of the seed audit
issue 32 closed (docs/canopen-io.md, "icpdas: manual says / fieldgate does").

* ``no_tpdo_at_start``: NMT Start gets no response frame (I-7232D TV-07); the first TPDO comes
  with the first event (audit 000 #53);
* ``store_write_emcy``: a save the device cannot write is refused and reported with the
  table's "EEPROM access error" EMCY ``00 50 81 02`` (§2.5; audit 000 #14, 001 #6);
* ``module_limits``: the modules behind the head fit the box the style copies (I-7232D: 10
  Modbus modules, §1.3; I-7231D: 15 DCON modules, §2.2): INFO for a superset (audit 000 #40,
  001 #12).
"""

from __future__ import annotations

from ..device import SdoAbort
from ..framework import Context, Fail, Inconclusive, Info, Skip, case
from .common import (
    LOAD,
    SAVE,
    error_free,
    expect_emcy,
    live_pdo,
    log_mark,
    operational,
    pdos,
)
from .profiles import require_icpdas

HARDWARE_ERROR = 0x06060000
EMCY_5000 = bytes.fromhex("00 50")
I7232D_MODULES, I7231D_MODULES = 10, 15


def _inputs(ctx: Context) -> dict[tuple[int, int], int]:
    """Every DI byte and AI channel the EDS lists, as read now."""
    dev = ctx.device
    values = {}
    for index in (0x6000, 0x6401):
        if dev.has(index, 1):
            values.update(
                {(index, s): dev.read(index, s) for s in range(1, dev.read(index, 0) + 1)}
            )
    return values


@case(
    "icpdas",
    "no_tpdo_at_start",
    "NMT Start: no response frame, no TPDO until an event (TV-07)",
)
def icpdas_no_tpdo_at_start(ctx: Context) -> None:
    require_icpdas(ctx)
    dev = ctx.device
    if dev.has(0x1017) or dev.has(0x1016):
        raise Skip(
            "EDS lists 0x1016/0x1017: a master profile added heartbeat (the Delta AS300 also "
            "needs each TPDO after Start, E2)"
        )
    cobs = {
        live.cob & 0x7FF for p in pdos(dev, True) if not (live := live_pdo(dev, p)).cob & 0x80000000
    }
    if not cobs:
        raise Skip("no valid TPDO")
    before = _inputs(ctx)
    log_mark(ctx)
    operational(ctx)
    frames = dev.link.collect(lambda f: f.cob in cobs and not f.rtr, ctx.timing.silence + 0.2)
    if frames and _inputs(ctx) != before:
        raise Inconclusive("the inputs changed while the case watched: TPDOs may be events")
    if frames:
        raise Fail(
            "TPDO after NMT Start",
            expected="no frame (TV-07: 'No response frame. The node goes to Operational')",
            seen=str(frames[0]),
            clause="I-7232D manual §5.2.3 TV-07",
        )


@case(
    "icpdas",
    "store_write_emcy",
    "a save that cannot be written: abort 0606 0000 and EMCY 00 50 81 02 (EEPROM access error)",
)
def icpdas_store_write_emcy(ctx: Context) -> None:
    require_icpdas(ctx)
    dev = ctx.device
    dev.require(0x1010, 1, why="store parameters (the I-7232D has none: an extension)")
    error_free(ctx, "before the case (an EEPROM error already active sends no new EMCY)")
    mark = log_mark(ctx)
    try:
        dev.write(0x1010, 1, SAVE)
    except SdoAbort as exc:
        refused = exc
    else:
        ctx.cleanup(lambda: dev.write(0x1011, 1, LOAD))
        raise Skip(
            "the store could be written: the case needs a device whose store cannot be (a full "
            "or read-only state directory)"
        )
    if refused.code != HARDWARE_ERROR:
        raise Fail(
            "a save refused",
            expected="0606 0000 (hardware error: the store cannot be written)",
            seen=str(refused),
        )
    frame = expect_emcy(ctx, 0x5000)
    if frame is None:
        for _, direction, seen in dev.link.log[mark:]:  # (it may precede the abort)
            if (
                direction == "←"
                and seen.cob == 0x80 + dev.node_id
                and bytes(seen.data[:2]) == EMCY_5000
            ):
                frame = seen
    if frame is None or bytes(frame.data[2:4]) != b"\x81\x02":
        raise Fail(
            "no EEPROM access error EMCY for the failed save",
            expected=f"{0x80 + dev.node_id:03X} [8] 00 50 81 02 00 00 00 00 (§2.5)",
            seen=str(frame) if frame else "nothing",
            clause="I-7232D manual §2.5 EMCY table",
        )


@case(
    "icpdas",
    "module_limits",
    "the modules fit the box the style copies (I-7232D: 10, I-7231D: 15; 0x2000:0)",
)
def icpdas_module_limits(ctx: Context) -> None:
    require_icpdas(ctx)
    dev = ctx.device
    dev.require(0x2000, 0, why="module error counters (a sub-index per module)")
    count = dev.read(0x2000, 0)
    dcon = dev.has(0x2001)  # the I-7231D's DCON host watchdog objects
    box, most = ("I-7231D", I7231D_MODULES) if dcon else ("I-7232D", I7232D_MODULES)
    if count > most:
        raise Info(
            f"{count} modules: more than the {box} holds ({most}); a superset that would not "
            "go back onto the real box",
            seen=f"0x2000:0 = {count}",
        )
