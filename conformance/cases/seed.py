"""The ``seed`` profile: the worked frame examples (TV-*) of the I-7232D and I-7231D manuals
(seed-000 / seed-001), replayed frame by frame, for devices that claim compatibility.

The manuals use node 1; the replay uses the device's node-ID (COB-IDs are shifted). Where
an extract marks a printed frame as a misprint, the corrected frame is used (its **Note**).
Expedited SDO answers are compared on their valid bytes only (the devices leave stale bytes).
PDO vectors need ``--loopback`` (DO wired to DI, AO to AI; the seed-001 bench's inverting
wiring is not assumed).
"""

from __future__ import annotations

import struct
import time

from ..device import NMT_START, StateProbe
from ..framework import Context, Fail, Skip, case
from .cia401 import _error_mode, io_pdos, require_loopback, wait_value
from .common import Pdo, active_pdo, live_pdo, operational, remap
from .errctl import life_guard
from .lss import CONFIGURATION, WAITING, identity, lss, must, require_lss
from .sdo import require_block


def replay(ctx: Context, script: str) -> None:
    """Run a vector. Lines: ``-> COB data`` send, ``<- COB data`` expect, ``-- COB`` silence,
    ``sync``. ``COB+`` adds the node-ID; ``??`` matches any byte; a trailing ``*`` any further bytes;
    ``RTR`` sends a remote frame."""
    dev = ctx.device
    for raw in script.strip().splitlines():
        words = raw.split("#")[0].split()
        if not words:
            continue
        op = words[0]
        if op == "sync":
            dev.link.send(0x080, b"")
            continue
        cob = int(words[1].rstrip("+"), 16) + (dev.node_id if words[1].endswith("+") else 0)
        rest = words[2:]
        if op == "->":
            if rest[:1] == ["RTR"]:
                dev.link.send(cob, rtr=True, dlc=int(rest[1]) if len(rest) > 1 else 0)
            else:
                dev.link.flush()
                dev.link.send(cob, bytes(int(b, 16) for b in rest))
        elif op == "<-":
            frame = dev.link.expect(cob, ctx.timing.response)
            want = " ".join(rest)
            if frame is None:
                raise Fail(
                    f"vector step '{raw.strip()}'", expected=f"{cob:03X} {want}", seen="nothing"
                )
            if not _match(frame.data, rest):
                raise Fail(
                    f"vector step '{raw.strip()}'", expected=f"{cob:03X} {want}", seen=str(frame)
                )
        elif op == "--":
            frame = dev.link.expect(cob, ctx.timing.silence)
            if frame is not None:
                raise Fail(
                    f"vector step '{raw.strip()}'",
                    expected=f"nothing on {cob:03X}",
                    seen=str(frame),
                )
        else:
            raise ValueError(f"bad vector line {raw!r}")


def _match(data: bytes, pattern: list[str]) -> bool:
    open_end = pattern[-1:] == ["*"]
    tokens = pattern[:-1] if open_end else pattern
    if len(data) < len(tokens) or (not open_end and len(data) != len(tokens)):
        return False
    return all(
        t == "??" or int(t, 16) == b for t, b in zip(tokens, data[: len(tokens)], strict=True)
    )


def require_objects(ctx: Context, *indices: int) -> None:
    for index in indices:
        ctx.device.require(index, why="object used by the seed vector")


def restore_later(ctx: Context, index: int, sub: int) -> None:
    dev = ctx.device
    old = dev.upload(index, sub)
    ctx.cleanup(lambda: dev.download(index, sub, old))


@case("seed", "tv01_expedited_upload", "TV-01 / TV-S01: 0x1400:0 = 2 by expedited upload")
def tv01(ctx: Context) -> None:
    require_objects(ctx, 0x1400)
    highest = ctx.device.od_default(0x1400, 0, 2)
    if highest != 2:
        raise Skip(
            f"the EDS gives 0x1400 {highest} sub-entries (CiA 301 v4.2 allows 2 or 5); the"
            " I-7232D's answer byte 02 is its own"
        )
    replay(
        ctx,
        """
        -> 600+ 40 00 14 00 00 00 00 00
        <- 580+ 4F 00 14 00 02 ?? ?? ??
    """,
    )


