"""The I-7241D's Application object 0x64 (application.py)."""

from __future__ import annotations

from ...dnet import (
    SET,
    CipErrorSeen,
    status_text,
)
from ...framework import Context, Fail, Info, Skip, case
from .common import APPLICATION, P, explicit, number

APPLICATION_SIZES = {1: 4, 2: 1, 3: 1, 4: 4, 5: 1, 6: 1, 7: 4, 8: 1, 9: 1, 0x0A: 1}


@case(
    P,
    "application_object",
    "the I-7241D's Application object 0x64: class attributes 1-4 and every instance attribute "
    "of its manual (0x01-0x17) readable, with lengths and data that agree",
)
def application_object(ctx: Context) -> None:
    d = explicit(ctx)
    try:
        revision = d.get(APPLICATION, 0, 1)
    except CipErrorSeen as err:
        if err.general in (0x05, 0x08, 0x16):
            raise Skip(
                f"no class 0x64 ({status_text(err.general)}): not an I-7241D-style device"
            ) from None
        raise
    count = number(d.get(APPLICATION, 0, 2))
    if len(revision) != 2 or not count:
        raise Fail(
            "class attributes 1/2",
            expected="UINT revision, UINT instances > 0",
            seen=f"{revision.hex()} / {count}",
        )
    for attribute in (3, 4):  # COM timeout (UINT), Host OK (BYTE)
        value = d.get(APPLICATION, 0, attribute)
        if len(value) != (2 if attribute == 3 else 1):
            raise Fail(f"class attribute {attribute} has the wrong size", seen=value.hex(" "))
    for instance in range(1, count + 1):
        for attribute, size in APPLICATION_SIZES.items():
            value = d.get(APPLICATION, instance, attribute)
            if len(value) != size:
                raise Fail(
                    f"instance {instance} attribute 0x{attribute:02X} has the wrong size",
                    expected=f"{size} byte(s)",
                    seen=value.hex(" ").upper() or "empty",
                )
        lengths = [number(d.get(APPLICATION, instance, 0x0C + n)) for n in range(4)]
        counts = [number(d.get(APPLICATION, instance, 0x10 + n)) for n in range(4)]
        for n, kind in enumerate(("DO", "AO", "DI", "AI")):
            data = d.get(APPLICATION, instance, 0x14 + n)
            if len(data) != lengths[n]:
                raise Fail(
                    f"instance {instance}: {kind} data (0x{0x14 + n:02X}) and its length (0x{0x0C + n:02X}) disagree",
                    expected=f"{lengths[n]} bytes",
                    seen=f"{len(data)} bytes",
                )
            analog = kind in ("AO", "AI")
            wanted = 2 * counts[n] if analog else (counts[n] + 7) // 8
            if lengths[n] != wanted:
                raise Fail(
                    f"instance {instance}: {kind} length for {counts[n]} channels",
                    expected=f"{wanted} bytes",
                    seen=f"{lengths[n]}",
                )
        d.expect_error(
            bytes([SET, APPLICATION, instance, 0x16, 0x00]), (0x0E, 0x15), "Set of DI data"
        )


I7241D_MODULES = 15  # seed-003 §1.3


@case(
    P,
    "application_module_limit",
    "the modules behind the node fit the I-7241D (at most 15 DCON modules: class 0x64 attribute 2)",
)
def application_module_limit(ctx: Context) -> None:
    d = explicit(ctx)
    try:
        count = number(d.get(APPLICATION, 0, 2))
    except CipErrorSeen as err:
        raise Skip(
            f"no class 0x64 ({status_text(err.general)}): not an I-7241D-style device"
        ) from None
    if count > I7241D_MODULES:
        raise Info(
            f"{count} modules: more than the I-7241D holds ({I7241D_MODULES}); a superset that "
            "would not go back onto the real box",
            seen=f"class 0x64 attribute 2 = {count}",
        )


@case(
    P,
    "application_operation_state",
    "fieldgate's class 0x64 attribute 5: the 7-segment's first digit, 'n' normal or '1' DCON "
    "modules init error, as the Identity status says (bit 10)",
)
def application_operation_state(ctx: Context) -> None:
    d = explicit(ctx)
    try:
        state = d.get(APPLICATION, 0, 5)
    except CipErrorSeen as err:
        raise Skip(
            f"class 0x64 attribute 5 ({status_text(err.general)}): the I-7241D shows its state "
            "on the display only"
        ) from None
    status = number(d.get(0x01, 1, 5))
    expected = b"1" if status & 0x0400 else b"n"
    if state != expected:
        raise Fail(
            "operation state and Identity status disagree",
            expected=f"{expected!r} (Identity status 0x{status:04X})",
            seen=repr(state),
        )
