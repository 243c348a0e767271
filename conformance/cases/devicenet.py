"""DeviceNet Group 2 Only slave: duplicate MAC ID check, Predefined Master/Slave Connection Set
(Allocate / Release), explicit messaging with CIP errors and fragmentation, poll I/O, expected
packet rate and inactivity timeout (anchors-gateways §2, seed-003)."""

from __future__ import annotations

import time

from ..dnet import (
    ALLOCATE,
    CHOICE_COS,
    CHOICE_CYCLIC,
    CHOICE_EXPLICIT,
    CHOICE_POLL,
    CHOICE_STROBE,
    G1_COS_CYCLIC,
    G1_POLL_RESPONSE,
    G2_COS_ACK,
    G2_DUP_MAC,
    G2_POLL,
    GET,
    RESET,
    SET,
    CipErrorSeen,
    DnetDevice,
    status_text,
)
from ..framework import Context, Fail, Skip, case
from ..link import Frame

P = "devicenet"
IDENTITY, DEVICENET, CONNECTION = 0x01, 0x03, 0x05
POLL_INSTANCE = 2
STATE_ESTABLISHED, STATE_TIMED_OUT = 3, 4
TESTER_VENDOR, TESTER_SERIAL = (
    0xFFFE,
    0x7E57C0DE,
)  # the tester's "own" identity in a duplicate MAC ID request
IDENTITY_SIZES = {1: 2, 2: 2, 3: 2, 4: 2, 5: 2, 6: 4}
IDENTITY_NAMES = {
    1: "vendor ID",
    2: "device type",
    3: "product code",
    4: "revision",
    5: "status",
    6: "serial number",
    7: "product name",
}


def dev(ctx: Context) -> DnetDevice:
    return ctx.dnet


def explicit(ctx: Context) -> DnetDevice:
    d = dev(ctx)
    d.allocate(CHOICE_EXPLICIT)
    return d


def short_string(data: bytes, what: str) -> str:
    if not data or data[0] != len(data) - 1:
        raise Fail(
            f"{what} is not a SHORT_STRING (length byte + characters)",
            seen=data.hex(" ").upper() or "empty",
        )
    return data[1:].decode("latin-1")


def io_sizes(d: DnetDevice, instance: int) -> tuple[int, int]:
    produced = int.from_bytes(d.get(CONNECTION, instance, 7), "little")
    consumed = int.from_bytes(d.get(CONNECTION, instance, 8), "little")
    return produced, consumed


def allocate_poll(d: DnetDevice) -> None:
    """Explicit + poll, or SKIP if the device refuses poll as unsupported."""
    try:
        d.allocate(CHOICE_EXPLICIT | CHOICE_POLL)
    except CipErrorSeen as err:
        if err.general in (0x02, 0x09):
            raise Skip(
                f"the device refuses a poll connection ({status_text(err.general)}): poll not supported"
            ) from None
        raise Fail(
            "Allocate explicit + poll refused", expected="[hdr] CB 00", seen=str(err.frame)
        ) from None


def set_epr(d: DnetDevice, instance: int, ms: int) -> int:
    granted = d.set(CONNECTION, instance, 9, ms.to_bytes(2, "little"))
    value = int.from_bytes(granted, "little") if len(granted) == 2 else None
    if value is None or value < ms:
        raise Fail(
            "Set expected packet rate: the response must carry the granted rate (≥ the requested one)",
            expected=f"2 bytes ≥ {ms}",
            seen=granted.hex(" ").upper() or "empty",
        )
    return value


