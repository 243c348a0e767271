"""Helpers shared by the case modules: picking objects from the EDS, PDO set-up, EMCY triggers."""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes

from ..device import NMT_PREOP, NMT_START, Device, SdoAbort, abort_text
from ..framework import Context, Fail, Inconclusive, Skip
from ..link import Frame

EMCY_LENGTH_ERROR = 0x8210
EMCY_LIFE_GUARD = 0x8130
RESTRICTED = [
    (0x000, 0x000),
    (0x001, 0x07F),
    (0x101, 0x180),
    (0x581, 0x5FF),
    (0x601, 0x67F),
    (0x6E0, 0x6FF),
    (0x701, 0x77F),
    (0x780, 0x7FF),
]


def restricted(cob: int) -> bool:
    return any(lo <= cob <= hi for lo, hi in RESTRICTED)


def is_count(var: ODVariable) -> bool:
    """Sub 0 of a record or array (the entry count)."""
    return var.subindex == 0 and isinstance(var.parent, (ODRecord, ODArray))


def signed(var: ODVariable) -> bool:
    return var.data_type in datatypes.SIGNED_TYPES


def int_default(var: ODVariable | None) -> int | None:
    return (
        var.default
        if var is not None and isinstance(var.default, int) and not isinstance(var.default, bool)
        else None
    )


def rw_ints(dev: Device, lo: int, hi: int, avoid: tuple[int, ...] = ()) -> list[ODVariable]:
    """Writable integer entries with an EDS default in [lo, hi], not PDO parameters or listed indices."""
    out = []
    for var in dev.variables():
        if not lo <= var.index <= hi or var.index in avoid or 0x1400 <= var.index <= 0x1BFF:
            continue
        if var.access_type not in ("rw", "rww", "rwr") or is_count(var):
            continue
        if (
            int_default(var) is not None
            and var.fixed_size
            and len(var) <= 32
            and var.data_type not in (0x0001, 0x0008)
        ):
            out.append(var)
    return out


def other_value(var: ODVariable) -> int:
    """A value different from the default that stays inside the declared range."""
    default = int_default(var) or 0
    candidate = default + 1
    top = var.max if var.max is not None else (1 << (len(var) - (1 if signed(var) else 0))) - 1
    if candidate > top:
        candidate = default - 1
    return candidate


def subindex_numbers(dev: Device, index: int) -> list[int]:
    """The sub-indices the EDS lists for ``index``, in order ([0] for a variable)."""
    obj = dev.od[index]
    return sorted(obj.subindices) if isinstance(obj, (ODRecord, ODArray)) else [0]


def emcy_cob(dev: Device) -> int:
    return dev.od_default(0x1014, 0, 0x80 + dev.node_id) & 0x7FF


def emcy_code(frame: Frame) -> int:
    code: int = struct.unpack_from("<H", frame.data.ljust(2, b"\0"))[0]
    return code


def expect_emcy(ctx: Context, code: int | None, timeout: float | None = None) -> Frame | None:
    """The next EMCY with ``code`` (None: any, -1: any but an error reset 0x0000)."""
    dev = ctx.device
    cob = emcy_cob(dev)

    def wanted(f: Frame) -> bool:
        if f.cob != cob or f.rtr:
            return False
        return code is None or emcy_code(f) == code or code == -1 and emcy_code(f) != 0

    frame = dev.link.expect(wanted, timeout or ctx.timing.response)
    return frame


# -- PDOs --------------------------------------------------------------------------
@dataclass
class Pdo:
    n: int  # 0-based
    tx: bool
    cob: int
    entries: list[int]

    @property
    def comm(self) -> int:
        return (0x1800 if self.tx else 0x1400) + self.n

    @property
    def mapping(self) -> int:
        return (0x1A00 if self.tx else 0x1600) + self.n

    @property
    def length(self) -> int:
        return sum(e & 0xFF for e in self.entries) // 8

    @property
    def name(self) -> str:
        return f"{'T' if self.tx else 'R'}PDO{self.n + 1}"