def _segments(value: bytes, index: int) -> str:
    lo, hi = index & 0xFF, index >> 8
    lines = [
        f"-> 600+ 40 {lo:02X} {hi:02X} 00 00 00 00 00",
        f"<- 580+ 41 {lo:02X} {hi:02X} 00 {' '.join(f'{b:02X}' for b in struct.pack('<I', len(value)))}",
    ]
    toggle = 0
    for pos in range(0, len(value), 7):
        chunk = value[pos : pos + 7]
        last = pos + 7 >= len(value)
        b0 = toggle << 4 | (7 - len(chunk)) << 1 | int(last)
        lines.append(f"-> 600+ {0x60 | toggle << 4:02X} 00 00 00 00 00 00 00")
        lines.append(
            f"<- 580+ {b0:02X} " + " ".join([f"{b:02X}" for b in chunk] + ["??"] * (7 - len(chunk)))
        )
        toggle ^= 1
    return "\n".join(lines)


def _device_name(ctx: Context) -> bytes:
    require_objects(ctx, 0x1008)
    value = ctx.device.upload(0x1008, 0)
    if len(value) <= 4:
        raise Skip(f"0x1008 holds {len(value)} bytes: the vector needs a segmented name")
    return value


@case("seed", "tv02_segmented_upload", "TV-02 / TV-S02: segmented upload of 0x1008, frame by frame")
def tv02(ctx: Context) -> None:
    replay(ctx, _segments(_device_name(ctx), 0x1008))


@case(
    "seed", "tv03_block_upload", "TV-03 / TV-S03: block upload of 0x1008 without CRC, blksize 127"
)
def tv03(ctx: Context) -> None:
    value = _device_name(ctx)
    require_block(ctx)
    if len(value) > 127 * 7:
        raise Skip("0x1008 longer than one block")
    size = " ".join(f"{b:02X}" for b in struct.pack("<I", len(value)))
    lines = [
        "-> 600+ A0 08 10 00 7F 00 00 00",
        f"<- 580+ C2 08 10 00 {size}",
        "-> 600+ A3 00 00 00 00 00 00 00",
    ]
    chunks = [value[i : i + 7] for i in range(0, len(value), 7)]
    for seq, chunk in enumerate(chunks, 1):
        last = seq == len(chunks)
        lines.append(
            f"<- 580+ {seq | (0x80 if last else 0):02X} "
            + " ".join([f"{b:02X}" for b in chunk] + ["??"] * (7 - len(chunk)))
        )
    n = 7 - len(chunks[-1])
    lines += [
        f"-> 600+ A2 {len(chunks):02X} 7F 00 00 00 00 00",
        f"<- 580+ {0xC1 | n << 2:02X} ?? ?? ?? ?? ?? ?? ??",
        "-> 600+ A1 00 00 00 00 00 00 00",
        "-- 580+",
    ]
    replay(ctx, "\n".join(lines))


@case(
    "seed",
    "tv04_expedited_download",
    "TV-04 / TV-S04: 0x1400:2 = 5 by expedited download, reads back 5",
)
def tv04(ctx: Context) -> None:
    require_objects(ctx, 0x1400)
    restore_later(ctx, 0x1400, 2)
    replay(
        ctx,
        """
        -> 600+ 2F 00 14 02 05 00 00 00
        <- 580+ 60 00 14 02 ?? ?? ?? ??
        -> 600+ 40 00 14 02 00 00 00 00
        <- 580+ 4F 00 14 02 05 ?? ?? ??
    """,
    )