@case(
    P,
    "dup_mac_answer",
    "a duplicate MAC ID request for the device's MAC is answered with a response (vendor, serial)",
)
def dup_mac_answer(ctx: Context) -> None:
    d = dev(ctx)
    request = (
        bytes([0x00]) + TESTER_VENDOR.to_bytes(2, "little") + TESTER_SERIAL.to_bytes(4, "little")
    )
    d.link.flush()
    d.link.send(d.g2(G2_DUP_MAC), request)
    frame = d.link.expect(d.g2(G2_DUP_MAC), ctx.timing.response)
    if frame is None:
        raise Fail(
            "no duplicate MAC ID response",
            expected=f"{d.g2(G2_DUP_MAC):03X} [7] 80 <vendor> <serial>",
            seen="nothing",
        )
    if len(frame.data) != 7 or not frame.data[0] & 0x80:
        raise Fail(
            "malformed duplicate MAC ID response",
            expected="DLC 7, byte 0 bit 7 set (response)",
            seen=str(frame),
        )
    identity = explicit(ctx)
    vendor, serial = identity.get(IDENTITY, 1, 1), identity.get(IDENTITY, 1, 6)
    if frame.data[1:3] != vendor or frame.data[3:7] != serial:
        raise Fail(
            "duplicate MAC ID response does not carry the Identity vendor ID and serial number",
            expected=(vendor + serial).hex(" ").upper(),
            seen=str(frame),
        )


@case(
    P,
    "dup_mac_at_reset",
    "Identity Reset: the device restarts with two duplicate MAC ID requests, then is online again",
)
def dup_mac_at_reset(ctx: Context) -> None:
    d = explicit(ctx)
    reply = d.request(bytes([RESET, IDENTITY, 1]))
    if reply is None:
        raise Fail("no response to Identity Reset", expected="[hdr] 85", seen="nothing")
    if reply.service == 0x94 and reply.data[:1] == b"\x08":
        raise Skip(
            "the device does not support the Identity Reset service (0x08): the power-up check cannot be provoked over the bus"
        )
    if reply.service != RESET | 0x80:
        raise Fail(
            "wrong response to Identity Reset", expected="[hdr] 85", seen=str(reply.frames[-1])
        )
    requests: list[Frame] = []
    deadline = (
        time.monotonic() + ctx.timing.bootup + 2.5
    )  # DeviceNet: one second after each request
    while len(requests) < 2 and time.monotonic() < deadline:
        frame = d.link.expect(d.g2(G2_DUP_MAC), deadline - time.monotonic())
        if frame is not None:
            if len(frame.data) != 7 or frame.data[0] & 0x80:
                raise Fail(
                    "malformed duplicate MAC ID request",
                    expected="DLC 7, byte 0 = 00 (request)",
                    seen=str(frame),
                )
            requests.append(frame)
    if len(requests) < 2:
        raise Fail(
            "the restart did not send two duplicate MAC ID requests",
            expected=f"2 × {d.g2(G2_DUP_MAC):03X} [7] 00 ...",
            seen=f"{len(requests)}",
        )
    if not d.wait_online(ctx.timing.bootup + 1.5):
        raise Fail(
            "the device is not online again after its duplicate MAC ID check",
            expected="a response to Allocate",
            seen="nothing",
        )


@case(
    P,
    "allocate_explicit",
    "Allocate explicit through the Group 2 Only unconnected port: [master MAC] CB <body format>",
)
def allocate_explicit(ctx: Context) -> None:
    d = dev(ctx)
    frame = d.allocate(CHOICE_EXPLICIT)
    data = frame.data
    if len(data) != 3 or data[0] != d.master_mac or data[2] > 0x03:
        raise Fail(
            "wrong Allocate response",
            expected=f"{d.g2(3):03X} [3] {d.master_mac:02X} CB <0..3>",
            seen=str(frame),
        )
    choice = d.get(DEVICENET, 1, 5)
    if len(choice) != 2 or not choice[0] & CHOICE_EXPLICIT or choice[1] != d.master_mac:
        raise Fail(
            "DeviceNet object attribute 5 does not show the allocation",
            expected=f"choice with bit 0, master {d.master_mac:02X}",
            seen=choice.hex(" ").upper(),
        )


