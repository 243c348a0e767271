"""Change of state and cyclic I/O (io_messaging.py): consumed, produced and acknowledged both ways."""

from __future__ import annotations

import time

from ...dnet import (
    ALLOCATE,
    CHOICE_COS,
    CHOICE_CYCLIC,
    CHOICE_EXPLICIT,
    CHOICE_POLL,
    G1_COS_CYCLIC,
    G1_POLL_RESPONSE,
    G2_COS_ACK,
    G2_POLL,
    CipErrorSeen,
    DnetDevice,
    status_text,
)
from ...framework import Context, Fail, Skip, case
from .common import (
    CONNECTION,
    COS_INSTANCE,
    POLL_INSTANCE,
    STATE_ESTABLISHED,
    P,
    dev,
    number,
    set_epr,
)


def allocate_cos_only(d: DnetDevice, choice: int) -> int:
    """Explicit + COS or cyclic without poll; the master-data connection's consumed size
    (instance 2), or Skip when the device has none."""
    try:
        d.allocate(CHOICE_EXPLICIT | choice)
    except CipErrorSeen as err:
        raise Skip(f"allocation 0x{choice:02X} refused ({status_text(err.general)})") from None
    try:
        consumed = number(d.get(CONNECTION, POLL_INSTANCE, 8))
    except CipErrorSeen as err:
        if err.general != 0x16:
            raise
        raise Skip(
            "no instance 2 with COS/cyclic alone: the device consumes no data from the master that way"
        ) from None
    expected = {4: d.g1(G1_POLL_RESPONSE), 5: d.g2(G2_POLL)}
    for attribute, can_id in expected.items():
        value = number(d.get(CONNECTION, POLL_INSTANCE, attribute))
        if value != can_id:
            raise Fail(
                f"the master's COS/cyclic data connection: attribute {attribute} (connection ID)",
                expected=f"0x{can_id:03X} (the predefined set's poll identifiers)",
                seen=f"0x{value:03X}",
            )
    if not consumed:
        raise Fail("instance 2 exists for COS/cyclic data but consumes nothing", seen="size 0")
    return consumed


def expect_ack(d: DnetDevice, what: str) -> None:
    frame = d.link.expect(d.g1(G1_POLL_RESPONSE), d.timing.response)
    if frame is None or frame.data:
        raise Fail(
            f"{what} was not acknowledged",
            expected=f"{d.g1(G1_POLL_RESPONSE):03X} [0] (an empty acknowledge)",
            seen=str(frame) if frame else "nothing",
        )


@case(
    P,
    "cos_consume",
    "change of state alone consumes the master's data on instance 2 (G2/5), acknowledged with "
    "an empty G1/15 message; a poll allocated after it is refused (02/04); released with COS",
)
def cos_consume(ctx: Context) -> None:
    d = dev(ctx)
    consumed = allocate_cos_only(d, CHOICE_COS)
    set_epr(d, COS_INSTANCE, 1000)
    if d.get(CONNECTION, POLL_INSTANCE, 1) != bytes([STATE_ESTABLISHED]):
        set_epr(d, POLL_INSTANCE, 1000)
    d.link.flush()
    d.send_io(d.g2(G2_POLL), bytes(consumed))  # all-zero outputs: the safe value
    expect_ack(d, "the master's change-of-state data")
    frame = d.unconnected(ALLOCATE, bytes([CHOICE_POLL, d.master_mac]))
    if frame is None or frame.data[1:4] != bytes([0x94, 0x02, 0x04]):
        raise Fail(
            "a poll allocated while instance 2 carries the master's COS data was not refused",
            expected="[hdr] 94 02 04 (resource unavailable: poll after COS/cyclic)",
            seen=str(frame) if frame else "nothing",
        )
    d.release(CHOICE_COS)
    try:
        d.get(CONNECTION, POLL_INSTANCE, 1)
    except CipErrorSeen as err:
        if err.general == 0x16:
            return
        raise
    raise Fail("instance 2 stayed after COS was released", expected="error 0x16 for it")


@case(
    P,
    "cyclic_both_ways",
    "cyclic alone: the slave produces every expected packet rate (acknowledged), the master's "
    "cyclic data is consumed and acknowledged; both stay Established while the traffic goes on",
)
def cyclic_both_ways(ctx: Context) -> None:
    d = dev(ctx)
    consumed = allocate_cos_only(d, CHOICE_CYCLIC)
    produced = number(d.get(CONNECTION, COS_INSTANCE, 7))
    epr = set_epr(d, COS_INSTANCE, ctx.timing.heartbeat_ms)
    if d.get(CONNECTION, POLL_INSTANCE, 1) != bytes([STATE_ESTABLISHED]):
        set_epr(d, POLL_INSTANCE, epr)
    messages = 0
    end = time.monotonic() + 6 * epr / 1000
    while time.monotonic() < end:
        # within two periods: a message is late under load, never missing
        data = d.io_message(
            d.g1(G1_COS_CYCLIC), produced, 2 * epr / 1000 + ctx.timing.slack(epr / 1000)
        )
        if data is None:
            raise Fail(
                "no cyclic message within two expected packet rates", expected=f"every {epr} ms"
            )
        if len(data) != produced:
            raise Fail(
                "cyclic message of the wrong size", expected=str(produced), seen=str(len(data))
            )
        messages += 1
        d.link.send(d.g2(G2_COS_ACK), b"")  # the master's acknowledge
        d.send_io(d.g2(G2_POLL), bytes(consumed))
        expect_ack(d, "the master's cyclic data")
    for instance in (COS_INSTANCE, POLL_INSTANCE):
        state = d.get(CONNECTION, instance, 1)
        if state != bytes([STATE_ESTABLISHED]):
            raise Fail(
                f"instance {instance} left Established although both sides kept to the rate",
                expected="state 3",
                seen=state.hex(),
            )
    if messages < 3:
        raise Fail(
            "too few cyclic messages", expected="one per expected packet rate", seen=str(messages)
        )
