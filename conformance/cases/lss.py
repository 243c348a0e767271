"""LSS (CiA 305): switch modes, inquire, identify, configure node-ID and bit timing, store, fastscan."""

from __future__ import annotations

import struct
import time

from ..device import NMT_RESET_COMM, Device
from ..framework import Context, Fail, Skip, case
from ..link import Frame

TX, RX = 0x7E5, 0x7E4  # master → slave, slave → master
WAITING, CONFIGURATION = 0, 1


def require_lss(ctx: Context) -> None:
    if not getattr(ctx.device.od.device_information, "LSS_supported", False):
        raise Skip("EDS [DeviceInfo] does not set LSS_Supported=1")
    ctx.device.require(0x1018, 4, why="LSS address = 0x1018:1..4")


def lss(
    ctx: Context, data: bytes | list[int], reply: int | None = None, timeout: float | None = None
) -> Frame | None:
    dev = ctx.device
    dev.link.flush()
    dev.link.send(TX, bytes(data).ljust(8, b"\0"))
    if reply is None:
        time.sleep(0.01)
        return None
    return dev.link.expect(
        lambda f: f.cob == RX and f.data[:1] == bytes([reply]),
        ctx.timing.response if timeout is None else timeout,
    )


def must(ctx: Context, data: bytes | list[int], reply: int, what: str) -> Frame:
    frame = lss(ctx, data, reply)
    if frame is None:
        raise Fail(f"no LSS answer to {what}", expected=f"7E4 [8] {reply:02X} ..", seen="nothing")
    if len(frame.data) != 8:
        raise Fail(
            f"LSS answer to {what} with DLC {len(frame.data)}", expected="DLC 8", seen=str(frame)
        )
    return frame


def silent(ctx: Context, data: bytes | list[int], what: str) -> None:
    dev = ctx.device
    dev.link.flush()
    dev.link.send(TX, bytes(data).ljust(8, b"\0"))
    frame = dev.link.expect(RX, ctx.timing.silence)
    if frame is not None:
        raise Fail(f"LSS answer to {what}", expected="none", seen=str(frame))


def identity(dev: Device) -> list[int]:
    return [dev.read(0x1018, s) for s in (1, 2, 3, 4)]


def switch(ctx: Context, mode: int) -> None:
    lss(ctx, [0x04, mode])
    if mode == CONFIGURATION:
        ctx.cleanup(lambda: lss(ctx, [0x04, WAITING]))


@case(
    "lss", "switch_global", "switch mode global: inquire node-ID answers only in configuration mode"
)
def switch_global(ctx: Context) -> None:
    require_lss(ctx)
    silent(ctx, [0x5E], "inquire node-ID in waiting mode")
    switch(ctx, CONFIGURATION)
    frame = must(ctx, [0x5E], 0x5E, "inquire node-ID")
    if frame.data[1] != ctx.device.node_id:
        raise Fail("inquire node-ID", expected=f"5E {ctx.device.node_id:02X}", seen=str(frame))
    lss(ctx, [0x04, WAITING])
    silent(ctx, [0x5E], "inquire node-ID after switching back to waiting")


@case("lss", "inquire_identity", "inquire vendor, product, revision and serial match 0x1018")
def inquire_identity(ctx: Context) -> None:
    require_lss(ctx)
    ident = identity(ctx.device)
    switch(ctx, CONFIGURATION)
    for cs, value, name in zip(
        (0x5A, 0x5B, 0x5C, 0x5D),
        ident,
        ("vendor-ID", "product code", "revision", "serial number"),
        strict=True,
    ):
        frame = must(ctx, [cs], cs, f"inquire {name}")
        got = struct.unpack_from("<I", frame.data, 1)[0]
        if got != value:
            raise Fail(f"inquire {name}", expected=f"0x{value:08X} (0x1018)", seen=f"0x{got:08X}")


