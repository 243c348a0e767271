"""Device and master profiles: does a device behave as its manual says, without extra set-up?

Three opt-in profiles (run with ``--profile icpdas``, ``na9161``, ``delta-as300`` or ``all``):

``icpdas``
    a device claiming ICP DAS I-7232D / I-7231D compatibility: guarding only (no 0x1016 /
    0x1017, seed-000 §2.3), analog changes send no TPDO
    (§2.7, step 4; needs ``--loopback``), EMCY ``00 FF 80 0A`` on an NMT reset request (§2.5),
    the manuals' 2-byte writes to 0x6443/0x6444 (§3.7, printed U16).
``na9161`` (beside the FnBus cases of :mod:`.na9161`)
    a device claiming CREVIS NA-9161 compatibility: its defaults (§3.1, §3.4: guarding
    200 ms x 2, 0x6206 = 0xFF, 0x6207 = 0, 0x6443 = 1, 0x6444 = 0, 20-entry history), every
    output to 0 and PRE-OPERATIONAL when a watched heartbeat stops or SYNC stops (§4.8, §9.7.3),
    an analog change sends its TPDO without any SDO write (§3.4 "Objects NOT in the seed";
    needs ``--loopback``), the overflow EMCY of a full EMCY queue (§3.2 0x1015), the per-slot
    objects 0x2000/0x2200/0x4501/0x4502/0x4504 (§3.3), the seed's short expedited writes (TV-10).
``delta-as300``
    a slave meant for a Delta AS300 master (seed-002 REQ-AS table): a node-ID the master
    can address other than its own (REQ-AS-01), a heartbeat producer (REQ-AS-06), a 0x1016
    entry that watches the master's heartbeat (node 1, 200 ms) without any SDO write and
    reports its loss (REQ-AS-07), PDO lengths the master checks (E1/E2, REQ-AS-12/14/15).

Where a manual leaves a code open (the NA-9161's EMCY table is missing) a case checks what
the manual fixes (an EMCY, its class) and says so in its title.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from ..device import NMT_RESET_COMM, NMT_START, SdoAbort, StateProbe, mux
from ..framework import Context, Fail, Skip, case
from ..link import Frame
from .cia401 import require_loopback
from .common import (
    LengthError,
    Pdo,
    active_pdo,
    emcy_code,
    expect_emcy,
    int_default,
    live_pdo,
    log_mark,
    operational,
    pdos,
)
from .errctl import resume

ERROR = -1  # expect_emcy: any EMCY but an error reset
PRE_OPERATIONAL = 0x7F
AS300_MASTER, AS300_HEARTBEAT_MS, AS300_MAX_ID = 1, 200, 64


# -- helpers ---------------------------------------------------------------------------------
def outputs(ctx: Context) -> list[tuple[int, int, int]]:
    """(index, sub, a non-zero value) of every DO byte and AO channel the EDS lists."""
    dev = ctx.device
    found = []
    for index, value in ((0x6200, 0xFF), (0x6411, 0x0123)):
        if dev.has(index, 1):
            found += [(index, s, value) for s in range(1, dev.read(index, 0) + 1)]
    if not found:
        raise Skip("EDS lists no output (0x6200, 0x6411)")
    return found


def drive(ctx: Context, outs: list[tuple[int, int, int]]) -> None:
    for index, sub, value in outs:
        ctx.device.write(index, sub, value)


def wait_zero(ctx: Context, outs: list[tuple[int, int, int]], what: str) -> None:
    dev = ctx.device
    deadline = time.monotonic() + ctx.timing.bootup
    seen: dict[str, int] = {}
    while time.monotonic() < deadline:
        seen = {f"0x{i:04X}:{s}": dev.read(i, s) for i, s, _ in outs}
        if not any(seen.values()):
            return
        time.sleep(0.02)
    left = ", ".join(f"{k} = {v:#x}" for k, v in seen.items() if v)
    raise Fail(
        what,
        expected="every output 0 (0x6206 = 0xFF / 0x6207 = 0, 0x6443 = 1 / 0x6444 = 0)",
        seen=left,
    )


def require_defaults(ctx: Context, wanted: dict[tuple[int, int], int], why: str) -> None:
    """Skip unless the EDS lists these defaults (a device that says it is not in that state)."""
    dev = ctx.device
    for (index, sub), value in wanted.items():
        var = dev.var(index, sub)
        if var is None or int_default(var) != value:
            raise Skip(f"EDS default of 0x{index:04X}:{sub} is not {value:#x} ({why})")


def error_register_clear(ctx: Context, within: float) -> None:
    """Wait until 0x1001 reads 0 (an error that ends by itself has ended), at most ``within``."""
    dev = ctx.device
    deadline = time.monotonic() + within
    while dev.has(0x1001) and dev.read(0x1001, 0) and time.monotonic() < deadline:
        time.sleep(0.05)


def spare_node(ctx: Context) -> int:
    return ctx.options.lss_spare_node_id or ctx.device.node_id % 127 + 1


def heartbeat_stops(
    ctx: Context, producer: int, period_s: float, consumer_s: float
) -> tuple[Frame | None, float]:
    """Send ``producer``'s heartbeat for a while (no EMCY may come), then stop; the EMCY that
    follows (or None), and the time of the last heartbeat."""
    dev = ctx.device
    ctx.cleanup(lambda: resume(ctx, lambda: dev.link.send(0x700 + producer, b"\x05")))
    end = time.monotonic() + max(5 * period_s, consumer_s + period_s)
    while time.monotonic() < end:
        dev.link.send(0x700 + producer, b"\x05")
        early = expect_emcy(ctx, ERROR, period_s)
        if early is not None:
            raise Fail(
                f"EMCY while node {producer} still sends its heartbeat",
                expected="none",
                seen=str(early),
            )
    last = time.time()
    frame = expect_emcy(ctx, ERROR, consumer_s + ctx.timing.slack(consumer_s) + ctx.timing.response)
    return frame, last


# -- icpdas ------------------------------------------------------------------------------------
def require_icpdas(ctx: Context) -> None:
    if ctx.device.has(0x4500):
        raise Skip("EDS lists 0x4500: an NA-9161-style head, not an ICP DAS one")


@case(
    "icpdas",
    "guarding_only",
    "node guarding only: no 0x1016/0x1017 (I-7232D §2.3), guard RTR answered",
)
def icpdas_guarding_only(ctx: Context) -> None:
    require_icpdas(ctx)
    dev = ctx.device
    dev.require(0x100C, why="node guarding")
    if dev.has(0x1017) or dev.has(0x1016):
        raise Skip("EDS lists 0x1016/0x1017: heartbeat added (a master profile that needs it)")
    dev.expect_abort(bytes([0x40]) + mux(0x1017, 0), (0x06020000,), "read of 0x1017")
    dev.expect_abort(bytes([0x40]) + mux(0x1016, 1), (0x06020000,), "read of 0x1016:1")
    reply = dev.guard()
    if reply is None or len(reply.data) != 1 or reply.data[0] & 0x7F != PRE_OPERATIONAL:
        raise Fail("guard RTR in Pre-operational", expected="701+ID [1] 7F or FF", seen=str(reply))


@case(
    "icpdas",
    "nmt_reset_emcy",
    "an NMT reset request sends EMCY 00 FF 80 0A before the boot-up (§2.5)",
)
def icpdas_nmt_reset_emcy(ctx: Context) -> None:
    require_icpdas(ctx)
    dev = ctx.device
    dev.require(0x1014, why="EMCY producer")
    mark = log_mark(ctx)
    if dev.reset(NMT_RESET_COMM) is None:
        raise Fail("no boot-up after NMT reset communication", expected="700+ID [1] 00")
    cob = 0x80 + dev.node_id
    for _, direction, frame in dev.link.log[mark:]:
        if direction != "←":
            continue
        if frame.cob == 0x700 + dev.node_id:
            break
        if frame.cob == cob and bytes(frame.data[:4]) == bytes.fromhex("00 FF 80 0A"):
            return
    raise Fail(
        "no EMCY for the reset request before the boot-up",
        expected=f"{cob:03X} [8] 00 FF 80 0A 00 00 00 00, then 700+ID [1] 00",
        seen="see frames",
    )


@case(
    "icpdas",
    "ao_error_two_byte_writes",
    "0x6443/0x6444 take the manuals' 2-byte writes (printed U16)",
)
def icpdas_ao_error_two_byte_writes(ctx: Context) -> None:
    require_icpdas(ctx)
    dev = ctx.device
    dev.require(0x6443, 1, why="AO error mode")
    dev.require(0x6444, 1, why="AO error value")
    for index, raw, want in ((0x6443, b"\x01\x00", 1), (0x6444, b"\x34\x12", 0x1234)):
        dev.patch(ctx, index, 1, dev.read(index, 1))  # restored afterwards
        try:
            frame = dev.sdo(bytes([0x2B]) + mux(index, 1) + raw + b"\0\0")
        except SdoAbort as exc:
            raise Fail(
                f"2-byte write to 0x{index:04X}:1 refused",
                expected="60 (the manual writes it with 2B)",
                seen=str(exc),
            ) from None
        if frame.data[0] != 0x60:
            raise Fail(f"2-byte write to 0x{index:04X}:1", expected="60", seen=str(frame))
        if dev.read(index, 1) != want:
            raise Fail(f"0x{index:04X}:1 after the write", expected=f"{want:#x}")


def analog_tpdo(ctx: Context) -> Pdo:
    """The TPDO mapping AI 1 (0x6401:1) and the AO looped back to it."""
    require_loopback(ctx)
    dev = ctx.device
    dev.require(0x6411, 1, why="an AO looped back to the AI")
    for p in pdos(dev, tx=True):
        if p.entries and p.entries[0] >> 8 == 0x640101:
            live = live_pdo(dev, p)
            if not live.cob & 0x80000000:
                return live
    raise Skip("no valid TPDO maps 0x6401:1 first")


def after_start(ctx: Context) -> None:
    operational(ctx)
    time.sleep(max(0.1, ctx.timing.silence))  # the TPDOs sent on entering Operational
    ctx.device.link.flush()


@case(
    "icpdas", "analog_change_no_tpdo", "an analog input change sends no TPDO (I-7232D §2.7, step 4)"
)
def icpdas_analog_change_no_tpdo(ctx: Context) -> None:
    require_icpdas(ctx)
    dev = ctx.device
    tpdo = analog_tpdo(ctx)
    if dev.read(tpdo.comm, 2) < 254 or (dev.has(tpdo.comm, 5) and dev.read(tpdo.comm, 5)):
        raise Skip(f"{tpdo.name} is not event-driven without an event timer")
    old = dev.read(0x6411, 1)
    ctx.cleanup(lambda: dev.write(0x6411, 1, old))
    after_start(ctx)
    dev.write(0x6411, 1, (old + 0x321) & 0x7FFF)
    frames = dev.link.collect(tpdo.cob & 0x7FF, ctx.timing.silence + 0.2)
    if frames:
        raise Fail(
            f"{tpdo.name} sent on an analog change",
            expected="nothing (analog changes are not events)",
            seen=str(frames[0]),
        )


# -- na9161 ------------------------------------------------------------------------------------
NA9161_DEFAULTS = {(0x100C, 0): 200, (0x100D, 0): 2}


@case(
    "na9161",
    "defaults",
    "the manual's defaults: guarding 200 ms x 2, 0x6206 = 0xFF, 0x6207 = 0, 0x6443 = 1, 0x6444 = 0",
)
def na9161_defaults(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x4500, why="an NA-9161-style head")
    wanted = dict(NA9161_DEFAULTS)
    for index, value in ((0x6206, 0xFF), (0x6207, 0x00), (0x6443, 1), (0x6444, 0)):
        if dev.has(index, 1):
            wanted.update({(index, s): value for s in range(1, dev.read(index, 0) + 1)})
    masks = digital_masks(ctx)
    for (index, sub), value in wanted.items():
        mask = masks.get(sub, 0xFF) if index in (0x6206, 0x6207) else -1
        default = int_default(dev.var(index, sub))
        live = dev.read(index, sub)
        if default is None or default & mask != value & mask or live & mask != value & mask:
            raise Fail(
                f"0x{index:04X}:{sub}",
                expected=f"{value:#x} (seed-004 §3.1/§3.4)",
                seen=f"EDS {default}, device {live}",
            )
    if not dev.has(0x1003, 20):
        raise Fail("0x1003 holds fewer than 20 errors", expected="sub 1..20 (§3.1)")


def digital_masks(ctx: Context) -> dict[int, int]:
    """0x6200 sub -> the bits of that byte that are outputs (a padding bit has no error mode):
    from 0x2220:1 in compressed packing (only the last byte is padded); where the device does
    not tell (non-compressed: a padded byte per module), bit 0 alone, which every byte has."""
    dev = ctx.device
    if not dev.has(0x6200, 0):
        return {}
    count = dev.read(0x6200, 0)
    bits = dev.read(0x2220, 1) if dev.has(0x2220, 1) else None
    if bits is None or not 8 * (count - 1) < bits <= 8 * count:
        return dict.fromkeys(range(1, count + 1), 0x01)
    return {**dict.fromkeys(range(1, count), 0xFF), count: (1 << (bits - 8 * (count - 1))) - 1}


def _error_event(ctx: Context, trigger: Callable[[], Frame | None], what: str) -> None:
    """Outputs driven, ``trigger()`` raises the error event (returns its EMCY): every output
    goes to 0 and the head to Pre-operational (seed-004 §3.2, §4.3, §4.8)."""
    dev = ctx.device
    modes = {(0x6206, 1): 0xFF, (0x6207, 1): 0} if dev.has(0x6206, 1) else {(0x6443, 1): 1}
    require_defaults(ctx, modes, "the NA-9161's error modes")
    outs = outputs(ctx)
    probe = StateProbe(ctx)
    ctx.cleanup(lambda: dev.reset(NMT_RESET_COMM))
    dev.nmt(NMT_START)
    time.sleep(0.02)
    drive(ctx, outs)
    frame = trigger()
    if frame is None:
        raise Fail(f"no EMCY when {what}", expected="an EMCY (the error event)", seen="nothing")
    wait_zero(ctx, outs, f"outputs after {what}")
    probe.expect(PRE_OPERATIONAL, what)


@case(
    "na9161",
    "heartbeat_loss_outputs",
    "a watched heartbeat stops: EMCY, every output to 0, Pre-operational",
)
def na9161_heartbeat_loss_outputs(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x4500, why="an NA-9161-style head")
    dev.require(0x1016, 1, why="heartbeat consumer")
    producer = spare_node(ctx)
    period = ctx.timing.heartbeat_ms / 1000
    consumer_ms = 3 * ctx.timing.heartbeat_ms

    def trigger() -> Frame | None:
        dev.write(0x1016, 1, producer << 16 | consumer_ms)
        ctx.cleanup(lambda: dev.write(0x1016, 1, 0))
        frame, _ = heartbeat_stops(ctx, producer, period, consumer_ms / 1000)
        return frame

    _error_event(ctx, trigger, f"the heartbeat of node {producer} stopped")


@case(
    "na9161",
    "sync_loss_outputs",
    "SYNC stops (0x1006): EMCY, every output to 0, Pre-operational (§4.8)",
)
def na9161_sync_loss_outputs(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x4500, why="an NA-9161-style head")
    dev.require(0x1006, why="SYNC monitoring")
    period_us = 50_000  # the Delta AS300's SYNC cycle
    sync_cob = int(dev.read(0x1005, 0)) & 0x7FF if dev.has(0x1005) else 0x80

    def trigger() -> Frame | None:
        dev.patch(ctx, 0x1006, 0, period_us)
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            dev.link.send(sync_cob, b"")
            time.sleep(period_us / 1e6)
        limit = 2 * period_us / 1e6 + ctx.timing.slack(period_us / 1e6) + ctx.timing.response
        return expect_emcy(ctx, ERROR, limit)

    _error_event(ctx, trigger, "SYNC stopped")


@case(
    "na9161",
    "analog_change_tpdo",
    "an analog input change sends its TPDO within the inhibit time, no SDO write (§3.4)",
)
def na9161_analog_change_tpdo(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x4500, why="an NA-9161-style head")
    tpdo = analog_tpdo(ctx)
    inhibit = dev.read(tpdo.comm, 3) / 10_000 if dev.has(tpdo.comm, 3) else 0.0
    old = dev.read(0x6411, 1)
    ctx.cleanup(lambda: dev.write(0x6411, 1, old))
    after_start(ctx)
    time.sleep(inhibit)  # the Start transmission's inhibit time has passed
    dev.link.flush()
    new = (old + 0x321) & 0x7FFF
    dev.write(0x6411, 1, new)
    want = new.to_bytes(2, "little")
    limit = inhibit + ctx.timing.slack(inhibit) + ctx.timing.bootup
    frame = dev.link.expect(
        lambda f: f.cob == tpdo.cob & 0x7FF and not f.rtr and bytes(f.data[:2]) == want, limit
    )
    if frame is None:
        raise Fail(
            f"{tpdo.name} not sent on the analog change",
            expected=f"{tpdo.cob & 0x7FF:03X} {want.hex(' ')} ... within {limit:.2f} s",
            seen="see frames",
        )


@case(
    "na9161",
    "emcy_queue_overflow",
    "EMCYs held back by 0x1015 overflow their queue: an overrun EMCY (0x8110) at once",
)
def na9161_emcy_queue_overflow(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x4500, why="an NA-9161-style head")
    dev.require(0x1015, why="EMCY inhibit time")
    trigger = LengthError(ctx)
    dev.patch(ctx, 0x1015, 0, 10_000)  # 1 s: everything after the first EMCY waits
    # last: the overrun error ends by itself after a quiet time (fieldgate: 1 s), which a reset
    # does not shorten; the next case must not find it (its verdict would depend on the order)
    ctx.cleanup(lambda: error_register_clear(ctx, 3.0))
    ctx.cleanup(lambda: dev.reset(NMT_RESET_COMM))
    rpdo, good = trigger.rpdo, trigger.good
    t0 = time.monotonic()
    for _ in range(12):  # two EMCYs each (the error and its reset): 24 > a 20-entry queue
        dev.link.send(rpdo.cob & 0x7FF, good[: rpdo.length - 1])
        time.sleep(0.005)
        dev.link.send(rpdo.cob & 0x7FF, good)
        time.sleep(0.005)
    frame = expect_emcy(ctx, None, ctx.timing.response)
    seen = []
    while frame is not None and time.monotonic() - t0 < 1.0:
        seen.append(frame)
        if emcy_code(frame) == 0x8110:
            return
        frame = expect_emcy(ctx, None, max(0.0, 1.0 - (time.monotonic() - t0)))
    raise Fail(
        "no overrun EMCY while the inhibit time holds the queue back",
        expected="EMCY 0x8110 (CAN overrun) at once",
        seen=", ".join(str(f) for f in seen) or "nothing",
    )


SLOT_OBJECTS = (0x2000, 0x2200, 0x4501, 0x4502, 0x4504)


@case(
    "na9161",
    "slot_objects",
    "0x2000/0x2200/0x4501/0x4502/0x4504: a sub-index per slot; 0x4501:n = the size of 0x2000:n; 0x2200 write-only",
)
def na9161_slot_objects(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x4503, why="slots (product codes)")
    missing = [f"0x{i:04X}" for i in SLOT_OBJECTS if not dev.has(i, 0)]
    if missing:
        raise Skip(f"EDS lists no {', '.join(missing)}")
    slots = dev.read(0x4503, 0)
    for index in SLOT_OBJECTS:
        if dev.read(index, 0) != slots:
            raise Fail(
                f"0x{index:04X}:0",
                expected=f"{slots} (slots, as 0x4503:0)",
                seen=str(dev.read(index, 0)),
            )
    for n in range(1, slots + 1):
        size = int.from_bytes(dev.upload(0x4501, n), "little")
        data = dev.upload(0x2000, n)
        if len(data) != size:
            raise Fail(
                f"slot {n}: 0x2000:{n} is {len(data)} bytes", expected=f"{size} (0x4501:{n})"
            )
        if len(dev.upload(0x4504, n)) != 4:
            raise Fail(f"0x4504:{n} is not UNSIGNED32")
    dev.expect_abort(bytes([0x40]) + mux(0x2200, 1), (0x06010001,), "read of 0x2200:1 (write-only)")


@case(
    "na9161",
    "short_expedited_write",
    "a U32 written with a 2-byte expedited download is taken (TV-10)",
)
def na9161_short_expedited_write(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x4500, 3, why="slot active flags (TV-10)")
    old = dev.read(0x4500, 3)
    ctx.cleanup(lambda: dev.write(0x4500, 3, old))
    try:
        frame = dev.sdo(bytes([0x2B]) + mux(0x4500, 3) + (old ^ 1).to_bytes(2, "little") + b"\0\0")
    except SdoAbort as exc:
        raise Fail("TV-10: 2B 00 45 03 .. refused", expected="60 00 45 03", seen=str(exc)) from None
    if frame.data[0] != 0x60 or dev.read(0x4500, 3) != old ^ 1:
        raise Fail("TV-10 write of 0x4500:3", expected=f"60, then 0x{old ^ 1:08X}", seen=str(frame))


# -- delta-as300 --------------------------------------------------------------------------------
@case(
    "delta-as300",
    "node_id",
    "node-ID 2..64: the master addresses 1..64 and is 1 itself (REQ-AS-01, E8)",
)
def as300_node_id(ctx: Context) -> None:
    node = ctx.device.node_id
    if node == AS300_MASTER or node > AS300_MAX_ID:
        raise Fail(f"node-ID {node}", expected=f"2..{AS300_MAX_ID}")


@case(
    "delta-as300",
    "heartbeat_producer",
    "0x1017 U16 rw: heartbeat at the period written (REQ-AS-06)",
)
def as300_heartbeat_producer(ctx: Context) -> None:
    dev = ctx.device
    var = dev.var(0x1017, 0)
    if var is None:
        raise Fail(
            "no heartbeat producer (0x1017)",
            expected="0x1017 U16 rw: the AS300 supervises its slaves by heartbeat only (E7)",
        )
    if var.access_type not in ("rw", "rww", "rwr"):
        raise Fail("0x1017 access", expected="rw", seen=var.access_type)
    dev.patch(ctx, 0x1017, 0, ctx.timing.heartbeat_ms)
    dev.link.flush()
    period = ctx.timing.heartbeat_ms / 1000
    beats = dev.link.collect(lambda f: f.cob == 0x700 + dev.node_id and not f.rtr, 4.5 * period)
    if len(beats) < 3 or any(len(f.data) != 1 for f in beats):
        raise Fail(
            "heartbeat",
            expected=f"a [1] frame every {ctx.timing.heartbeat_ms} ms",
            seen=f"{len(beats)} frames",
        )


@case(
    "delta-as300",
    "master_heartbeat_watched",
    "0x1016 watches node 1's heartbeat by default; its loss is an EMCY without any SDO write (REQ-AS-07)",
)
def as300_master_heartbeat_watched(ctx: Context) -> None:
    dev = ctx.device
    count = int_default(dev.var(0x1016, 0)) or 0  # no 0x1016: no entry (a failure below)
    entries = [int_default(dev.var(0x1016, s)) or 0 for s in range(1, count + 1)]
    watch = [e for e in entries if (e >> 16) & 0xFF == AS300_MASTER and e & 0xFFFF]
    if not watch:
        raise Fail(
            "no 0x1016 default watches the master",
            expected=f"node {AS300_MASTER} with a time > {AS300_HEARTBEAT_MS} ms",
            seen=", ".join(f"0x{e:08X}" for e in entries) or "no entries",
        )
    consumer_ms = watch[0] & 0xFFFF
    if consumer_ms <= AS300_HEARTBEAT_MS:
        raise Fail(
            "consumer time",
            expected=f"> {AS300_HEARTBEAT_MS} ms (the master's period)",
            seen=f"{consumer_ms} ms",
        )
    ctx.cleanup(lambda: dev.reset(NMT_RESET_COMM))
    frame, last = heartbeat_stops(ctx, AS300_MASTER, AS300_HEARTBEAT_MS / 1000, consumer_ms / 1000)
    if frame is None or emcy_code(frame) != 0x8130:
        raise Fail(
            "master loss not reported",
            expected=f"EMCY 0x8130 about {consumer_ms} ms after the master's last heartbeat",
            seen=str(frame) if frame else "nothing",
        )


@case(
    "delta-as300",
    "pdo_lengths",
    "valid PDOs carry data in whole 8/16/32/64-bit entries; TPDOs after Start have their mapped length (E1/E2)",
)
def as300_pdo_lengths(ctx: Context) -> None:
    dev = ctx.device
    found = pdos(dev, True) + pdos(dev, False)
    if not found:
        raise Skip("EDS lists no PDO")
    for p in found:
        if p.cob & 0x80000000:
            continue
        if not p.entries:
            raise Fail(
                f"{p.name} is valid with nothing mapped",
                expected="invalid (bit 31), or mapped data (E2)",
            )
        bad = [e for e in p.entries if (e & 0xFF) not in (8, 16, 32, 64)]
        if bad:
            raise Fail(
                f"{p.name} maps 0x{bad[0]:08X}", expected="8/16/32/64-bit entries (REQ-AS-12)"
            )
    tpdo = active_pdo(dev, tx=True)
    dev.link.flush()
    dev.nmt(NMT_START)
    frames = dev.link.collect(
        lambda f: f.cob == tpdo.cob & 0x7FF and not f.rtr, ctx.timing.response
    )
    if not frames:
        raise Fail(
            f"no {tpdo.name} after Start", expected=f"{tpdo.cob & 0x7FF:03X} [{tpdo.length}] (E2)"
        )
    wrong = [f for f in frames if len(f.data) != tpdo.length]
    if wrong:
        raise Fail(f"{tpdo.name} length", expected=f"DLC {tpdo.length} (E1)", seen=str(wrong[0]))