@case(
    "seed",
    "tv05_block_download",
    "TV-05 / TV-S05: 0x1400:2 = 5 by block download (end frame D9, n = 6)",
)
def tv05(ctx: Context) -> None:
    require_objects(ctx, 0x1400)
    require_block(ctx)
    restore_later(ctx, 0x1400, 2)
    dev = ctx.device
    frame = dev.sdo(b"\xc0\x00\x14\x02")
    if (
        frame.data[0] & 0xFB != 0xA0  # A4: the server offers CRC (CiA 301 §7.2.4.3.11)
        or bytes(frame.data[1:4]) != b"\x00\x14\x02"
        or not 1 <= frame.data[4] <= 127
    ):
        raise Fail(
            "block download initiate response",
            expected="A0 (or A4) 00 14 02 <blksize 1..127>",
            seen=str(frame),
        )
    replay(
        ctx,
        """
        -> 600+ 81 05 00 00 00 00 00 00
        <- 580+ A2 01 ?? ?? ?? ?? ?? ??
        -> 600+ D9 00 00 00 00 00 00 00
        <- 580+ A1 ?? ?? ?? ?? ?? ?? ??
        -> 600+ 40 00 14 02 00 00 00 00
        <- 580+ 4F 00 14 02 05 ?? ?? ??
    """,
    )


@case("seed", "tv06_abort", "TV-06 / TV-S06: reading 0x1008:1 aborts with 0609 0011")
def tv06(ctx: Context) -> None:
    require_objects(ctx, 0x1008)
    replay(
        ctx,
        """
        -> 600+ 40 08 10 01 00 00 00 00
        <- 580+ 80 08 10 01 11 00 09 06
    """,
    )


@case("seed", "tv07_nmt_dlc8", "TV-07 / TV-P00 / TV-N01: NMT start sent with DLC 8 is accepted")
def tv07(ctx: Context) -> None:
    probe = StateProbe(ctx)
    ctx.device.nmt(NMT_START, dlc=8)
    probe.expect(0x05, "NMT start with DLC 8")


def _hex(data: bytes) -> str:
    return " ".join(f"{b:02X}" for b in data)


def _pattern(rpdo: Pdo, seed: int) -> bytes:
    return bytes((seed + 0x11 * i) & 0xFF for i in range(rpdo.length))


def _rpdo_line(rpdo: Pdo, data: bytes) -> str:
    return f"-> {rpdo.cob & 0x7FF:03X} {_hex(data.ljust(8, bytes(1)))}"


def _tpdo_line(tpdo: Pdo, data: bytes) -> str:
    return f"<- {tpdo.cob & 0x7FF:03X} {_hex(data[: tpdo.length])}"


@case(
    "seed",
    "tv08_rpdo_to_tpdo",
    "TV-08 / TV-P01: RxPDO1 [8] writes DO, the DI change sends TxPDO1 with the mapped length",
)
def tv08(ctx: Context) -> None:
    rpdo, tpdo = io_pdos(ctx)
    operational(ctx)
    x = _pattern(rpdo, 0x34)
    replay(ctx, _rpdo_line(rpdo, x) + "\n" + _tpdo_line(tpdo, x))


@case(
    "seed", "tv10_rtr_tpdo2", "TV-10 / TV-P02: RTR on TxPDO2 answers the AI with DLC 2 per channel"
)
def tv10(ctx: Context) -> None:
    dev = ctx.device
    tpdo = active_pdo(dev, tx=True, n=1, rtr=True)
    if tpdo.entries[0] >> 16 != 0x6401:
        raise Skip("TPDO2 does not map 0x6401 (the seed layout)")
    operational(ctx)
    replay(
        ctx,
        f"-> {tpdo.cob & 0x7FF:03X} RTR {tpdo.length}\n<- {tpdo.cob & 0x7FF:03X} "
        + " ".join(["??"] * tpdo.length),
    )