@case(
    "lss",
    "switch_selective",
    "switch mode selective: full match answers 0x44 and enters configuration; a wrong serial does not",
)
def switch_selective(ctx: Context) -> None:
    require_lss(ctx)
    ident = identity(ctx.device)
    for cs, value in zip((0x40, 0x41, 0x42), ident[:3], strict=True):  # no serial number (0x43)
        lss(ctx, bytes([cs]) + struct.pack("<I", value))
    silent(
        ctx, bytes([0x43]) + struct.pack("<I", ident[3] ^ 1), "switch selective with a wrong serial"
    )
    silent(ctx, [0x5E], "inquire node-ID after a failed selective switch")
    for cs, value in zip((0x40, 0x41, 0x42), ident[:3], strict=True):  # no serial number (0x43)
        lss(ctx, bytes([cs]) + struct.pack("<I", value))
    ctx.cleanup(lambda: lss(ctx, [0x04, WAITING]))
    must(ctx, bytes([0x43]) + struct.pack("<I", ident[3]), 0x44, "switch selective")
    must(ctx, [0x5E], 0x5E, "inquire node-ID after the selective switch")


@case(
    "lss",
    "identify_remote",
    "identify remote slave: a matching range answers 0x4F, a non-matching one does not",
)
def identify_remote(ctx: Context) -> None:
    require_lss(ctx)
    v, p, r, s = identity(ctx.device)

    def request(serial_lo: int, serial_hi: int) -> list[bytes]:
        parts = [
            (0x46, v),
            (0x47, p),
            (0x48, 0),
            (0x49, 0xFFFFFFFF),
            (0x4A, serial_lo),
            (0x4B, serial_hi),
        ]
        return [bytes([cs]) + struct.pack("<I", val) for cs, val in parts]

    for frame in request(s, s)[:-1]:
        lss(ctx, frame)
    if lss(ctx, request(s, s)[-1], 0x4F) is None:
        raise Skip(
            "no answer to identify remote slave: an optional LSS service (CiA 305 §5.4 lists"
            " identification as optional), not offered"
        )
    lo = (s + 1) & 0xFFFFFFFF
    for frame in request(lo, max(lo, 0xFFFFFFFF if lo else 1))[:-1]:
        lss(ctx, frame)
    if lo:
        silent(
            ctx,
            request(lo, 0xFFFFFFFF)[-1],
            "identify remote slave with the serial outside the range",
        )


@case(
    "lss",
    "identify_non_configured",
    "a configured slave does not answer identify non-configured (0x4C)",
)
def identify_non_configured(ctx: Context) -> None:
    require_lss(ctx)
    silent(ctx, [0x4C], "identify non-configured remote slave")


@case(
    "lss",
    "configure_bit_timing",
    "configure bit timing answers 0x13 with 0 (supported) or 1; a reserved table answers an error",
)
def configure_bit_timing(ctx: Context) -> None:
    require_lss(ctx)
    switch(ctx, CONFIGURATION)
    frame = lss(ctx, [0x13, 0x00, 0x04], 0x13)
    if frame is None:
        raise Fail(
            "no LSS answer to configure bit timing 125 kbit/s (CiA table index 4)",
            expected="7E4 [8] 13 <0 supported or 1 not> ..",
            seen="nothing",
            clause="CiA 305 §5.3.3 / §6.4.3 (configure bit timing parameters is a confirmed service: the slave answers 0 or 1, also when it does not support the table)",
        )
    if frame.data[1] not in (0, 1):
        raise Fail("configure bit timing error code", expected="0 or 1", seen=str(frame))
    frame = must(
        ctx, [0x13, 0x00, 0x0F], 0x13, "configure bit timing with table index 15 (reserved)"
    )
    if frame.data[1] == 0:
        raise Fail("reserved bit timing index accepted", expected="13 01 ..", seen=str(frame))


@case("lss", "store", "store configuration answers 0x17 with 0 (stored) or 1 (not supported)")
def store(ctx: Context) -> None:
    require_lss(ctx)
    switch(ctx, CONFIGURATION)
    frame = must(ctx, [0x17], 0x17, "store configuration")
    if frame.data[1] not in (0, 1):
        raise Fail("store configuration error code", expected="0 or 1", seen=str(frame))


def spare_id(ctx: Context) -> int:
    return ctx.options.lss_spare_node_id or ctx.device.node_id % 127 + 1


def restore_node_id(ctx: Context, current: int) -> None:
    """Give the device its node-ID back (used as clean-up, also after a failure)."""
    dev = ctx.device
    lss(ctx, [0x04, CONFIGURATION])
    lss(ctx, [0x11, dev.node_id], 0x11)
    lss(ctx, [0x04, WAITING])
    dev.nmt(NMT_RESET_COMM, node=current)
    dev.wait_bootup()