@case(
    P,
    "allocate_conflict",
    "a second Allocate of the same connection, or by another master, is refused (0x0B / 0x0C)",
)
def allocate_conflict(ctx: Context) -> None:
    d = explicit(ctx)
    for choice, master, codes, what in (
        (CHOICE_EXPLICIT, None, (0x0B,), "explicit allocated twice"),
        (CHOICE_EXPLICIT, (d.master_mac + 1) & 0x3F, (0x0C,), "Allocate by another master"),
    ):
        try:
            frame = d.allocate(choice, master=master)
        except CipErrorSeen as err:
            if err.general not in codes:
                raise Fail(
                    f"{what}: wrong general status",
                    expected=" or ".join(status_text(c) for c in codes),
                    seen=str(err.frame),
                ) from None
            continue
        raise Fail(f"{what}: accepted", expected="an error response [hdr] CB→94", seen=str(frame))


@case(
    P,
    "allocate_validation",
    "invalid Allocate choices are refused 09/02, other services on the unconnected port 02/03",
)
def allocate_validation(ctx: Context) -> None:
    d = dev(ctx)
    for choice, what in (
        (0x00, "Allocate with choice 0"),
        (0x41, "ack suppression without COS or cyclic"),
        (CHOICE_POLL, "poll without the explicit connection"),
    ):
        d.expect_unconnected_error(ALLOCATE, bytes([choice, d.master_mac]), (0x09, 0x02), what)
    d.expect_unconnected_error(
        GET, bytes([1]), (0x02, 0x03), "Get_Attribute_Single on the Group 2 Only unconnected port"
    )


@case(
    P,
    "identity",
    "Identity (class 1 instance 1): vendor, device type, product code, revision, status, serial, product name",
)
def identity(ctx: Context) -> None:
    d = explicit(ctx)
    for attribute, size in IDENTITY_SIZES.items():
        data = d.get(IDENTITY, 1, attribute)
        if len(data) != size:
            raise Fail(
                f"Identity attribute {attribute} ({IDENTITY_NAMES[attribute]}) has the wrong size",
                expected=f"{size} bytes",
                seen=data.hex(" ").upper() or "empty",
            )
    major, minor = d.get(IDENTITY, 1, 4)
    if not 1 <= major <= 127:
        raise Fail(
            "Identity revision: major revision out of range",
            expected="1..127",
            seen=f"{major}.{minor}",
        )
    name = short_string(d.get(IDENTITY, 1, 7), "Identity attribute 7 (product name)")
    if not 1 <= len(name) <= 32:
        raise Fail("product name length", expected="1..32 characters", seen=repr(name))


GET_ATTRIBUTES_ALL = 0x01


def identity_singles(d: DnetDevice) -> bytes:
    """Identity attributes 1-7 read one by one (Get_Attribute_Single), joined in attribute order."""
    return b"".join(d.get(IDENTITY, 1, attribute) for attribute in IDENTITY_NAMES)


@case(
    P,
    "identity_get_all",
    "Get_Attributes_All (0x01) of Identity instance 1 answers attributes 1-7 in the specification's order, equal to their Get_Attribute_Single answers (CIP Vol. 1 §5-2 Identity object)",
)
def identity_get_all(ctx: Context) -> None:
    """The response is vendor ID, device type, product code, revision (major, minor), status,
    serial number, product name (SHORT_STRING), nothing between them. Later CIP editions append
    further attributes (8 state, 9 configuration consistency value, 10 heartbeat interval) for
    devices that have them, so bytes after the product name are allowed. The status word may
    change between two reads: the singles are read before and after."""
    d = explicit(ctx)
    before = identity_singles(d)
    try:
        reply = d.call(
            GET_ATTRIBUTES_ALL, IDENTITY, 1, b"", "Get_Attributes_All of Identity instance 1"
        )
    except CipErrorSeen as err:
        if err.general == 0x08:
            raise Skip(
                "the device does not offer Get_Attributes_All on the Identity object (answers 0x08)"
            ) from None
        raise Fail(
            "Get_Attributes_All of Identity instance 1 refused",
            expected="[hdr] 81 <attributes 1-7>",
            seen=str(err.frame),
        ) from None
    after = identity_singles(d)
    answer = reply.data[: len(before)]
    if answer not in (before, after[: len(before)]) or len(reply.data) < len(before):
        names = ", ".join(IDENTITY_NAMES.values())
        raise Fail(
            f"Get_Attributes_All does not answer {names} in this order",
            expected=before.hex(" ").upper(),
            seen=reply.data.hex(" ").upper() or "empty",
        )


