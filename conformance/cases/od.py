"""Object dictionary against the EDS (CCT "EDS checker" and OD 01-09 style)."""

from __future__ import annotations

from functools import partial

from canopen.objectdictionary import ODArray, ODRecord, datatypes

from ..device import SdoAbort, abort_text, mux, type_name
from ..framework import Context, Fail, Skip, case
from .common import int_default, rw_ints, signed, subindex_numbers

KNOWN_TYPES = {
    getattr(datatypes, n)
    for n in dir(datatypes)
    if n.isupper() and isinstance(getattr(datatypes, n), int)
}
NO_DATA = 0x08000024
RO_WRITE_ABORTS = (0x06010002, 0x06010000, 0x08000000)
# entries whose value is live state rather than a default the EDS can promise
VOLATILE = {0x1001, 0x1002, 0x1003, 0x1010, 0x1011, 0x1F80}


def _report(problems: list[str], what: str) -> None:
    if problems:
        shown = problems[:12] + (
            [f"... and {len(problems) - 12} more"] if len(problems) > 12 else []
        )
        raise Fail(
            f"{len(problems)} {what}", seen="\n                " + "\n                ".join(shown)
        )


@case("od", "eds_check", "EDS consistency: mandatory objects, sub 0 counts, PDO pairs, data types")
def eds_check(ctx: Context) -> None:
    dev = ctx.device
    problems = []
    for index, name in ((0x1000, "device type"), (0x1001, "error register"), (0x1018, "identity")):
        if not dev.has(index):
            problems.append(f"mandatory 0x{index:04X} ({name}) missing")
    if dev.has(0x1018) and not dev.has(0x1018, 1):
        problems.append("0x1018:1 (vendor-ID) missing")
    if not (dev.has(0x1017) or dev.has(0x100C)):
        problems.append(
            "no error control object: neither 0x1017 (heartbeat) nor 0x100C (guard time)"
        )
    for index in dev.od:
        obj = dev.od[index]
        if isinstance(obj, ODRecord):
            top = obj.subindices.get(0)
            if top is None:
                problems.append(f"0x{index:04X}: record without sub 0")
            elif (
                top.access_type in ("ro", "const")
                and int_default(top) is not None
                and max(obj.subindices) != top.default
                and not 0x1600 <= index <= 0x1BFF
            ):
                problems.append(
                    f"0x{index:04X}: sub 0 says {top.default} but the highest sub-index is {max(obj.subindices)}"
                )
        elif isinstance(obj, ODArray) and 0 not in obj.subindices:
            problems.append(f"0x{index:04X}: array without sub 0")
    for var in dev.variables():
        if var.data_type not in KNOWN_TYPES:
            problems.append(
                f"0x{var.index:04X}:{var.subindex}: unknown data type 0x{var.data_type:04X}"
            )
    for comm, mapping in ((0x1400, 0x1600), (0x1800, 0x1A00)):
        for n in range(512):
            if dev.has(comm + n) != dev.has(mapping + n):
                problems.append(f"0x{comm + n:04X} and 0x{mapping + n:04X} must come in pairs")
    _report(problems, "EDS problems")


@case("od", "read_all", "every readable entry in the EDS reads back with its type's size and range")
def read_all(ctx: Context) -> None:
    dev = ctx.device
    problems = []
    count = 0
    for var in dev.variables():
        if not var.readable:
            continue
        count += 1
        where = f"0x{var.index:04X}:{var.subindex}"
        try:
            raw = dev.upload(var.index, var.subindex)
        except SdoAbort as exc:
            if (
                exc.code != NO_DATA
            ):  # "no data available" is a valid answer (e.g. an empty 0x1003 entry)
                problems.append(f"{where}: {exc}")
            continue
        except Fail as exc:
            problems.append(f"{where}: {exc.message} ({exc.seen})")
            if len(problems) >= 3 and all("no SDO response" in p for p in problems[-3:]):
                raise Fail(
                    "the device stopped answering SDO",
                    seen="\n                " + "\n                ".join(problems[-3:]),
                ) from None
            continue
        if var.fixed_size and len(raw) * 8 != len(var):
            problems.append(
                f"{where}: {len(raw)} bytes served, {type_name(var)} needs {len(var) // 8}"
            )
            continue
        if var.fixed_size and var.data_type not in (datatypes.REAL32, datatypes.REAL64):
            value = var.decode_raw(raw)
            if not isinstance(value, (int, float)):
                continue  # (a fixed-size entry that is no number: nothing to compare)
            if var.min is not None and value < var.min or var.max is not None and value > var.max:
                problems.append(
                    f"{where}: value {value} outside the EDS range {var.min}..{var.max}"
                )
    if count == 0:
        raise Skip("EDS lists no readable entry")
    _report(problems, "entries misread")


@case("od", "defaults", "constant and communication entries hold their EDS default")
def defaults(ctx: Context) -> None:
    dev = ctx.device
    problems = []
    for var in dev.variables():
        expected: object = var.default  # (typed int by canopen; a string entry's is a str)
        if not var.readable or expected in (None, "") or var.index in VOLATILE:
            continue
        if var.access_type != "const" and not (0x1000 <= var.index <= 0x1FFF):
            continue
        try:
            value = dev.read(var.index, var.subindex)
        except (SdoAbort, Fail):
            continue  # read_all reports unreadable entries
        if isinstance(expected, str) and isinstance(value, str):
            value, expected = value.rstrip("\0"), expected.rstrip("\0")
        if value != expected:
            problems.append(
                f"0x{var.index:04X}:{var.subindex}: device {value!r}, EDS default {expected!r}"
            )
    _report(problems, "defaults differ from the EDS")