def pdos(dev: Device, tx: bool) -> list[Pdo]:
    base_c, base_m = (0x1800, 0x1A00) if tx else (0x1400, 0x1600)
    out = []
    for n in range(512):
        if not (dev.has(base_c + n) and dev.has(base_m + n)):
            continue
        cob = int_default(dev.var(base_c + n, 1))
        count = int_default(dev.var(base_m + n, 0)) or 0
        entries = [int_default(dev.var(base_m + n, s)) or 0 for s in range(1, count + 1)]
        out.append(Pdo(n, tx, cob if cob is not None else 0x80000000, entries))
    return out


def live_pdo(dev: Device, pdo: Pdo) -> Pdo:
    """The PDO as the device serves it now."""
    cob = dev.read(pdo.comm, 1)
    count = dev.read(pdo.mapping, 0)
    entries = [dev.read(pdo.mapping, s) for s in range(1, count + 1)]
    return Pdo(pdo.n, pdo.tx, cob, entries)


def active_pdo(where: Device | Context, tx: bool, rtr: bool = False, n: int | None = None) -> Pdo:
    """A valid, mapped PDO the device serves now. Given the case's context (not just the
    device), a device without one whose EDS shows writable communication and mapping
    parameters gets one configured by the case (CiA 301 §7.2.2.3 procedure), restored at its
    end; otherwise the case SKIPs, saying why."""
    dev = where if isinstance(where, Device) else where.device
    kind = "TPDO" if tx else "RPDO"
    for p in pdos(dev, tx):
        if n is not None and p.n != n:
            continue
        if p.cob & 0x80000000 or not p.entries:
            continue
        live = live_pdo(dev, p)
        if live.cob & 0x80000000 or not live.entries or live.length == 0:
            continue
        if rtr and live.cob & 0x40000000:
            continue
        return live
    which = f"{kind}{n + 1}" if n is not None else f"any {kind}"
    why = f"EDS lists no valid, mapped {which}" + (" that allows RTR" if rtr else "")
    if isinstance(where, Device) or n is not None:
        raise Skip(why)
    return configure_pdo(where, tx, rtr, why)


def mappable_entry(dev: Device, tx: bool) -> ODVariable | None:
    """An entry a PDO may carry: PDO-mappable in the EDS, 8-32 bits, readable for a TPDO,
    writable for an RPDO; the manufacturer and profile area first, else a communication entry
    outside the SDO and PDO parameters (CANopenNode's demo maps only 0x1001)."""
    wanted = ("ro", "rw", "rwr", "const") if tx else ("rw", "rww", "wo")
    found = [
        v
        for v in dev.variables()
        if v.pdo_mappable
        and not 0x1200 <= v.index <= 0x1BFF
        and v.access_type in wanted
        and v.fixed_size
        and len(v) in (8, 16, 32)
        and not is_count(v)
    ]
    found.sort(key=lambda v: v.index < 0x2000)  # (stable: EDS order within each area)
    return found[0] if found else None


def invalid_again(dev: Device, comm: int) -> None:
    dev.write(comm, 1, dev.read(comm, 1) | 0x80000000)