@case(
    P,
    "devicenet_object",
    "DeviceNet object (class 3 instance 1): MAC ID = the device's, baud rate code 0..2",
)
def devicenet_object(ctx: Context) -> None:
    d = explicit(ctx)
    mac, baud = d.get(DEVICENET, 1, 1), d.get(DEVICENET, 1, 2)
    if mac != bytes([d.mac_id]):
        raise Fail(
            "DeviceNet object attribute 1 (MAC ID)",
            expected=f"{d.mac_id:02X}",
            seen=mac.hex(" ").upper(),
        )
    if len(baud) != 1 or baud[0] > 2:
        raise Fail(
            "DeviceNet object attribute 2 (baud rate)",
            expected="one byte 0 (125k), 1 (250k) or 2 (500k)",
            seen=baud.hex(" ").upper(),
        )


@case(P, "error_unknown_service", "a service the object does not offer is refused with 0x08")
def error_unknown_service(ctx: Context) -> None:
    explicit(ctx).expect_error(
        bytes([0x06, IDENTITY, 1]), (0x08,), "Start (0x06) to the Identity object"
    )


@case(P, "error_unknown_object", "an unknown class or instance is refused with 0x16 (or 0x05)")
def error_unknown_object(ctx: Context) -> None:
    d = explicit(ctx)
    d.expect_error(bytes([GET, 0xC8, 1, 1]), (0x16, 0x05), "Get of reserved class 0xC8")
    d.expect_error(bytes([GET, IDENTITY, 0x7F, 1]), (0x16, 0x05), "Get of Identity instance 0x7F")


@case(P, "error_unknown_attribute", "an unknown attribute is refused with 0x14")
def error_unknown_attribute(ctx: Context) -> None:
    explicit(ctx).expect_error(
        bytes([GET, IDENTITY, 1, 0x63]), (0x14,), "Get of Identity attribute 99"
    )


@case(
    P, "error_read_only", "a Set of a read-only attribute (Identity vendor ID) is refused with 0x0E"
)
def error_read_only(ctx: Context) -> None:
    d = explicit(ctx)
    vendor = d.get(IDENTITY, 1, 1)
    d.expect_error(bytes([SET, IDENTITY, 1, 1]) + vendor, (0x0E,), "Set of Identity vendor ID")


@case(
    P,
    "fragmented_response",
    "a long attribute (product name) comes as acknowledged fragments: first, middle, last, counts in order",
)
def fragmented_response(ctx: Context) -> None:
    d = explicit(ctx)
    reply = d.call(GET, IDENTITY, 1, bytes([7]), "Get of the product name")
    if len(reply.frames) == 1:
        raise Skip(
            f"the product name ({len(reply.data) - 1} characters) fits one frame: no long attribute to read"
        )
    name = short_string(reply.data, "the reassembled product name")
    if len(reply.frames) != (len(name) + 2 + 5) // 6:
        raise Fail(
            "fragment count",
            expected=f"{(len(name) + 2 + 5) // 6} fragments of 6 bytes",
            seen=f"{len(reply.frames)}",
        )