@case(
    "seed",
    "tv11_event_timer",
    "TV-11 / TV-P03: 0x1801:5 = 1000 ms sends TxPDO2 every second; 0 stops it",
)
def tv11(ctx: Context) -> None:
    dev = ctx.device
    tpdo = active_pdo(dev, tx=True, n=1)
    dev.require(0x1801, 5)
    if any(e >> 16 == 0x6401 for e in tpdo.entries) and not dev.has(0x6423):
        raise Skip(
            "no 0x6423: analog changes are TPDO events on this device (the NA-9161's way), so "
            "the event timer cannot be told apart from them while its inputs move"
        )
    restore_later(ctx, 0x1801, 5)
    operational(ctx)
    replay(ctx, "-> 600+ 2B 01 18 05 E8 03 00 00\n<- 580+ 60 01 18 05 ?? ?? ?? ??")
    frames = dev.link.collect(lambda f: f.cob == tpdo.cob & 0x7FF and not f.rtr, 2.1)
    if len(frames) < 2 or not ctx.timing.within(frames[1].timestamp - frames[0].timestamp, 1.0):
        raise Fail(
            "TxPDO2 with event timer 1000 ms",
            expected="2 frames 1 s apart in 2.1 s",
            seen=", ".join(f"{f.timestamp - frames[0].timestamp:.3f}" for f in frames) or "nothing",
        )
    replay(ctx, "-> 600+ 2B 01 18 05 00 00 00 00\n<- 580+ 60 01 18 05 ?? ?? ?? ??")
    dev.link.flush()
    late = dev.link.collect(lambda f: f.cob == tpdo.cob & 0x7FF and not f.rtr, 1.1)
    if late:
        raise Fail("TxPDO2 still sent after event timer 0", expected="nothing", seen=str(late[0]))


def _typed(ctx: Context, tx: bool, ttype: int) -> tuple[Pdo, Pdo, int]:
    """The I/O PDO pair with the RPDO1 (tx False) or TPDO1 (tx True) type set by the vector's SDO frame,
    the node Operational; returns (rpdo, tpdo, TPDO1 COB-ID)."""
    rpdo, tpdo = io_pdos(ctx)
    index = tpdo.comm if tx else rpdo.comm
    restore_later(ctx, index, 2)
    replay(
        ctx,
        f"-> 600+ 2F {index & 0xFF:02X} {index >> 8:02X} 02 {ttype:02X} 00 00 00\n<- 580+ 60 {index & 0xFF:02X} {index >> 8:02X} 02 ?? ?? ?? ??",
    )
    operational(ctx)
    return rpdo, tpdo, tpdo.cob & 0x7FF


@case("seed", "tv12_rpdo_type0", "TV-12 / TV-P04: RxPDO1 type 0 is applied only at the next SYNC")
def tv12(ctx: Context) -> None:
    rpdo, tpdo, t = _typed(ctx, False, 0)
    x = _pattern(rpdo, 0x78)
    replay(ctx, _rpdo_line(rpdo, x) + f"\n-- {t:03X}\nsync\n" + _tpdo_line(tpdo, x))


@case(
    "seed",
    "tv13_tpdo_type0",
    "TV-13 / TV-P05: TxPDO1 type 0 is sent at SYNC only if the DI changed",
)
def tv13(ctx: Context) -> None:
    rpdo, tpdo, t = _typed(ctx, True, 0)
    x = _pattern(rpdo, 0xAB)
    replay(
        ctx,
        _rpdo_line(rpdo, x) + f"\n-- {t:03X}\nsync\n" + _tpdo_line(tpdo, x) + f"\nsync\n-- {t:03X}",
    )


@case("seed", "tv14_tpdo_type3", "TV-14 / TV-P06: TxPDO1 type 3 is sent at the third SYNC")
def tv14(ctx: Context) -> None:
    rpdo, tpdo, t = _typed(ctx, True, 3)
    x = _pattern(rpdo, 0xEF)
    replay(
        ctx,
        _rpdo_line(rpdo, x)
        + f"\n-- {t:03X}\nsync\n-- {t:03X}\nsync\n-- {t:03X}\nsync\n"
        + _tpdo_line(tpdo, x),
    )