@case(
    "lss",
    "configure_node_id",
    "configure node-ID: invalid IDs refused; a new ID is taken at reset communication",
)
def configure_node_id(ctx: Context) -> None:
    require_lss(ctx)
    dev = ctx.device
    new = spare_id(ctx)
    switch(ctx, CONFIGURATION)
    for bad in (0x00, 0x80):
        frame = must(ctx, [0x11, bad], 0x11, f"configure node-ID 0x{bad:02X}")
        if frame.data[1] != 1:
            raise Fail(f"node-ID 0x{bad:02X} accepted", expected="11 01 ..", seen=str(frame))
    frame = must(ctx, [0x11, new], 0x11, f"configure node-ID {new}")
    if frame.data[1] != 0:
        raise Fail(f"node-ID {new} refused", expected="11 00 ..", seen=str(frame))
    ctx.cleanup(lambda: restore_node_id(ctx, new))
    lss(ctx, [0x04, WAITING])
    dev.link.flush()
    dev.nmt(NMT_RESET_COMM)
    boot = dev.wait_bootup(new)
    if boot is None:
        raise Fail(
            "no boot-up on the new node-ID after reset communication",
            expected=f"{0x700 + new:03X} [1] 00",
            seen="nothing",
        )
    # asked twice: a request right after the boot-up may reach a device still opening its
    # SDO channel on the new CAN-IDs (durand over SocketCAN: its receive filter follows the
    # boot-up by a few ms)
    for _ in range(2):
        dev.link.flush()
        dev.link.send(0x600 + new, b"\x40\x00\x10\x00\0\0\0\0")
        if dev.link.expect(0x580 + new, ctx.timing.response) is not None:
            break
    else:
        raise Fail(
            "no SDO answer on the new node-ID", expected=f"{0x580 + new:03X} ..", seen="nothing"
        )


@case(
    "lss",
    "fastscan",
    "fastscan finds the unconfigured device by its 0x1018 identity and it gets its node-ID back",
)
def fastscan(ctx: Context) -> None:
    require_lss(ctx)
    dev = ctx.device
    ident = identity(dev)
    switch(ctx, CONFIGURATION)
    frame = must(ctx, [0x11, 0xFF], 0x11, "configure node-ID 0xFF (unconfigured)")
    if frame.data[1] != 0:
        raise Skip("the device refuses node-ID 0xFF: it cannot become unconfigured")
    ctx.cleanup(lambda: restore_node_id(ctx, dev.node_id))
    lss(ctx, [0x04, WAITING])
    dev.nmt(NMT_RESET_COMM)
    time.sleep(0.05)
    # identify non-configured remote slave is optional (CiA 305): asked, not required
    lss(ctx, [0x4C], 0x50)
    if lss(ctx, struct.pack("<BIBBB", 0x51, 0, 0x80, 0, 0), 0x4F) is None:
        raise Skip(
            "no answer to a fastscan reset (bit check 0x80) from the unconfigured device:"
            " fastscan is an optional LSS service (CiA 305), not offered"
        )
    silent(
        ctx, struct.pack("<BIBBB", 0x51, ident[0] ^ 1, 0, 0, 1), "fastscan with a wrong vendor-ID"
    )
    for sub in range(4):
        nxt = (sub + 1) & 3
        must(
            ctx,
            struct.pack("<BIBBB", 0x51, ident[sub], 0, sub, nxt),
            0x4F,
            f"fastscan confirming 0x1018:{sub + 1}",
        )
    frame = must(ctx, [0x5E], 0x5E, "inquire node-ID after fastscan (configuration mode)")
    if frame.data[1] != 0xFF:
        raise Fail("inquire node-ID of an unconfigured device", expected="5E FF", seen=str(frame))
    must(ctx, [0x11, dev.node_id], 0x11, "configure node-ID back")
    dev.link.flush()
    lss(ctx, [0x04, WAITING])
    if dev.wait_bootup() is None:
        raise Fail(
            "no boot-up after configuring the node-ID of an unconfigured device and switching to waiting",
            expected=f"{0x700 + dev.node_id:03X} [1] 00",
            seen="nothing",
        )
