"""The few rtnetlink messages that read and configure a SocketCAN interface.

Linux configures a CAN controller over rtnetlink (``RTM_NEWLINK`` with the ``can`` link
kind's attributes, the uapi of ``linux/can/netlink.h``); ``ip link set canX type can ...``
is one client of it, this module another. It encodes the requests and decodes the answers
without I/O (:func:`get_link_request`, :func:`set_link_request`, :func:`decode_link`,
:func:`decode_ack`: tested on the host with built bytes), and :class:`RouteSocket` sends them.

Why our own and not pyroute2 or ``ip -json``: docs/can-link.md ("Choosing the netlink
client") has the measured comparison.
"""

from __future__ import annotations

import errno
import os
import socket
import struct
from dataclasses import dataclass, field

NETLINK_ROUTE = 0
RTM_NEWLINK, RTM_GETLINK = 16, 18
NLMSG_ERROR, NLMSG_DONE = 2, 3
NLM_F_REQUEST, NLM_F_ACK = 0x1, 0x4
IFF_UP = 0x1
AF_UNSPEC = 0
IFLA_IFNAME, IFLA_LINKINFO = 3, 18
IFLA_INFO_KIND, IFLA_INFO_DATA, IFLA_INFO_XSTATS = 1, 2, 3
NLA_F_NESTED = 0x8000
NLA_TYPE_MASK = 0x3FFF
# linux/can/netlink.h
IFLA_CAN_BITTIMING = 1
IFLA_CAN_BITTIMING_CONST = 2
IFLA_CAN_CLOCK = 3
IFLA_CAN_STATE = 4
IFLA_CAN_CTRLMODE = 5
IFLA_CAN_RESTART_MS = 6
IFLA_CAN_RESTART = 7
IFLA_CAN_BERR_COUNTER = 8
IFLA_CAN_BITRATE_CONST = 13
IFLA_CAN_CTRLMODE_EXT = 17  # nested: IFLA_CAN_CTRLMODE_SUPPORTED (1), since Linux 5.18
IFLA_CAN_CTRLMODE_SUPPORTED = 1
CAN_CTRLMODE_LISTENONLY = 0x02
CAN_STATES = (
    "error-active",
    "error-warning",
    "error-passive",
    "bus-off",
    "stopped",
    "sleeping",
)

NLMSGHDR = struct.Struct("=IHHII")  # length, type, flags, sequence, port id
IFINFOMSG = struct.Struct("=BxHiII")  # family, pad, device type, index, flags, change mask
NLATTR = struct.Struct("=HH")  # length, type
BITTIMING = struct.Struct("=8I")  # bitrate, sample point (per mille), tq, prop, ph1, ph2, sjw, brp
CTRLMODE = struct.Struct("=II")  # mask, flags
BERR = struct.Struct("=HH")  # tx errors, rx errors
CAN_DEVICE_STATS = struct.Struct("=6I")  # bus_error, warning, passive, bus_off, arb lost, restarts


def _align(n: int) -> int:
    return (n + 3) & ~3


def attr(kind: int, payload: bytes) -> bytes:
    """One netlink attribute, padded to four bytes."""
    length = NLATTR.size + len(payload)
    return NLATTR.pack(length, kind) + payload + b"\0" * (_align(length) - length)


def attrs(data: bytes) -> dict[int, bytes]:
    """The attributes of a buffer by type (the last one wins, as in the kernel)."""
    out: dict[int, bytes] = {}
    offset = 0
    while offset + NLATTR.size <= len(data):
        length, kind = NLATTR.unpack_from(data, offset)
        if length < NLATTR.size or offset + length > len(data):
            break
        out[kind & NLA_TYPE_MASK] = data[offset + NLATTR.size : offset + length]
        offset += _align(length)
    return out


def message(kind: int, flags: int, sequence: int, body: bytes) -> bytes:
    return NLMSGHDR.pack(NLMSGHDR.size + len(body), kind, flags, sequence, 0) + body


def get_link_request(name: str, sequence: int) -> bytes:
    body = IFINFOMSG.pack(AF_UNSPEC, 0, 0, 0, 0) + attr(IFLA_IFNAME, name.encode() + b"\0")
    return message(RTM_GETLINK, NLM_F_REQUEST, sequence, body)