def configure_pdo(ctx: Context, tx: bool, rtr: bool, why: str) -> Pdo:
    """Set up a PDO the EDS shows as configurable: invalid, mapping = one mappable entry, a
    COB-ID of the pre-defined connection set (or its own), valid; restored when the case ends."""
    dev = ctx.device
    kind = "TPDO" if tx else "RPDO"
    entry = mappable_entry(dev, tx)
    if entry is None:
        raise Skip(
            f"{why}, and the EDS lists no PDO-mappable {'readable' if tx else 'writable'} entry to map"
        )
    for p in pdos(dev, tx):
        comm, mapping = dev.var(p.comm, 1), dev.var(p.mapping, 0)
        if comm is None or mapping is None or not dev.has(p.mapping, 1):
            continue
        if "w" not in comm.access_type or "w" not in mapping.access_type:
            continue
        mapped = entry.index << 16 | entry.subindex << 8 | len(entry)
        try:
            old = dev.read(p.comm, 1)
            if tx and rtr and old & 0x40000000:
                raise Skip(
                    f"{why}; {p.name}'s COB-ID has bit 30 set (no RTR allowed): RTR on PDOs is"
                    " optional (CiA 301 §7.5.2.35) and not recommended"
                )
            base = old & 0x7FF
            if restricted(base) or not base:
                base = (0x180 if tx else 0x200) + 0x100 * (p.n % 4) + dev.node_id
            remap(ctx, p, [mapped])
            # the cleanups run last-first: the PDO must be invalid before its mapping returns
            ctx.cleanup(partial(invalid_again, dev, p.comm))
            dev.write(p.comm, 1, base | (0x40000000 if tx and old & 0x40000000 else 0))
        except SdoAbort as exc:
            raise Skip(
                f"{why}; configuring {p.name} to map 0x{entry.index:04X}:{entry.subindex} was refused: {abort_text(exc.code)}"
            ) from None
        return live_pdo(dev, p)
    raise Skip(f"{why}, and no {kind} has writable communication and mapping parameters in the EDS")


def set_pdo_type(ctx: Context, pdo: Pdo, ttype: int) -> None:
    ctx.device.patch(ctx, pdo.comm, 2, ttype)


def set_pdo_sub(ctx: Context, pdo: Pdo, sub: int, value: int, what: str) -> None:
    if not ctx.device.has(pdo.comm, sub):
        raise Skip(f"EDS lists no 0x{pdo.comm:04X}:{sub} ({what})")
    ctx.device.patch(ctx, pdo.comm, sub, value)


def invalidate(ctx: Context, pdo: Pdo) -> None:
    """Set the PDO's COB-ID invalid; the original COB-ID comes back at the end of the case."""
    dev = ctx.device
    old = dev.read(pdo.comm, 1)
    dev.write(pdo.comm, 1, old | 0x80000000)

    def restore() -> None:
        dev.write(pdo.comm, 1, dev.read(pdo.comm, 1) | 0x80000000)
        dev.write(pdo.comm, 1, old)

    ctx.cleanup(restore)


def keep_mapping(ctx: Context, pdo: Pdo, beyond: int = 0) -> list[int]:
    """The PDO's current mapping entries; they are written back when the case ends, and so
    are the sub-entries up to ``beyond`` past the count (a device keeps what was written
    there, and a later 'save' would store it)."""
    dev = ctx.device
    entries = [dev.read(pdo.mapping, s) for s in range(1, dev.read(pdo.mapping, 0) + 1)]
    unused = {
        s: dev.read(pdo.mapping, s)
        for s in range(len(entries) + 1, beyond + 1)
        if dev.has(pdo.mapping, s)
    }

    def restore() -> None:
        dev.write(pdo.mapping, 0, 0)
        for s, e in [*enumerate(entries, 1), *unused.items()]:
            dev.write(pdo.mapping, s, e)
        dev.write(pdo.mapping, 0, len(entries))

    ctx.cleanup(restore)
    return entries


def remap(ctx: Context, pdo: Pdo, entries: list[int]) -> None:
    """CiA 301 mapping procedure: invalid, sub 0 = 0, entries, sub 0 = n; restored afterwards."""
    dev = ctx.device
    invalidate(ctx, pdo)
    keep_mapping(ctx, pdo, beyond=len(entries))
    dev.write(pdo.mapping, 0, 0)
    for s, e in enumerate(entries, 1):
        dev.write(pdo.mapping, s, e)
    dev.write(pdo.mapping, 0, len(entries))