@case(
    "od", "write_read_only", "writes to read-only and constant entries are refused with 0601 0002"
)
def write_read_only(ctx: Context) -> None:
    dev = ctx.device
    problems = []
    tried = 0
    for var in dev.variables():
        if var.access_type not in ("ro", "const") or not var.readable:
            continue
        try:
            raw = dev.upload(var.index, var.subindex)
        except (SdoAbort, Fail):
            continue
        tried += 1
        try:
            dev.download(var.index, var.subindex, raw)
        except SdoAbort as exc:
            if exc.code not in RO_WRITE_ABORTS:
                problems.append(f"0x{var.index:04X}:{var.subindex}: {abort_text(exc.code)}")
            continue
        problems.append(f"0x{var.index:04X}:{var.subindex} ({var.access_type}): write accepted")
    if not tried:
        raise Skip("EDS lists no read-only entry")
    _report(problems, f"read-only entries not refused with {abort_text(0x06010002)}")


@case("od", "read_write_only", "reads of write-only entries are refused with 0601 0001")
def read_write_only(ctx: Context) -> None:
    dev = ctx.device
    targets = [v for v in dev.variables() if v.access_type == "wo"]
    if not targets:
        raise Skip("EDS lists no write-only entry")
    for var in targets:
        dev.expect_abort(
            bytes([0x40]) + mux(var.index, var.subindex),
            (0x06010001,),
            f"read of write-only 0x{var.index:04X}:{var.subindex}",
        )


@case(
    "od",
    "missing_object",
    "an index the EDS does not list is refused with 0602 0000 (read and write)",
)
def missing_object(ctx: Context) -> None:
    dev = ctx.device
    index = next(i for i in (0x5FFF, 0x5FFE, 0x3FFF, 0x2FFF, 0x1FFE) if not dev.has(i))
    dev.expect_abort(
        bytes([0x40]) + mux(index, 0), (0x06020000, 0x08000000), f"read of 0x{index:04X}"
    )
    dev.expect_abort(
        bytes([0x2F]) + mux(index, 0) + b"\x01", (0x06020000, 0x08000000), f"write of 0x{index:04X}"
    )


@case("od", "missing_subindex", "a sub-index the EDS does not list is refused with 0609 0011")
def missing_subindex(ctx: Context) -> None:
    dev = ctx.device
    dev.require(0x1000)
    dev.expect_abort(bytes([0x40]) + mux(0x1000, 1), (0x06090011, 0x08000000), "read of 0x1000:1")
    if dev.has(0x1018):
        top = max(subindex_numbers(dev, 0x1018)) + 1
        dev.expect_abort(
            bytes([0x40]) + mux(0x1018, top), (0x06090011, 0x08000000), f"read of 0x1018:{top}"
        )


@case("od", "length_mismatch", "writes of the wrong length are refused with 0607 0010/0012/0013")
def length_mismatch(ctx: Context) -> None:
    dev = ctx.device
    candidates = rw_ints(dev, 0x1000, 0x1FFF) + rw_ints(dev, 0x2000, 0x9FFF)
    short = next((v for v in candidates if len(v) == 16), None)
    long = next((v for v in candidates if len(v) == 32), None)
    if short is None and long is None:
        raise Skip("EDS lists no writable 16- or 32-bit entry")
    for var, data, codes, what in (
        (
            short,
            b"\x00\x00\x00\x00",
            (0x06070010, 0x06070012, 0x08000000),
            "4 bytes into a 16-bit entry",
        ),
        (long, b"\x00", (0x06070010, 0x06070013, 0x08000000), "1 byte into a 32-bit entry"),
    ):
        if var is None:
            continue
        old = dev.upload(var.index, var.subindex)
        ctx.cleanup(partial(dev.download, var.index, var.subindex, old))
        dev.expect_write_abort(
            var.index, var.subindex, data, codes, f"{what} (0x{var.index:04X}:{var.subindex})"
        )


@case(
    "od",
    "value_range",
    "writes outside the EDS LowLimit/HighLimit are refused with 0609 0030/0031/0032",
)
def value_range(ctx: Context) -> None:
    dev = ctx.device
    checked = 0
    for var in rw_ints(dev, 0x1000, 0xFFFF):
        bits = len(var) - (1 if signed(var) else 0)
        lo_type, hi_type = (-(1 << bits), (1 << bits) - 1) if signed(var) else (0, (1 << bits) - 1)
        probes = []
        if var.max is not None and var.max < hi_type:
            probes.append((var.max + 1, (0x06090030, 0x06090031, 0x08000000), "above HighLimit"))
        if var.min is not None and var.min > lo_type:
            probes.append((var.min - 1, (0x06090030, 0x06090032, 0x08000000), "below LowLimit"))
        if not probes:
            continue
        old = dev.upload(var.index, var.subindex)
        ctx.cleanup(partial(dev.download, var.index, var.subindex, old))
        for value, codes, what in probes:
            checked += 1
            dev.expect_write_abort(
                var.index,
                var.subindex,
                var.encode_raw(value),
                codes,
                f"0x{var.index:04X}:{var.subindex} = {value} {what}",
            )
        if checked >= 6:
            break
    if not checked:
        raise Skip(
            "EDS gives no LowLimit/HighLimit narrower than the data type on a writable entry"
        )
