"""The ``na9161`` profile: devices that claim CREVIS NA-9161 compatibility (seed-004).

FnBus register 0x4500 (TV-06..TV-10), the digital packing modes (§2.2: compressed =
one bit stream, non-compressed = a byte per module), the special-module areas
0x3000/0x3200 (raw bytes, user-mapped only, §2.7) and the 0x2020/0x2220 bit counts.

Where the seed is silent the cases grade what fieldgate chose and documents
(docs/na9161.md): a written data mode or slot flag takes effect at the next NMT Reset
Node ([AMBIG-35]). Opt-in like ``seed``: run with ``--profile na9161`` (or ``all``).

The rows of the seed audit issue 32 closed: the field-power bit of 0x4500:1 (§5.3), slot
memory that is the module's and not its I/O (§3.3), "Changed HW configuration" at power-on on
defaults (§4.5; needs ``--power-cycle``), saved COB-IDs kept across a node-ID change (0x1010,
[AMBIG-24]; the node-ID changed by LSS).
"""

from __future__ import annotations

import time

from ..device import NMT_RESET_COMM, NMT_RESET_NODE, mux
from ..framework import Context, Fail, Skip, case
from .cia401 import require_loopback
from .common import (
    LOAD,
    SAVE,
    Pdo,
    active_pdo,
    expect_emcy,
    operational,
    pdos,
    remap,
    require_store,
)
from .lss import CONFIGURATION, WAITING, lss, must, require_lss, restore_node_id, spare_id
from .lss import switch as lss_switch
from .mapping import revalidate
from .od import RO_WRITE_ABORTS
from .pdo import rtr

FNBUS, SI, SO = 0x4500, 0x3000, 0x3200
VALUE_ABORTS = (0x06090030, 0x06090031, 0x08000000)
AREAS = ((0x6000, 0x2020, "input"), (0x6200, 0x2220, "output"))


def require_fnbus(ctx: Context, sub: int | None = None) -> None:
    ctx.device.require(FNBUS, sub, why="FnBus communication register (NA-9161)")


def reset_node(ctx: Context, after: str) -> None:
    if ctx.device.reset(NMT_RESET_NODE) is None:
        raise Fail(f"no boot-up after NMT Reset Node ({after})", expected="700+ID [1] 00")


def slot_count(ctx: Context) -> int:
    """Modules attached: 0x4503:0 (product codes), else fieldgate's 0x2010:0."""
    dev = ctx.device
    for index in (0x4503, 0x2010):
        if dev.has(index, 0):
            return int(dev.read(index, 0))
    raise Skip("EDS lists neither 0x4503 nor 0x2010: the number of slots is unknown")


@case("na9161", "fnbus_register", "0x4500: 3 subs, status U32 ro, data mode 0/1, slot flags U32")
def fnbus_register(ctx: Context) -> None:
    dev = ctx.device
    require_fnbus(ctx, 2)
    answer = dev.sdo(bytes([0x40]) + mux(FNBUS, 0))
    if answer.data[0] != 0x4F or answer.data[4] != 3:
        raise Fail("0x4500:0", expected="4F 00 45 00 03 ...", seen=str(answer))
    for sub in (1, 3):
        answer = dev.sdo(bytes([0x40]) + mux(FNBUS, sub))  # TV-06 / TV-09
        if answer.data[0] not in (0x43, 0x41):
            raise Fail(f"0x4500:{sub} is UNSIGNED32", expected="43 00 45 ..", seen=str(answer))
    mode = dev.read(FNBUS, 2)
    if mode not in (0, 1):
        raise Fail("0x4500:2 data mode", expected="0 or 1", seen=str(mode))
    # TV-08: the mode written back, byte for byte (1-byte expedited download)
    answer = dev.sdo(bytes([0x2F]) + mux(FNBUS, 2) + bytes([mode, 0, 0, 0]))
    if bytes(answer.data) != bytes.fromhex("60 00 45 02 00 00 00 00"):
        raise Fail("TV-08 write 0x4500:2", expected="60 00 45 02 00 00 00 00", seen=str(answer))
    dev.expect_write_abort(FNBUS, 2, bytes([2]), VALUE_ABORTS, "0x4500:2 = 2")
    dev.expect_write_abort(FNBUS, 1, bytes(4), RO_WRITE_ABORTS, "0x4500:1 (read-only)")


