"""SocketCAN's raw socket under a python-can bus: the fast path of :mod:`.busrx` and
:mod:`.adapter`, behind a feature check, with python-can's public API as the fallback.

Inside User-Mode Linux (and on small ARM gateways) every system call and every Python call
on the per-frame path counts. python-can's ``SocketcanBus.recv(0)`` costs a ``select`` and
a ``recvmsg`` per frame plus a ``can.Message``; its ``send`` a ``select``, a ``send``, two
logger look-ups and a generator per frame. Read directly, a frame is one ``recv`` and one
``struct`` unpack (and the empty socket one more ``recv``); sent directly, one ``pack`` and
one ``send`` (docs/canopen-bench.md, "Where the time goes on SocketCAN").

:func:`raw_socket` returns the bus's ``AF_CAN``/``CAN_RAW`` socket only for what this path
handles exactly like python-can: python-can's ``socketcan`` bus (its ``socket`` attribute),
classic CAN (no FD frames: ``bus.protocol`` is ``CAN_20``), bound to one interface. Anything
else (another python-can version that keeps the socket elsewhere, CAN FD, another
interface) gets None and uses ``bus.recv`` / ``bus.send``. Filters are python-can's
(``bus.set_filters`` sets ``CAN_RAW_FILTER`` on this socket), so both paths see the same
frames; the adapter's exact listen-set check covers a kernel that refused the filters.
"""

from __future__ import annotations

import socket
import struct

import can

FRAME = struct.Struct("=IB3x8s")  # struct can_frame: can_id + flags, len, pad, data[8]
CAN_EFF_FLAG = 0x8000_0000
CAN_RTR_FLAG = 0x4000_0000
CAN_ERR_FLAG = 0x2000_0000
CAN_SFF_MASK = 0x7FF
CAN_EFF_MASK = 0x1FFF_FFFF
OTHER_FLAGS = CAN_EFF_FLAG | CAN_ERR_FLAG  # frames the adapter hands to python-can's form
ENABLED = True  # tests switch the fast path off to run the public one over SocketCAN
RX_BUFFER_BYTES = 2 * 1024 * 1024  # asked for; the kernel doubles it (bookkeeping) and caps it
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)  # Linux: beyond rmem_max, CAP_NET_ADMIN


def raw_socket(bus: can.BusABC) -> socket.socket | None:
    """The bus's raw CAN socket when the fast path applies (see the module notes), else None."""
    family = getattr(socket, "AF_CAN", None)
    if not ENABLED or family is None:
        return None
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return None
    try:
        if sock.family != family or sock.type != socket.SOCK_RAW or sock.fileno() < 0:
            return None
    except OSError:
        return None
    if getattr(bus, "protocol", None) is not can.CanProtocol.CAN_20:
        return None
    channel = getattr(bus, "channel", None)
    if not isinstance(channel, str) or not channel:
        return None
    return sock


def enlarge_receive_buffer(sock: socket.socket, size: int = RX_BUFFER_BYTES) -> int:
    """Give the socket room for bursts: the frames that arrive while the process is not
    scheduled (another process busy, a slow back, a GC pause) wait in this buffer, and the
    kernel drops what does not fit. The default (net.core.rmem_default, 208 KiB) holds
    about 250 frames: a quarter of a second at 1 kHz SYNC + RPDO. SO_RCVBUFFORCE goes
    beyond net.core.rmem_max where the process may (root, CAP_NET_ADMIN); SO_RCVBUF is
    capped by it otherwise. Returns the buffer's size in bytes as the kernel reports it."""
    current = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    if current < 2 * size:
        for option in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, option, size)
                break
            except OSError:
                continue
    return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))


def to_message(word: int, dlc: int, data: bytes) -> can.Message:
    """python-can's form of a raw frame the adapter does not take itself (error, 29-bit)."""
    if word & CAN_ERR_FLAG:
        return can.Message(
            arbitration_id=word & CAN_EFF_MASK, is_error_frame=True, dlc=dlc, data=data[:dlc]
        )
    return can.Message(
        arbitration_id=word & CAN_EFF_MASK,
        is_extended_id=True,
        is_remote_frame=bool(word & CAN_RTR_FLAG),
        dlc=dlc,
        data=None if word & CAN_RTR_FLAG else data[:dlc],
    )
