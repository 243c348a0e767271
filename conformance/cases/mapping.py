"""PDO mapping granularity (CiA 301 §7.4.7.1, CiA 306 ``Granularity`` / ``[DummyUsage]``).

* dummy entries (0x0001-0x0007, sub 0) in an RPDO skip the bits of the data type;
  the EDS's ``[DummyUsage]`` says which the device accepts;
* bit-granular devices map single BOOLEAN channels (CiA 401 0x6020-/0x6220-) with length
  1, packed LSB first; byte-granular devices refuse entries shorter than their object.
"""

from __future__ import annotations

from canopen.objectdictionary import BOOLEAN, ODVariable

from ..device import SdoAbort, abort_text
from ..framework import Context, Fail, Skip, case
from .common import Pdo, active_pdo, invalidate, keep_mapping, operational, preop, remap
from .pdo import rtr, sync

NOT_MAPPABLE = 0x06040041
DUMMY_BITS = {0x0001: 1, 0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}


def dummies(ctx: Context) -> list[int]:
    """Dummy entries the EDS declares (canopen turns ``DummyNNNN=1`` into an object at NNNN)."""
    return [i for i in DUMMY_BITS if ctx.device.has(i)]


def bit_entries(ctx: Context, writable: bool) -> list[ODVariable]:
    """PDO-mappable BOOLEAN entries (1-bit mapping), writable ones for RPDOs, readable for TPDOs."""
    return [
        v
        for v in ctx.device.variables()
        if v.index >= 0x2000
        and v.data_type == BOOLEAN
        and v.pdo_mappable
        and (v.writable if writable else v.readable)
    ]


def revalidate(ctx: Context, pdo: Pdo) -> None:
    """Make a remapped PDO valid again on its own COB-ID; invalid first when the case ends."""
    dev = ctx.device
    dev.write(pdo.comm, 1, pdo.cob & ~0x80000000)
    ctx.cleanup(lambda: dev.write(pdo.comm, 1, dev.read(pdo.comm, 1) | 0x80000000))


def entry(var: ODVariable, bits: int | None = None) -> int:
    return var.index << 16 | var.subindex << 8 | (len(var) if bits is None else bits)


def send_rpdo(ctx: Context, pdo: Pdo, data: bytes) -> None:
    """The RPDO in Operational (a SYNC after it for synchronous types), then Pre-operational."""
    dev = ctx.device
    operational(ctx)
    dev.link.flush()
    dev.link.send(pdo.cob & 0x7FF, data)
    if dev.read(pdo.comm, 2) <= 240:
        sync(ctx)
    dev.sdo_request(bytes([0x40, 0x00, 0x10, 0x00]))  # a round trip: the RPDO was handled
    preop(ctx)