@dataclass(frozen=True)
class LinkChange:
    """What one ``RTM_NEWLINK`` asks of a CAN interface (None: leave as it is)."""

    bitrate: int | None = None
    sample_point: float | None = None  # 0.875; None: the kernel's default for the rate
    restart_ms: int | None = None
    listen_only: bool | None = None
    restart: bool = False
    up: bool | None = None

    def can_data(self) -> bytes:
        data = b""
        if self.bitrate is not None:
            per_mille = round((self.sample_point or 0) * 1000)
            data += attr(
                IFLA_CAN_BITTIMING, BITTIMING.pack(self.bitrate, per_mille, 0, 0, 0, 0, 0, 0)
            )
        if self.listen_only is not None:
            flags = CAN_CTRLMODE_LISTENONLY if self.listen_only else 0
            data += attr(IFLA_CAN_CTRLMODE, CTRLMODE.pack(CAN_CTRLMODE_LISTENONLY, flags))
        if self.restart_ms is not None:
            data += attr(IFLA_CAN_RESTART_MS, struct.pack("=I", self.restart_ms))
        if self.restart:
            data += attr(IFLA_CAN_RESTART, struct.pack("=I", 1))  # the kernel wants a u32
        return data


def set_link_request(index: int, change: LinkChange, sequence: int) -> bytes:
    flags = change_mask = 0
    if change.up is not None:
        flags, change_mask = (IFF_UP if change.up else 0), IFF_UP
    body = IFINFOMSG.pack(AF_UNSPEC, 0, index, flags, change_mask)
    data = change.can_data()
    if data:
        info = attr(IFLA_INFO_KIND, b"can\0") + attr(IFLA_INFO_DATA | NLA_F_NESTED, data)
        body += attr(IFLA_LINKINFO | NLA_F_NESTED, info)
    return message(RTM_NEWLINK, NLM_F_REQUEST | NLM_F_ACK, sequence, body)


@dataclass(frozen=True)
class RawLink:
    """A CAN interface as rtnetlink describes it (None: the driver does not report it)."""

    name: str
    index: int
    up: bool
    kind: str  # "can" (a controller's driver), "vcan", "vxcan", ... ("" when none)
    bitrate: int | None = None
    sample_point: float | None = None
    clock_hz: int | None = None
    state: str | None = None
    listen_only: bool | None = None
    listen_only_supported: bool | None = None
    restart_ms: int | None = None
    tx_errors: int | None = None
    rx_errors: int | None = None
    bitrate_const: tuple[int, ...] = ()
    timing_const: str | None = None  # the controller's name in its bit-timing limits
    counters: dict[str, int] = field(default_factory=dict)  # the driver's can_device_stats