@case(
    P,
    "poll_io",
    "allocate poll, set its expected packet rate; a poll of the consumed size answers the produced size",
)
def poll_io(ctx: Context) -> None:
    d = dev(ctx)
    allocate_poll(d)
    produced, consumed = io_sizes(d, POLL_INSTANCE)
    granted = set_epr(d, POLL_INSTANCE, 1000)
    if int.from_bytes(d.get(CONNECTION, POLL_INSTANCE, 9), "little") != granted:
        raise Fail("expected packet rate does not read back as granted", expected=str(granted))
    state = d.get(CONNECTION, POLL_INSTANCE, 1)
    if state != bytes([STATE_ESTABLISHED]):
        raise Fail(
            "poll connection not Established after its EPR was set",
            expected="state 3",
            seen=state.hex(),
        )
    first = d.poll(bytes(consumed))  # all-zero outputs: the safe value
    if first is None:
        raise Fail(
            "no poll response",
            expected=f"{d.poll_response_id:03X} with {produced} bytes",
            seen="nothing",
        )
    data = d.poll_fragments(first, produced)
    if len(data) != produced:
        raise Fail(
            "poll response has the wrong size",
            expected=f"{produced} bytes (connection attribute 7)",
            seen=f"{len(data)} bytes",
        )


@case(
    P,
    "loopback_poll",
    "--loopback: outputs sent by poll come back in the poll response (same layout both ways)",
)
def loopback_poll(ctx: Context) -> None:
    if not ctx.options.loopback:
        raise Skip("needs --loopback (a bench whose outputs are wired to its inputs)")
    d = dev(ctx)
    allocate_poll(d)
    produced, consumed = io_sizes(d, POLL_INSTANCE)
    if produced != consumed or not consumed:
        raise Skip(
            f"produced ({produced} bytes) and consumed ({consumed} bytes) sizes differ: the layout cannot be compared"
        )
    set_epr(d, POLL_INSTANCE, 1000)
    pattern = bytes((0xA5, 0x5A, 0x3C)[i % 3] for i in range(consumed))
    try:
        seen = b""
        deadline = time.monotonic() + 4 * ctx.timing.response
        while seen != pattern and time.monotonic() < deadline:  # the loop may take a few polls
            first = d.poll(pattern)
            seen = d.poll_fragments(first, produced) if first is not None else b""
            time.sleep(0.02)
        if seen != pattern:
            raise Fail(
                "the outputs did not come back through the loopback",
                expected=pattern.hex(" ").upper(),
                seen=seen.hex(" ").upper() or "no poll response",
            )
    finally:
        d.poll(bytes(consumed))  # outputs back to zero


@case(
    P,
    "epr_keeps_alive",
    "polls faster than the expected packet rate keep the poll connection Established",
)
def epr_keeps_alive(ctx: Context) -> None:
    d = dev(ctx)
    allocate_poll(d)
    _, consumed = io_sizes(d, POLL_INSTANCE)
    epr = set_epr(d, POLL_INSTANCE, ctx.timing.heartbeat_ms)
    end = time.monotonic() + 6 * epr / 1000
    while time.monotonic() < end:
        if d.poll(bytes(consumed)) is None:
            raise Fail("poll not answered while polling at half the expected packet rate")
        time.sleep(epr / 2000)
    state = d.get(CONNECTION, POLL_INSTANCE, 1)
    if state != bytes([STATE_ESTABLISHED]):
        raise Fail(
            "the poll connection left Established although polled in time",
            expected="state 3",
            seen=state.hex(),
        )