@case(
    "seed",
    "tv15_tpdo_type252",
    "TV-15 / TV-P07: TxPDO1 type 252 answers RTR with the value sampled at the last SYNC",
)
def tv15(ctx: Context) -> None:
    rpdo, tpdo, t = _typed(ctx, True, 252)
    old, new = _pattern(rpdo, 0x10), _pattern(rpdo, 0x34)
    replay(ctx, _rpdo_line(rpdo, old))
    time.sleep(0.1)
    replay(ctx, f"sync\n-- {t:03X}\n" + _rpdo_line(rpdo, new))
    time.sleep(0.1)
    replay(
        ctx,
        f"-> {t:03X} RTR {tpdo.length}\n"
        + _tpdo_line(tpdo, old)
        + f"\nsync\n-- {t:03X}\n-> {t:03X} RTR {tpdo.length}\n"
        + _tpdo_line(tpdo, new),
    )


@case(
    "seed",
    "tv16_tpdo_type253",
    "TV-16 / TV-P08: TxPDO1 type 253 is sent only on RTR, with the current value",
)
def tv16(ctx: Context) -> None:
    rpdo, tpdo, t = _typed(ctx, True, 253)
    x = _pattern(rpdo, 0x78)
    replay(ctx, _rpdo_line(rpdo, x) + f"\n-- {t:03X}")
    replay(ctx, f"-> {t:03X} RTR {tpdo.length}\n" + _tpdo_line(tpdo, x))


def _pdo6(ctx: Context, tx: bool) -> Pdo:
    dev = ctx.device
    comm = 0x1805 if tx else 0x1405
    require_objects(ctx, comm, comm + 0x200, 0x6000 if tx else 0x6200, 0x6401 if tx else 0x6411)
    return live_pdo(dev, Pdo(5, tx, 0, []))


@case(
    "seed",
    "tv17_dynamic_tpdo",
    "TV-17 / TV-P09: TxPDO at 0x1805/0x1A05 built at run time = DI byte + AI (3 bytes)",
)
def tv17(ctx: Context) -> None:
    require_loopback(ctx)
    dev = ctx.device
    pdo6 = _pdo6(ctx, tx=True)
    rpdo, _ = io_pdos(ctx)
    cob = 0x180 + (ctx.options.lss_spare_node_id or dev.node_id % 127 + 1)
    remap(ctx, pdo6, [0x60000108, 0x64010110])
    dev.write(0x1805, 1, cob)
    operational(ctx)
    x = _pattern(rpdo, 0x54)
    replay(ctx, _rpdo_line(rpdo, x))
    frame = dev.link.expect(cob, ctx.timing.response)
    if frame is None or len(frame.data) != 3 or frame.data[0] != x[0]:
        raise Fail(
            "dynamic TxPDO after a DI change",
            expected=f"{cob:03X} [3] {x[0]:02X} <AI lo> <AI hi>",
            seen=str(frame) if frame else "nothing",
        )


@case(
    "seed",
    "tv18_dynamic_rpdo",
    "TV-18 / TV-P10: RxPDO at 0x1405/0x1605 built at run time drives DO and AO",
)
def tv18(ctx: Context) -> None:
    require_loopback(ctx)
    dev = ctx.device
    pdo6 = _pdo6(ctx, tx=False)
    _, tpdo = io_pdos(ctx)
    restore_later(ctx, 0x6411, 1)
    cob = 0x200 + (ctx.options.lss_spare_node_id or dev.node_id % 127 + 1)
    remap(ctx, pdo6, [0x62000108, 0x64110110])
    dev.write(0x1405, 1, cob)
    operational(ctx)
    current = bytes(dev.upload(0x6000, s + 1)[0] for s in range(tpdo.length))
    x = bytes([0x54 if current[0] != 0x54 else 0x55]) + current[1:]
    replay(ctx, f"-> {cob:03X} {x[0]:02X} 21 03 00 00 00 00 00\n" + _tpdo_line(tpdo, x))
    wait_value(ctx, 0x6401, 1, 0x0321, "AI after the dynamic RxPDO wrote AO 0x0321")