@case(
    "na9161",
    "slot_flags",
    "0x4500:3 takes a bit per slot (TV-10, DS301-strict form); a bit past the last slot is refused",
)
def slot_flags(ctx: Context) -> None:
    dev = ctx.device
    require_fnbus(ctx, 3)
    slots = slot_count(ctx)
    if not 0 < slots < 32:
        raise Skip(f"{slots} slots: no free flag bit to test the refusal")
    old = dev.read(FNBUS, 3)
    ctx.cleanup(lambda: dev.write(FNBUS, 3, old))
    answer = dev.sdo(bytes([0x23]) + mux(FNBUS, 3) + (old ^ 1).to_bytes(4, "little"))
    if bytes(answer.data) != bytes.fromhex("60 00 45 03 00 00 00 00"):
        raise Fail("TV-10 write 0x4500:3", expected="60 00 45 03 00 00 00 00", seen=str(answer))
    if dev.read(FNBUS, 3) != old ^ 1:
        raise Fail("0x4500:3 reads back", expected=f"0x{old ^ 1:08X}")
    dev.expect_write_abort(
        FNBUS, 3, (1 << slots).to_bytes(4, "little"), VALUE_ABORTS, f"slot {slots + 1} flag"
    )


def _bits(ctx: Context, count_index: int) -> int | None:
    dev = ctx.device
    return int(dev.read(count_index, 1)) if dev.has(count_index, 1) else None


def digital_bits(code: int) -> tuple[int, int]:
    """(input, output) digital points of a slot from its 0x4503 product code (§2.5): a
    digital-family module's size codes; analog and special modules have none ([AMBIG-10])."""
    wire = code.to_bytes(4, "little")
    if wire[3] != 0x01:
        return 0, 0

    def points(size: int) -> int:
        if size == 0xC0:
            return 0
        if size & 0x80:
            return (size & 0x3F) + 1
        return 8 * ((size & 0x3F) + 1) if not size & 0x40 else 0

    return points(wire[0]), points(wire[1])


def module_bits(ctx: Context) -> list[tuple[int, int]] | None:
    """Each active slot's digital points, from 0x4503, when every slot is active; else None."""
    dev = ctx.device
    if not dev.has(0x4503, 0):
        return None
    if dev.has(FNBUS, 3) and dev.read(FNBUS, 3):
        return None  # deactivated slots: the codes describe more than the image
    return [digital_bits(dev.read(0x4503, n)) for n in range(1, dev.read(0x4503, 0) + 1)]


