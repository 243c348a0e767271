"""CiA 401 generic I/O: objects, device type, default PDO mapping, outputs to inputs, error modes.

The I/O cases need ``--loopback``: a bench where every DO n drives DI n and AO n drives AI n
(the seed manuals' demo bench; fieldgate's ``loopback`` back in tests).
"""

from __future__ import annotations

import time

from ..framework import Context, Fail, Skip, case
from .common import Pdo, active_pdo, operational
from .errctl import life_guard

IO = {0x6000: ("DI", 16), 0x6200: ("DO", 17), 0x6401: ("AI", 18), 0x6411: ("AO", 19)}


def require_401(ctx: Context) -> int:
    dev = ctx.device
    dev.require(0x1000)
    value: int = dev.read(0x1000, 0)
    if value & 0xFFFF != 0x0191:
        raise Skip(f"device type 0x{value:08X} is not CiA 401 (low word 0x0191)")
    return value


def require_loopback(ctx: Context) -> None:
    if not ctx.options.loopback:
        raise Skip("needs --loopback (outputs wired to inputs)")


def io_pdos(ctx: Context) -> tuple[Pdo, Pdo]:
    """RPDO1 (0x6200 DO bytes) and TPDO1 (0x6000 DI bytes) of a loopback bench; DO bytes restored afterwards."""
    require_loopback(ctx)
    dev = ctx.device
    rpdo = active_pdo(dev, tx=False, n=0)
    tpdo = active_pdo(dev, tx=True, n=0)
    if rpdo.entries[0] >> 16 != 0x6200 or tpdo.entries[0] >> 16 != 0x6000:
        raise Skip("RPDO1/TPDO1 do not map 0x6200/0x6000")
    old = bytes(dev.upload(0x6200, s + 1)[0] for s in range(len(rpdo.entries)))

    def restore() -> None:
        for s, value in enumerate(old, 1):
            dev.write(0x6200, s, value)

    ctx.cleanup(restore)
    return rpdo, tpdo


def wait_value(ctx: Context, index: int, sub: int, want: int, what: str) -> None:
    deadline = time.monotonic() + ctx.timing.bootup
    seen = None
    while time.monotonic() < deadline:
        seen = ctx.device.read(index, sub)
        if seen == want:
            return
        time.sleep(0.02)
    raise Fail(
        what,
        expected=f"0x{index:04X}:{sub} = {want:#x}",
        seen=f"{seen:#x}" if isinstance(seen, int) else str(seen),
    )


@case("cia401", "device_type", "0x1000 = 0x0191 with bits 16-19 telling which of DI/DO/AI/AO exist")
def device_type(ctx: Context) -> None:
    value = require_401(ctx)
    for index, (name, bit) in IO.items():
        if bool(value >> bit & 1) != ctx.device.has(index):
            raise Fail(
                f"0x1000 bit {bit} ({name}) disagrees with the EDS",
                expected=f"bit {bit} = {int(ctx.device.has(index))}",
                seen=f"0x{value:08X}",
            )


@case(
    "cia401",
    "objects",
    "0x6000/0x6200/0x6401/0x6411 counts and types; error-mode arrays match their outputs",
)
def objects(ctx: Context) -> None:
    require_401(ctx)
    dev = ctx.device
    counts = {}
    for index, (name, _) in IO.items():
        if not dev.has(index):
            continue
        counts[index] = dev.read(index, 0)
        for sub in range(1, counts[index] + 1):
            raw = dev.upload(index, sub)
            size = 1 if index in (0x6000, 0x6200) else 2
            if len(raw) != size:
                raise Fail(
                    f"0x{index:04X}:{sub} ({name}) size",
                    expected=f"{size} bytes",
                    seen=f"{len(raw)} bytes",
                )
    for mode, value, out in ((0x6206, 0x6207, 0x6200), (0x6443, 0x6444, 0x6411)):
        for index in (mode, value):
            if dev.has(index) and out in counts and dev.read(index, 0) != counts[out]:
                raise Fail(
                    f"0x{index:04X}:0 must equal the output count 0x{out:04X}:0",
                    expected=str(counts[out]),
                    seen=str(dev.read(index, 0)),
                )
    if not counts:
        raise Skip("EDS lists none of 0x6000/0x6200/0x6401/0x6411")


@case(
    "cia401",
    "default_mapping",
    "CiA 401 default PDOs: TPDO1 = 0x6000, RPDO1 = 0x6200, TPDO2 = 0x6401, RPDO2 = 0x6411",
)
def default_mapping(ctx: Context) -> None:
    require_401(ctx)
    dev = ctx.device
    checked = 0
    for index, mapping in ((0x6000, 0x1A00), (0x6200, 0x1600), (0x6401, 0x1A01), (0x6411, 0x1601)):
        if not (dev.has(index) and dev.has(mapping)):
            continue
        count = dev.read(mapping, 0)
        first = dev.read(mapping, 1) if count else 0
        if first >> 8 != index << 8 | 1:
            raise Fail(
                f"0x{mapping:04X}:1",
                expected=f"0x{index:04X}:01 mapped first",
                seen=f"0x{first:08X} (sub 0 = {count})",
            )
        checked += 1
    if not checked:
        raise Skip("EDS lists no CiA 401 I/O object with its default PDO")