@case(
    "seed",
    "tv19_emcy_length_error",
    "TV-19: short RxPDO1 → EMCY 10 82 11 09, history 0x00098210, reset EMCY recorded as 0",
)
def tv19(ctx: Context) -> None:
    dev = ctx.device
    require_objects(ctx, 0x1003, 0x1001, 0x1014)
    rpdo = active_pdo(dev, tx=False, n=0)
    good = b"".join(dev.upload(e >> 16, (e >> 8) & 0xFF)[: (e & 0xFF) // 8] for e in rpdo.entries)
    operational(ctx)
    r = rpdo.cob & 0x7FF
    replay(
        ctx,
        f"""
        -> {r:03X}
        <- 080+ 10 82 11 09 00 00 00 00
        -> 600+ 40 03 10 01 00 00 00 00
        <- 580+ 43 03 10 01 10 82 09 00
        -> 600+ 40 01 10 00 00 00 00 00
        <- 580+ 4F 01 10 00 11 ?? ?? ??
        -> {r:03X} {_hex(good)}
        <- 080+ 00 00 00 00 00 00 00 00
        -> 600+ 40 03 10 01 00 00 00 00
        <- 580+ 43 03 10 01 00 00 00 00
        -> 600+ 40 03 10 02 00 00 00 00
        <- 580+ 43 03 10 02 10 82 09 00
        -> 600+ 40 01 10 00 00 00 00 00
        <- 580+ 4F 01 10 00 00 ?? ?? ??
    """,
    )


@case(
    "seed",
    "tv20_guarding",
    "TV-20 / TV-G01: guard 250 ms × 4; RTR → 7F, toggle; then EMCY 30 81 11 07 after ~1 s",
)
def tv20(ctx: Context) -> None:
    require_objects(ctx, 0x100C, 0x100D, 0x1014)
    frame, delay, life = life_guard(ctx, 250, 4)
    if frame is None:
        raise Fail(
            "no life guarding EMCY",
            expected="080+ID [8] 30 81 11 07 00 00 00 00 about 1 s after the RTR",
            seen="nothing",
        )
    if bytes(frame.data) != bytes.fromhex("3081110700000000"):
        raise Fail("life guarding EMCY", expected="30 81 11 07 00 00 00 00", seen=str(frame))
    assert delay is not None  # (there is a frame)
    if not ctx.timing.within(delay, life):
        raise Fail(
            "life guarding EMCY time",
            expected=f"{life:.3f} s ± {ctx.timing.slack(life):.3f}",
            seen=f"{delay:.3f} s",
        )


@case(
    "seed",
    "tv21_lss_templates",
    "TV-21: LSS switch global, inquire 5A-5E, switch back, with DLC 8 frames",
)
def tv21(ctx: Context) -> None:
    require_lss(ctx)
    ident = identity(ctx.device)
    lss(ctx, [0x04, CONFIGURATION])
    ctx.cleanup(lambda: lss(ctx, [0x04, WAITING]))
    for cs, value in zip((0x5A, 0x5B, 0x5C, 0x5D), ident, strict=True):
        frame = must(ctx, [cs], cs, f"inquire 0x{cs:02X}")
        if bytes(frame.data[1:5]) != struct.pack("<I", value):
            raise Fail(
                f"inquire 0x{cs:02X}",
                expected=f"7E4 [8] {cs:02X} {_hex(struct.pack('<I', value))} ..",
                seen=str(frame),
            )
    frame = must(ctx, [0x5E], 0x5E, "inquire node-ID")
    if frame.data[1] != ctx.device.node_id:
        raise Fail("inquire node-ID", expected=f"5E {ctx.device.node_id:02X}", seen=str(frame))


@case(
    "seed",
    "tv23_error_modes",
    "TV-23 / TV-C4: 0x6206:1 = 0x31, 0x6207:1 = 0xF8; DO 0x00 → 0x30 on life guarding failure",
)
def tv23(ctx: Context) -> None:
    _error_mode(ctx, 0x6206, 0x6207, 0x6200, 0x6000, 0x31, 0xF8, 0x00, 0x30)