def all_pdos(dev: Device) -> list[Pdo]:
    found = pdos(dev, False) + pdos(dev, True)
    if not found:
        raise Skip("EDS lists no PDO")
    return found


def mapped_values(dev: Device, pdo: Pdo) -> bytes:
    """The bytes an RPDO must carry to write back what its mapped objects hold now."""
    out = bytearray()
    for e in pdo.entries:
        raw = dev.upload(e >> 16, (e >> 8) & 0xFF)
        out += raw[: (e & 0xFF) // 8].ljust((e & 0xFF) // 8, b"\0")
    return bytes(out)


def operational(ctx: Context) -> None:
    """NMT Start, once the device shows no error: a device may refuse Operational while its
    error register shows one (CANopenNode does), so a case that needs Operational on such a
    device gives no verdict (checked at the case's first Start, before it raises any error)."""
    if not ctx.error_checked:
        ctx.error_checked = True
        error_free(ctx, "before the case (a device with an error may refuse Operational)")
    ctx.device.nmt(NMT_START)
    time.sleep(0.02)


def preop(ctx: Context) -> None:
    ctx.device.nmt(NMT_PREOP)
    time.sleep(0.02)


# -- EMCY triggers ---------------------------------------------------------------------
class LengthError:
    """Provoke EMCY 0x8210 with a too-short RPDO, and clear it with a correct one."""

    def __init__(self, ctx: Context):
        self.ctx = ctx
        dev = ctx.device
        dev.require(0x1014, why="EMCY producer")
        self.rpdo = active_pdo(ctx, tx=False)
        self.good = mapped_values(dev, self.rpdo)
        operational(ctx)

    def raise_error(self) -> Frame | None:
        self.ctx.device.link.flush()
        self.ctx.device.link.send(self.rpdo.cob & 0x7FF, self.good[: self.rpdo.length - 1])
        return expect_emcy(self.ctx, EMCY_LENGTH_ERROR)

    def clear(self) -> Frame | None:
        self.ctx.device.link.flush()
        self.ctx.device.link.send(self.rpdo.cob & 0x7FF, self.good)
        return expect_emcy(self.ctx, 0x0000)


CLAUSE_GENERIC = (
    "CiA 301 §7.2.7.1 (EMCY byte 2 is the error register 0x1001) and §7.5.2.2 (bit 0, generic"
    " error, is set whenever an error is present)"
)


def require_generic_bit(frame: Frame, what: str) -> None:
    """The one rule for every EMCY that reports an error (code ≠ 0000), applied the same way by
    every case: DLC 8, and byte 2 (the error register) with bit 0 (generic error) set."""
    if len(frame.data) != 8 or not frame.data[2] & REGISTER_GENERIC:
        raise Fail(
            f"{what}: the error register must have the generic bit",
            expected="[8] <code> <register with bit 0> ...",
            seen=str(frame),
            clause=CLAUSE_GENERIC,
        )


def error_free(ctx: Context, when: str) -> None:
    """A precondition: the device reports no error (0x1001 = 0, and no error EMCY since the
    case began). A device that does cannot be graded by a case that needs an error-free one
    (CANopenNode's demo reports EMCY 0x5000 after its boot-up): INCONCLUSIVE, not FAIL."""
    dev = ctx.device
    dev.link.flush()
    cob = emcy_cob(dev)
    log = [(d, f) for _, d, f in dev.link.log]
    boots = [
        i
        for i, (d, f) in enumerate(log)
        if d == "←" and f.cob == 0x700 + dev.node_id and f.data == b"\0"
    ]
    # what came before the last boot-up (an EMCY announcing the reset, as the I-7232D's
    # 00 FF 80 0A) belongs to the device's previous life
    for direction, frame in log[boots[-1] + 1 if boots else 0 :]:
        if direction == "←" and frame.cob == cob and not frame.rtr and emcy_code(frame):
            raise Inconclusive(
                f"the device reports an error {when}: {frame} (EMCY {emcy_code(frame):04X})"
            )
    if dev.has(0x1001):
        register = dev.read(0x1001, 0)
        if register:
            raise Inconclusive(f"the device reports an error {when}: 0x1001 = 0x{register:02X}")


def require_abort(exc: SdoAbort, codes: tuple[int, ...], what: str) -> None:
    if exc.code not in codes:
        raise Fail(
            f"{what}: wrong abort code",
            expected=" or ".join(abort_text(c) for c in codes),
            seen=abort_text(exc.code),
        )


# -- errors that end -----------------------------------------------------------------------
EMCY_ERROR_RESET = 0x0000
REGISTER_GENERIC, REGISTER_COMMUNICATION = 0x01, 0x10


def error_register(ctx: Context) -> int | None:
    """0x1001 now, or None if the EDS does not list it."""
    return ctx.device.read(0x1001, 0) if ctx.device.has(0x1001) else None


def quiet_register(ctx: Context) -> int | None:
    """0x1001 before a case raises a communication error; SKIP if one is already active."""
    register = error_register(ctx)
    if register is not None and register & REGISTER_COMMUNICATION:
        raise Skip(f"0x1001 = 0x{register:02X} already shows a communication error before the case")
    return register


def log_mark(ctx: Context) -> int:
    """A position in the case's frame log: :func:`expect_error_reset` looks at frames after it."""
    ctx.device.link.flush()
    return len(ctx.device.link.log)


def expect_error_reset(
    ctx: Context,
    mark: int,
    after: Callable[[str, Frame], bool],
    what: str,
    before: int | None,
) -> Frame:
    """The error-reset EMCY (code 0000) that must follow the frame matching ``after(direction, frame)``
    logged after ``mark`` (the tester's command, or the boot-up): it may have come while the tester
    waited for something else (an SDO response), so the log is searched first. CiA 301 §7.2.7.1:
    when an error ends the device sends EMCY 0000 with the error register of the errors that remain;
    §7.5.2.2: 0x1001 drops the error's bits. ``before`` is 0x1001 before the error was raised."""
    link = ctx.device.link
    cob = emcy_cob(ctx.device)
    link.flush()
    found, started = None, False
    for _, direction, frame in link.log[mark:]:
        if not started:
            started = after(direction, frame)
        elif (
            direction == "←"
            and frame.cob == cob
            and not frame.rtr
            and emcy_code(frame) == EMCY_ERROR_RESET
        ):
            found = frame
            break
    if found is None and started:
        found = expect_emcy(ctx, EMCY_ERROR_RESET)
    if found is None:
        raise Fail(
            f"the error did not end when {what}",
            expected="EMCY 00 00 <error register left> ... (error reset)",
            seen="no error-reset EMCY",
            clause="CiA 301 §7.2.7.1 (the EMCY state machine sends the error reset when an error ends)",
        )
    register = error_register(ctx)
    if register is None:
        return found
    if len(found.data) < 3 or found.data[2] != register:
        raise Fail(
            f"error-reset EMCY after {what}: byte 2 must be the error register left",
            expected=f"00 00 {register:02X} ... (0x1001 = 0x{register:02X})",
            seen=str(found),
        )
    if register & REGISTER_COMMUNICATION or (before is not None and register != before):
        raise Fail(
            f"0x1001 after {what}",
            expected=f"0x{before if before is not None else 0:02X} (the communication bit 4 cleared)",
            seen=f"0x{register:02X}",
        )
    return found


# -- store (0x1010 / 0x1011), for every profile that saves --------------------------------------
SAVE = 0x65766173  # "save"
LOAD = 0x64616F6C  # "load"


def require_store(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1010, 1, why="store parameters")
    if not dev.read(0x1010, 1) & 0x01:
        raise Skip("0x1010:1 bit 0 is 0: the device does not save on command")