@case("cia401", "do_to_di_sdo", "a DO byte written over SDO shows on the looped-back DI byte")
def do_to_di_sdo(ctx: Context) -> None:
    require_401(ctx)
    require_loopback(ctx)
    dev = ctx.device
    dev.require(0x6200, 1)
    dev.require(0x6000, 1)
    operational(ctx)
    for value in (0xA5, 0x5A):
        dev.patch(ctx, 0x6200, 1, value)
        wait_value(ctx, 0x6000, 1, value, "DI after writing DO over SDO")


@case(
    "cia401",
    "rpdo_to_tpdo",
    "RPDO1 (DO) comes back as TPDO1 (DI) through the loop, type 255 on change",
)
def rpdo_to_tpdo(ctx: Context) -> None:
    require_401(ctx)
    require_loopback(ctx)
    dev = ctx.device
    rpdo, tpdo = io_pdos(ctx)
    operational(ctx)
    pattern = bytes((0x3C + 17 * i) & 0xFF for i in range(rpdo.length))
    dev.link.flush()
    dev.link.send(rpdo.cob & 0x7FF, pattern)
    deadline = time.monotonic() + ctx.timing.bootup
    while time.monotonic() < deadline:
        frame = dev.link.expect(tpdo.cob & 0x7FF, deadline - time.monotonic())
        if (
            frame is not None
            and frame.data[: min(len(pattern), tpdo.length)] == pattern[: tpdo.length]
        ):
            return
    raise Fail(
        "TPDO1 never carried the looped-back DO pattern",
        expected=f"{tpdo.cob & 0x7FF:03X} [{tpdo.length}] {pattern.hex(' ')}",
        seen="see frames",
    )


@case("cia401", "ao_to_ai", "an AO written by RPDO2 shows on the looped-back AI (0x6401)")
def ao_to_ai(ctx: Context) -> None:
    require_401(ctx)
    require_loopback(ctx)
    dev = ctx.device
    rpdo = active_pdo(dev, tx=False, n=1)
    if rpdo.entries[0] >> 8 != 0x641101:
        raise Skip("RPDO2 does not map 0x6411:1 first")
    old = dev.upload(0x6411, 1)
    ctx.cleanup(lambda: dev.download(0x6411, 1, old))
    operational(ctx)
    payload = bytearray()
    for e in rpdo.entries:
        payload += dev.upload(e >> 16, (e >> 8) & 0xFF)
    payload[0:2] = (0x1234).to_bytes(2, "little")
    dev.link.send(rpdo.cob & 0x7FF, bytes(payload))
    wait_value(ctx, 0x6401, 1, 0x1234, "AI after RPDO2 wrote AO 0x1234")


def _error_mode(
    ctx: Context,
    mode_idx: int,
    value_idx: int,
    out_idx: int,
    in_idx: int,
    mode: int,
    err_value: int,
    before: int,
    after: int,
) -> None:
    require_401(ctx)
    require_loopback(ctx)
    dev = ctx.device
    for index in (mode_idx, value_idx, out_idx, in_idx, 0x100C):
        dev.require(index, 1 if index != 0x100C else None)
    dev.patch(ctx, mode_idx, 1, mode)
    dev.patch(ctx, value_idx, 1, err_value)
    dev.patch(ctx, out_idx, 1, before)
    operational(ctx)
    wait_value(ctx, in_idx, 1, before, "input before the error")
    frame, _, _ = life_guard(ctx, max(20, ctx.timing.heartbeat_ms // 2), 2)
    if frame is None:
        raise Fail("no life guarding event to trigger the error mode", seen="nothing")
    what = f"input after the communication error (mode {mode:#x}, value {err_value:#x})"
    if after == before:  # "keep": give the device time to do it wrong
        time.sleep(max(0.1, ctx.timing.silence))
        seen = dev.read(in_idx, 1)
        if seen != after:
            raise Fail(what, expected=f"0x{in_idx:04X}:1 = {after:#x} (kept)", seen=f"{seen:#x}")
        return
    wait_value(ctx, in_idx, 1, after, what)


@case(
    "cia401",
    "error_mode_do",
    "0x6206/0x6207: on a communication error masked DO bits take their error value",
)
def error_mode_do(ctx: Context) -> None:
    _error_mode(ctx, 0x6206, 0x6207, 0x6200, 0x6000, 0x31, 0xF8, 0xFF, 0xFE)


@case(
    "cia401", "error_mode_hold", "0x6206 = 0: on a communication error the DO bits keep their value"
)
def error_mode_hold(ctx: Context) -> None:
    _error_mode(ctx, 0x6206, 0x6207, 0x6200, 0x6000, 0x00, 0xFF, 0xA5, 0xA5)


@case(
    "cia401",
    "error_mode_ao",
    "0x6443/0x6444: on a communication error the AO takes its error value",
)
def error_mode_ao(ctx: Context) -> None:
    _error_mode(ctx, 0x6443, 0x6444, 0x6411, 0x6401, 1, 0x0100, 0x0777, 0x0100)