@case(
    "sync-pdo",
    "dummy_mapping",
    "an RPDO with a dummy entry first skips its bits and writes the object after it",
)
def dummy_mapping(ctx: Context) -> None:
    dev = ctx.device
    byte_dummies = [i for i in dummies(ctx) if DUMMY_BITS[i] % 8 == 0]
    if not byte_dummies:
        raise Skip("the EDS declares no whole-byte dummy entry ([DummyUsage])")
    pdo = active_pdo(ctx, tx=False)
    target = pdo.entries[0]
    index, sub, bits = target >> 16, target >> 8 & 0xFF, target & 0xFF
    if bits % 8 or bits > 32:
        raise Skip(f"{pdo.name}'s first entry is {bits} bits")
    dummy = byte_dummies[0]
    old = dev.upload(index, sub)[: bits // 8]
    ctx.cleanup(lambda: dev.write(index, sub, old))
    new = bytes([old[0] ^ 0x01]) + old[1:]
    skipped = DUMMY_BITS[dummy] // 8
    remap(ctx, pdo, [dummy << 16 | DUMMY_BITS[dummy], target])
    live = Pdo(pdo.n, pdo.tx, pdo.cob, [dummy << 16 | DUMMY_BITS[dummy], target])
    revalidate(ctx, live)
    send_rpdo(ctx, live, bytes([0xA5]) * skipped + new)
    seen = dev.upload(index, sub)[: bits // 8]
    if seen != new:
        raise Fail(
            f"{pdo.name} with dummy 0x{dummy:04X} then 0x{index:04X}:{sub}",
            expected=f"0x{index:04X}:{sub} = {new.hex(' ')} (the {skipped} dummy byte(s) skipped)",
            seen=seen.hex(" "),
        )


@case(
    "sync-pdo",
    "dummy_undeclared",
    "a dummy entry the EDS does not declare is refused with 0604 0041",
)
def dummy_undeclared(ctx: Context) -> None:
    dev = ctx.device
    missing = [i for i in DUMMY_BITS if i not in dummies(ctx)]
    if not missing:
        raise Skip("the EDS declares every dummy entry")
    pdo = active_pdo(ctx, tx=False)
    invalidate(ctx, pdo)
    keep_mapping(ctx, pdo)
    dev.write(pdo.mapping, 0, 0)
    dummy = missing[0]
    dev.expect_write_abort(
        pdo.mapping,
        1,
        (dummy << 16 | DUMMY_BITS[dummy]).to_bytes(4, "little"),
        (NOT_MAPPABLE,),
        f"undeclared dummy 0x{dummy:04X}",
    )


@case(
    "sync-pdo",
    "bit_mapping",
    "bit-granular device: 1-bit entries pack LSB first, in RPDOs (0x6220) and TPDOs (0x6020)",
)
def bit_mapping(ctx: Context) -> None:
    dev = ctx.device
    outs, ins = bit_entries(ctx, writable=True), bit_entries(ctx, writable=False)
    outs = [v for v in outs if v.index in range(0x6220, 0x6228)] or outs
    if len(outs) < 2:
        raise Skip("no 1-bit mappable BOOLEAN outputs in the EDS (byte granularity)")
    a, b = outs[0], outs[1]
    old = [dev.read(v.index, v.subindex) for v in (a, b)]

    def restore_bits() -> None:
        for v, value in zip((a, b), old, strict=True):
            dev.write(v.index, v.subindex, value)

    ctx.cleanup(restore_bits)
    rpdo = active_pdo(ctx, tx=False)
    entries = [entry(a, 1), entry(b, 1)]
    remap(ctx, rpdo, entries)
    live = Pdo(rpdo.n, rpdo.tx, rpdo.cob, entries)
    revalidate(ctx, live)
    want = [int(not old[0]), int(old[1])]
    send_rpdo(ctx, live, bytes([want[0] | want[1] << 1]))
    seen = [int(dev.read(v.index, v.subindex)) for v in (a, b)]
    if seen != want:
        raise Fail(
            f"{rpdo.name} mapping 2 bits (0x{a.index:04X}:{a.subindex}, 0x{b.index:04X}:{b.subindex})",
            expected=f"{want} after frame {want[0] | want[1] << 1:02X}",
            seen=str(seen),
        )
    ins = [v for v in ins if v.index in range(0x6020, 0x6028)] or ins
    if len(ins) < 2 or not dev.has(0x6000, 1):
        return  # outputs checked; no input bits to check
    tpdo = active_pdo(ctx, tx=True, rtr=True)
    tx_entries = [entry(ins[0], 1), entry(ins[1], 1), 0x60000108]
    remap(ctx, tpdo, tx_entries)
    tlive = Pdo(tpdo.n, tpdo.tx, tpdo.cob, tx_entries)
    revalidate(ctx, tlive)
    operational(ctx)
    frame = rtr(ctx, Pdo(tpdo.n, True, tpdo.cob, [0x60000110]))  # RTR DLC 2: the 10 bits
    if frame is None:
        raise Fail(f"no answer to RTR on {tpdo.name}", expected="2 bytes", seen="nothing")
    if len(frame.data) != 2:
        raise Fail(f"{tpdo.name} DLC with 1 + 1 + 8 bits mapped", expected="2", seen=str(frame))
    packed = int.from_bytes(frame.data, "little")
    first_byte = packed >> 2 & 0xFF
    if (packed & 0b11) != (first_byte & 0b11):
        raise Fail(
            f"{tpdo.name}: bits 0-1 ({ins[0].subindex}, {ins[1].subindex}) and 0x6000:1 in bits 2-9 disagree",
            expected=f"bits 0-1 = bits 0-1 of 0x6000:1 (0x{first_byte:02X})",
            seen=str(frame),
        )


@case(
    "sync-pdo",
    "granularity_whole_bytes",
    "byte-granular device: an entry shorter than its object is refused with 0604 0041",
)
def granularity_whole_bytes(ctx: Context) -> None:
    dev = ctx.device
    if bit_entries(ctx, writable=True) or bit_entries(ctx, writable=False):
        raise Skip("the device maps single bits (BOOLEAN mappable entries)")
    pdo = active_pdo(ctx, tx=True)
    target = next((e for e in pdo.entries if (e & 0xFF) >= 8), None)
    if target is None:
        raise Skip(f"{pdo.name} maps no whole-byte object")
    invalidate(ctx, pdo)
    keep_mapping(ctx, pdo)
    dev.write(pdo.mapping, 0, 0)
    short = target & ~0xFF | 4
    try:
        dev.write(pdo.mapping, 1, short)
    except SdoAbort as exc:
        if exc.code != NOT_MAPPABLE:
            raise Fail(
                "4-bit entry refused with the wrong code",
                expected=abort_text(NOT_MAPPABLE),
                seen=abort_text(exc.code),
            ) from None
        return
    dev.expect_write_abort(
        pdo.mapping, 0, bytes([1]), (NOT_MAPPABLE, 0x06040042), f"sub 0 = 1 with 0x{short:08X}"
    )