def decode_link(payload: bytes, name: str = "") -> RawLink:
    """An ``RTM_NEWLINK`` answer's body (after the netlink header)."""
    _family, _type, index, flags, _change = IFINFOMSG.unpack_from(payload)
    top = attrs(payload[IFINFOMSG.size :])
    name = top.get(IFLA_IFNAME, name.encode()).rstrip(b"\0").decode()
    info = attrs(top.get(IFLA_LINKINFO, b""))
    kind = info.get(IFLA_INFO_KIND, b"").rstrip(b"\0").decode()
    can = attrs(info.get(IFLA_INFO_DATA, b""))
    fields: dict[str, object] = {}
    if IFLA_CAN_BITTIMING in can:
        bitrate, per_mille, *_ = BITTIMING.unpack_from(can[IFLA_CAN_BITTIMING])
        fields["bitrate"] = bitrate
        fields["sample_point"] = per_mille / 1000 if per_mille else None
    elif kind == "can":
        fields["bitrate"] = 0  # a controller not configured yet
    if IFLA_CAN_CLOCK in can:
        fields["clock_hz"] = struct.unpack_from("=I", can[IFLA_CAN_CLOCK])[0]
    if IFLA_CAN_STATE in can:
        number = struct.unpack_from("=I", can[IFLA_CAN_STATE])[0]
        fields["state"] = CAN_STATES[number] if number < len(CAN_STATES) else f"state {number}"
    if IFLA_CAN_CTRLMODE in can:
        _mask, modes = CTRLMODE.unpack_from(can[IFLA_CAN_CTRLMODE])
        fields["listen_only"] = bool(modes & CAN_CTRLMODE_LISTENONLY)
    supported = attrs(can.get(IFLA_CAN_CTRLMODE_EXT, b"")).get(IFLA_CAN_CTRLMODE_SUPPORTED)
    if supported is not None:
        modes_supported = struct.unpack_from("=I", supported)[0]
        fields["listen_only_supported"] = bool(modes_supported & CAN_CTRLMODE_LISTENONLY)
    if IFLA_CAN_RESTART_MS in can:
        fields["restart_ms"] = struct.unpack_from("=I", can[IFLA_CAN_RESTART_MS])[0]
    if IFLA_CAN_BERR_COUNTER in can:
        fields["tx_errors"], fields["rx_errors"] = BERR.unpack_from(can[IFLA_CAN_BERR_COUNTER])
    if IFLA_CAN_BITRATE_CONST in can:
        raw = can[IFLA_CAN_BITRATE_CONST]
        fields["bitrate_const"] = struct.unpack_from(f"={len(raw) // 4}I", raw)
    if IFLA_CAN_BITTIMING_CONST in can:
        fields["timing_const"] = can[IFLA_CAN_BITTIMING_CONST][:16].split(b"\0")[0].decode()
    stats = info.get(IFLA_INFO_XSTATS, b"")
    if kind == "can" and len(stats) >= CAN_DEVICE_STATS.size:
        names = (
            "bus_errors",
            "error_warning",
            "error_passive",
            "bus_off",
            "arbitration_lost",
            "restarts",
        )
        fields["counters"] = dict(zip(names, CAN_DEVICE_STATS.unpack_from(stats), strict=True))
    return RawLink(name, index, bool(flags & IFF_UP), kind, **fields)  # type: ignore[arg-type]


def decode_ack(data: bytes, sequence: int) -> tuple[int, bytes | None]:
    """(errno, a link's body or None) from one answer datagram: errno 0 is success."""
    offset = 0
    body: bytes | None = None
    while offset + NLMSGHDR.size <= len(data):
        length, kind, _flags, seq, _port = NLMSGHDR.unpack_from(data, offset)
        if length < NLMSGHDR.size:
            break
        payload = data[offset + NLMSGHDR.size : offset + length]
        if seq == sequence:
            if kind == NLMSG_ERROR:
                return -struct.unpack_from("=i", payload)[0], body
            if kind == RTM_NEWLINK:
                body = payload
            if kind == NLMSG_DONE:
                return 0, body
        offset += _align(length)
    return (0, body) if body is not None else (-1, None)


class NetlinkError(OSError):
    """The kernel refused a request (``errno`` is set)."""


class RouteSocket:
    """A blocking ``NETLINK_ROUTE`` socket: one request, its answer (a few hundred
    microseconds; the kernel answers at once, except that bringing some drivers up waits
    for the device, e.g. slcan for its serial adapter, up to a second)."""

    def __init__(self, timeout_s: float = 5.0) -> None:
        self.sock = socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, NETLINK_ROUTE)
        self.sock.settimeout(timeout_s)
        self.sock.bind((0, 0))
        self.sequence = 0

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> RouteSocket:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _ask(self, build: object) -> bytes | None:
        self.sequence += 1
        assert callable(build)
        self.sock.send(build(self.sequence))
        while True:
            code, body = decode_ack(self.sock.recv(65536), self.sequence)
            if code == -1:  # an answer to an older request, or nothing we know: read on
                continue
            if code:
                raise NetlinkError(code, os.strerror(code))
            return body

    def get(self, name: str) -> RawLink:
        body = self._ask(lambda seq: get_link_request(name, seq))
        if body is None:
            raise NetlinkError(errno.ENODEV, os.strerror(errno.ENODEV))
        return decode_link(body, name)

    def set(self, index: int, change: LinkChange) -> None:
        self._ask(lambda seq: set_link_request(index, change, seq))