@case(
    P,
    "inactivity_timeout",
    "no poll for 4 × the expected packet rate: the poll connection times out and polls are not answered",
)
def inactivity_timeout(ctx: Context) -> None:
    d = dev(ctx)
    allocate_poll(d)
    _, consumed = io_sizes(d, POLL_INSTANCE)
    epr = set_epr(d, POLL_INSTANCE, ctx.timing.heartbeat_ms)
    if d.poll(bytes(consumed)) is None:
        raise Fail("no poll response before the timeout")
    time.sleep(4 * epr / 1000 + ctx.timing.slack(4 * epr / 1000))
    try:
        state = d.get(CONNECTION, POLL_INSTANCE, 1)
    except CipErrorSeen as err:
        if err.general != 0x16:
            raise
        state = b"deleted"
    if state not in (bytes([STATE_TIMED_OUT]), b"deleted"):
        raise Fail(
            f"poll connection still alive after 4 × {epr} ms without a poll",
            expected="state 4 (timed out) or deleted",
            seen=state.hex(),
        )
    answer = d.poll(bytes(consumed), ctx.timing.silence)
    if answer is not None:
        raise Fail(
            "a timed-out poll connection still answers polls",
            expected="no poll response",
            seen=answer.hex(" ").upper(),
        )


@case(
    P,
    "release",
    "Release poll then explicit: CC responses; the released connections no longer answer; a second Release is refused",
)
def release(ctx: Context) -> None:
    d = dev(ctx)
    allocate_poll(d)
    _, consumed = io_sizes(d, POLL_INSTANCE)
    set_epr(d, POLL_INSTANCE, 1000)
    for choice in (CHOICE_POLL, CHOICE_EXPLICIT):
        frame = d.release(choice)
        if len(frame.data) != 2 or frame.data[0] != d.master_mac:
            raise Fail(
                f"wrong Release 0x{choice:02X} response",
                expected=f"[2] {d.master_mac:02X} CC",
                seen=str(frame),
            )
        if choice == CHOICE_POLL:
            answer = d.poll(bytes(consumed), ctx.timing.silence)
            if answer is not None:
                raise Fail(
                    "a released poll connection still answers",
                    expected="no poll response",
                    seen=answer.hex(" ").upper(),
                )
    reply = d.request(bytes([GET, IDENTITY, 1, 1]), ctx.timing.silence)
    if reply is not None:
        raise Fail(
            "a released explicit connection still answers",
            expected="no response",
            seen=str(reply.frames[-1]),
        )
    try:
        frame = d.release(CHOICE_EXPLICIT)
    except CipErrorSeen as err:
        if err.general != 0x0B:
            raise Fail(
                "second Release: wrong general status",
                expected=status_text(0x0B),
                seen=str(err.frame),
            ) from None
    else:
        raise Fail(
            "a Release of a connection not allocated is accepted",
            expected="error 0x0B",
            seen=str(frame),
        )
    other = (
        d.master_mac + 1
    ) & 0x3F  # with nothing allocated the set has no owner: another master may allocate
    ctx.cleanup(lambda: d.unconnected(0x4C, bytes([CHOICE_EXPLICIT]), master=other))
    try:
        d.allocate(CHOICE_EXPLICIT, master=other)
    except CipErrorSeen as err:
        raise Fail(
            "after releasing everything the set still has an owner: Allocate by another master refused",
            expected=f"{other:02X} CB 00",
            seen=str(err.frame),
        ) from None


# -- I/O connection paths, change of state / cyclic both ways, the I-7241D's object 0x64 ------
STROBE_INSTANCE, COS_INSTANCE = 3, 4
ASSEMBLY = 0x04
APPLICATION = 0x64


def number(data: bytes) -> int:
    return int.from_bytes(data, "little")


def assembly_of(path: bytes, what: str) -> int | None:
    """The Assembly instance a connection path names (``20 04 24 nn 30 03``), None if empty."""
    if not path:
        return None
    if path[:3] == b"\x20\x04\x24" and len(path) >= 4 and path[4:] in (b"", b"\x30\x03"):
        return path[3]
    if path[:4] == b"\x20\x04\x25\x00" and len(path) >= 6 and path[6:] in (b"", b"\x30\x03"):
        return number(path[4:6])
    raise Fail(
        f"{what} is not a path to an Assembly's data",
        expected="20 04 24 <instance> 30 03 (or 20 04 25 00 <instance LE16> 30 03)",
        seen=path.hex(" ").upper(),
    )