@case(
    "na9161",
    "data_mode_layout",
    "after Reset Node, compressed mode packs the bits (0x2020:1) into ceil(n/8) bytes, non-compressed a byte per module (0x4503)",
)
def data_mode_layout(ctx: Context) -> None:
    dev = ctx.device
    require_fnbus(ctx, 2)
    areas = [(obj, bits, name) for obj, bits, name in AREAS if dev.has(obj) and dev.has(bits, 1)]
    if not areas:
        raise Skip("EDS lists no 0x6000/0x2020 or 0x6200/0x2220 pair")
    old = dev.read(FNBUS, 2)
    slots = module_bits(ctx)

    def restore() -> None:
        dev.write(FNBUS, 2, old)
        dev.reset(NMT_RESET_NODE)

    ctx.cleanup(restore)
    for mode in (1, 0):
        dev.write(FNBUS, 2, mode)
        reset_node(ctx, f"0x4500:2 = {mode}")
        if dev.read(FNBUS, 2) != mode:
            raise Fail(
                "0x4500:2 after Reset Node", expected=str(mode), seen=str(dev.read(FNBUS, 2))
            )
        for obj, bits_index, name in areas:
            direction = 0 if obj == 0x6000 else 1
            bits = _bits(ctx, bits_index) or 0
            n = dev.read(obj, 0)
            need, exact = (bits + 7) // 8, mode == 1
            per_slot = [b[direction] for b in slots] if slots is not None else None
            if per_slot is not None and sum(per_slot) == bits and mode == 0:
                need, exact = sum((b + 7) // 8 for b in per_slot), True  # a byte per module
            if (n != need) if exact else (n < need):
                mode_name = "compressed" if mode else "non-compressed"
                raise Fail(
                    f"0x{obj:04X}:0 ({name} bytes) in {mode_name} mode",
                    expected=f"{'' if exact else '>= '}{need} for {bits} bits (0x{bits_index:04X}:1"
                    + (" and the slots' 0x4503 codes)" if exact and not mode else ")"),
                    seen=str(n),
                )


@case(
    "na9161",
    "bit_counts",
    "0x2020:1 / 0x2220:1 (TV-04/TV-05) are UNSIGNED16 and fit 0x6000 / 0x6200",
)
def bit_counts(ctx: Context) -> None:
    dev = ctx.device
    found = False
    for obj, bits_index, name in AREAS:
        if not dev.has(bits_index, 1):
            continue
        found = True
        answer = dev.sdo(bytes([0x40]) + mux(bits_index, 1))
        if answer.data[0] != 0x4B:
            raise Fail(f"0x{bits_index:04X}:1 is UNSIGNED16", expected="4B ...", seen=str(answer))
        bits = int.from_bytes(answer.data[4:6], "little")
        have = dev.read(obj, 0) if dev.has(obj) else 0
        if bits > 8 * have:
            raise Fail(
                f"{bits} digital {name} bits do not fit 0x{obj:04X}", expected=f"<= {8 * have}"
            )
    if not found:
        raise Skip("EDS lists neither 0x2020:1 nor 0x2220:1")


def _special(ctx: Context) -> list[int]:
    present = [i for i in (SI, SO) if ctx.device.has(i, 1)]
    if not present:
        raise Skip("EDS lists no special-module area 0x3000/0x3200 (no special modules)")
    return present


@case(
    "na9161",
    "special_areas",
    "0x3000/0x3200: sub 0 = bytes, UNSIGNED8, 0x3000 read-only, 0x3200 writable, PDO-mappable, not in the default mapping",
)
def special_areas(ctx: Context) -> None:
    dev = ctx.device
    for index in _special(ctx):
        n = dev.read(index, 0)
        if not 1 <= n <= 64 or not dev.has(index, n) or dev.has(index, n + 1):
            raise Fail(
                f"0x{index:04X}:0",
                expected="the number of bytes (1..64) the EDS lists",
                seen=str(n),
            )
        for sub in range(1, n + 1):
            var = dev.var(index, sub)
            if var is None or var.data_type != 0x0005 or not var.pdo_mappable:
                raise Fail(f"0x{index:04X}:{sub} in the EDS", expected="UNSIGNED8, PDOMapping=1")
            if len(dev.upload(index, sub)) != 1:
                raise Fail(f"0x{index:04X}:{sub} upload", expected="1 byte")
        if index == SI:
            dev.expect_write_abort(SI, 1, b"\x00", RO_WRITE_ABORTS, "0x3000:1 (inputs)")
        else:
            value = dev.upload(SO, 1)

            def restore(value: bytes = value) -> None:
                dev.download(SO, 1, value)

            ctx.cleanup(restore)
            dev.download(SO, 1, value)  # AMBIG-13: the seed prints ro; outputs must be writable
    defaults = [e for p in pdos(dev, True) + pdos(dev, False) for e in p.entries]
    mapped = sorted({e >> 16 for e in defaults} & {SI, SO})
    if mapped:
        raise Fail(
            "special data in the default PDO mapping (seed-004 §2.7: user-mapped only)",
            expected="no 0x3000/0x3200 entry in the EDS defaults of 0x1600-/0x1A00-",
            seen=", ".join(f"0x{i:04X}" for i in mapped),
        )


@case(
    "na9161",
    "special_tpdo",
    "0x3000 bytes mapped by the user into a TPDO come as SDO shows them (RTR)",
)
def special_tpdo(ctx: Context) -> None:
    dev = ctx.device
    if SI not in _special(ctx):
        raise Skip("EDS lists no 0x3000 (no special inputs)")
    n = min(8, dev.read(SI, 0))
    tpdo = active_pdo(dev, tx=True, rtr=True)
    entries = [SI << 16 | s << 8 | 8 for s in range(1, n + 1)]
    remap(ctx, tpdo, entries)
    live = Pdo(tpdo.n, True, tpdo.cob, entries)
    revalidate(ctx, live)
    before = b"".join(dev.upload(SI, s) for s in range(1, n + 1))
    operational(ctx)
    frame = rtr(ctx, live)
    after = b"".join(dev.upload(SI, s) for s in range(1, n + 1))
    if frame is None:
        raise Fail(f"no answer to RTR on {tpdo.name}", expected=f"{n} bytes", seen="nothing")
    if bytes(frame.data) not in (before, after):
        raise Fail(
            f"{tpdo.name} mapping 0x3000:1..{n}",
            expected=before.hex(" ") + (f" (or {after.hex(' ')})" if after != before else ""),
            seen=str(frame),
        )


# -- the rows of the seed audit issue 32 closed (docs/na9161.md) -------------------------------
@case(
    "na9161",
    "field_power_bit",
    "0x4500:1 byte 3 reports the field supply: 0x00 present, 0x80 missing (§5.3, TV-06)",
)
def field_power_bit(ctx: Context) -> None:
    require_fnbus(ctx, 1)
    status = ctx.device.read(FNBUS, 1)
    power = status >> 24 & 0xFF
    if power not in (0x00, 0x80):
        raise Fail(
            "0x4500:1 byte 3", expected="0x00 (supplied) or 0x80 (missing)", seen=f"0x{power:02X}"
        )


@case(
    "na9161",
    "slot_memory_not_io",
    "0x2000:n is the slot module's memory, not its I/O: an input change leaves it as it was (§3.3)",
)
def slot_memory_not_io(ctx: Context) -> None:
    dev = ctx.device
    require_fnbus(ctx)  # (0x2000 of an ICP DAS-style head holds error counters)
    dev.require(0x2000, 1, why="slot memory")
    require_loopback(ctx)
    dev.require(0x6411, 1, why="an AO looped back to an AI")
    count = int(dev.read(0x2000, 0))
    before = [dev.upload(0x2000, n) for n in range(1, count + 1)]
    old = dev.read(0x6411, 1)
    ctx.cleanup(lambda: dev.write(0x6411, 1, old))
    new = (old + 0x321) & 0x7FFF
    dev.write(0x6411, 1, new)
    deadline = time.monotonic() + ctx.timing.bootup
    while dev.read(0x6401, 1) != new and time.monotonic() < deadline:
        time.sleep(0.02)
    after = [dev.upload(0x2000, n) for n in range(1, count + 1)]
    changed = [n for n, (a, b) in enumerate(zip(before, after, strict=True), 1) if a != b]
    if changed:
        raise Fail(
            f"0x2000:{changed[0]} follows the slot's inputs",
            expected="the module's memory (parameters), unchanged by an I/O change",
            seen=f"{before[changed[0] - 1].hex(' ')} -> {after[changed[0] - 1].hex(' ')}",
            clause="NA-9161 manual §3.3 (0x2000 read memory), §9.6",
        )


@case(
    "na9161",
    "hw_config_emcy",
    "a head on its defaults sends 'Changed HW configuration' at power-on (§4.5, 0x1010)",
)
def hw_config_emcy(ctx: Context) -> None:
    dev = ctx.device
    require_fnbus(ctx)
    dev.require(0x1011, 1, why="restore default parameters")
    if ctx.options.power_cycle is None:
        raise Skip("needs --power-cycle COMMAND: the EMCY comes at power-on only")
    dev.write(0x1011, 1, LOAD)  # the defaults at the next power-on
    dev.link.flush()
    ctx.options.power_cycle()
    if dev.wait_bootup() is None:
        raise Fail("no boot-up after the power cycle", expected="700+ID [1] 00")
    frame = expect_emcy(ctx, 0x6300)
    if frame is None:
        raise Fail(
            "no 'Changed HW configuration' EMCY at power-on on defaults",
            expected=f"{0x80 + dev.node_id:03X} [8] 00 63 .. (0x6300 data set)",
            seen="nothing",
            clause="NA-9161 manual §4.5, §9.7.1 (0x1010)",
        )


@case(
    "na9161",
    "stored_cob_ids_kept",
    "saved COB-IDs keep their values when only the node-ID changes (0x1010, [AMBIG-24])",
)
def stored_cob_ids_kept(ctx: Context) -> None:
    dev = ctx.device
    require_fnbus(ctx)
    require_store(ctx)
    require_lss(ctx)  # (the NA-9161 changes it by switch; the tester can only by LSS)
    tpdo1 = dev.read(0x1800, 1) if dev.has(0x1800, 1) else None
    if tpdo1 is None or tpdo1 & 0x7FF != 0x180 + dev.node_id:
        raise Skip("TPDO1 is not at its predefined COB-ID 0x180 + node-ID")
    ctx.cleanup(lambda: reset_node(ctx, "defaults back"))
    ctx.cleanup(lambda: dev.write(0x1011, 1, LOAD))
    dev.write(0x1010, 1, SAVE)
    new = spare_id(ctx)
    lss_switch(ctx, CONFIGURATION)
    if must(ctx, [0x11, new], 0x11, f"configure node-ID {new}").data[1] != 0:
        raise Skip(f"the device refuses node-ID {new} by LSS")
    ctx.cleanup(lambda: restore_node_id(ctx, new))
    lss(ctx, [0x04, WAITING])
    dev.link.flush()
    dev.nmt(NMT_RESET_COMM)
    if dev.wait_bootup(new) is None:
        raise Fail("no boot-up on the new node-ID", expected=f"{0x700 + new:03X} [1] 00")
    seen = None
    for _ in range(2):  # (a device may open its new SDO channel just after the boot-up)
        dev.link.flush()
        dev.link.send(0x600 + new, bytes.fromhex("40 00 18 01 00 00 00 00"))
        answer = dev.link.expect(0x580 + new, ctx.timing.response)
        if answer is not None:
            seen = int.from_bytes(answer.data[4:8], "little")
            break
    if seen is None:
        raise Fail("no SDO answer on the new node-ID", expected=f"{0x580 + new:03X} ..")
    if seen & 0x7FF != tpdo1 & 0x7FF:
        raise Fail(
            "TPDO1's saved COB-ID followed the new node-ID",
            expected=f"0x{tpdo1 & 0x7FF:03X} (the stored value)",
            seen=f"0x{seen & 0x7FF:03X}",
            clause="NA-9161 manual §9.7.1 (0x1010)",
        )