def check_path(
    d: DnetDevice, instance: int, path_attr: int, size_attr: int, what: str
) -> int | None:
    """The path attribute names an assembly whose data has the connection's size; its instance."""
    path = d.get(CONNECTION, instance, path_attr)
    length = number(d.get(CONNECTION, instance, path_attr - 1))
    if length != len(path):
        raise Fail(
            f"{what}: path length attribute {path_attr - 1} disagrees with the path",
            expected=str(len(path)),
            seen=str(length),
        )
    size = number(d.get(CONNECTION, instance, size_attr))
    assembly = assembly_of(path, f"{what} (attribute {path_attr})")
    if assembly is None:
        return None
    data = d.get(ASSEMBLY, assembly, 3)
    fits = size == len(data) or (instance == STROBE_INSTANCE and size == min(len(data), 8))
    if not fits:
        raise Fail(
            f"{what}: the connection's size is not its assembly's",
            expected=f"attribute {size_attr} = {len(data)} (assembly 0x{assembly:02X} data)",
            seen=str(size),
        )
    return assembly


@case(
    P,
    "io_paths",
    "the I/O connections' path attributes (14/16) name the assembly each carries, of the "
    "connection's size; a path set while Configuring selects another assembly, the size follows",
)
def io_paths(ctx: Context) -> None:
    d = dev(ctx)
    try:
        d.allocate(CHOICE_EXPLICIT | CHOICE_POLL | CHOICE_STROBE)
    except CipErrorSeen as err:
        raise Skip(f"poll + bit-strobe refused ({status_text(err.general)})") from None
    produced = check_path(d, POLL_INSTANCE, 14, 7, "poll produced path")
    check_path(d, POLL_INSTANCE, 16, 8, "poll consumed path")
    check_path(d, STROBE_INSTANCE, 14, 7, "bit-strobe produced path")
    if produced is None:
        return
    # another input assembly: each instance up to the class's maximum whose Set is accepted
    highest = number(d.get(ASSEMBLY, 0, 2))
    others = [n for n in range(1, highest + 1) if n != produced]
    selected = None
    for n in others:
        reply = d.request(
            bytes([SET, CONNECTION, POLL_INSTANCE, 14, 0x20, 0x04, 0x24, n, 0x30, 0x03])
        )
        if reply is None:
            raise Fail("no response to Set of the poll's produced path")
        if reply.service == SET | 0x80:
            selected = n
            break
        if reply.data[:1] == b"\x0e":
            raise Skip(
                "the paths are Get only here: selection is by the device's own configuration"
            )
    if selected is None:
        return  # one input assembly: nothing else to select
    check_path(d, POLL_INSTANCE, 14, 7, f"poll produced path set to 0x{selected:02X}")
    size = number(d.get(CONNECTION, POLL_INSTANCE, 7))
    set_epr(d, POLL_INSTANCE, 1000)
    _, consumed = io_sizes(d, POLL_INSTANCE)
    first = d.poll(b"")  # idle: the produced data only
    if first is None:
        raise Fail("no poll response after selecting a path", expected=f"{size} bytes")
    answer = d.poll_fragments(first, size)
    if len(answer) != size:
        raise Fail(
            "the poll answers another size than its selected path",
            expected=f"{size} bytes (assembly 0x{selected:02X})",
            seen=f"{len(answer)} bytes",
        )
    reply = d.request(
        bytes([SET, CONNECTION, POLL_INSTANCE, 14, 0x20, 0x04, 0x24, produced, 0x30, 0x03])
    )
    if reply is None or reply.data[:1] != b"\x0c":
        raise Fail(
            "a path Set on an Established connection was not refused",
            expected="error 0x0C (object state conflict)",
            seen=str(reply.frames[-1]) if reply else "nothing",
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
