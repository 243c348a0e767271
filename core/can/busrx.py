"""Receive CAN messages on the event loop with as few thread hops as the bus allows.

``start_receiver(bus, loop, on_message, quick=None)`` calls ``on_message(msg)`` on the
event loop's thread for every message the bus receives, in order:

* buses with a file descriptor (SocketCAN): ``loop.add_reader``, reading until the socket
  is empty, without a thread; python-can's SocketCAN bus is read from its raw socket when
  :func:`.socketcan_raw.raw_socket` allows (one ``recv`` per frame), else with ``bus.recv``;
* every other interface (pcan, kvaser, ixxat, ... and python-can's ``virtual``): a
  receive thread blocked in ``bus.recv`` that hands messages to the loop in batches (one
  ``call_soon_threadsafe`` wakes the loop for everything queued until it runs); a driver
  exception ends it and is kept in :attr:`Receiver.exception` (the adapter fails the
  front, which restarts).

Apart from that feature-checked SocketCAN path only python-can's public API is used
(``recv``, ``fileno``), so python-can's filtering
(``set_filters``: in the kernel, the adapter's hardware or python-can's ``recv``) applies
on every path. (Up to python-can 4.6 the ``virtual`` bus was read by replacing its private
receive queue, which pinned python-can below 4.7 and bypassed its filtering.)

``quick(msg) -> bool``, given, runs on the receive thread first and returns True when it
has handled the message completely (the CANopen front answers SDO reads there, see
:meth:`fieldgate.plugins.canopen.cia301.node.Node.quick_answer`). It is asked only when every
message handed to the loop before has been handled (:attr:`Receiver.idle`), so the
answers keep the order of the requests; anything it declines goes to the loop.

A receive thread costs one extra thread wake-up per batch of frames that goes to the
loop; an SDO read answered on it costs none, like canopen's LocalNode
(bench/canopen_sdo.py).
"""

from __future__ import annotations

import asyncio
import logging
import socket
import sys
import threading
from collections import deque
from collections.abc import Callable

import can

from .socketcan_raw import FRAME, raw_socket

log = logging.getLogger("fieldgate.can.busrx")

OnMessage = Callable[[can.Message], None]
OnRaw = Callable[[int, int, bytes], None]  # (can_id | CAN_*_FLAGs, dlc, 8 data bytes)
RAW_BATCH = 256  # frames read per wake-up at most on the raw path
Quick = Callable[[can.Message], bool]
RECV_TIMEOUT_S = 0.1  # how often the receive thread looks at whether it should stop
HANDOVER_LIMIT = 10_000  # frames waiting for the loop; more are dropped (an rx overrun)
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)  # Linux: frames the socket buffer dropped
# room for the drop counter (u32) beside the timestamp python-can asks for (SO_TIMESTAMPNS)
ANCILLARY = (
    socket.CMSG_SPACE(4) + socket.CMSG_SPACE(16) + 32 if hasattr(socket, "CMSG_SPACE") else 0
)


class Receiver:
    """A running receive path; :meth:`stop` before shutting the bus down.

    ``dropped`` counts frames lost before the loop saw them (the gateway's own receive
    queue overran): the receive thread's hand-over queue full (:data:`HANDOVER_LIMIT`, the
    loop far behind), or SocketCAN's socket buffer full (the kernel's ``SO_RXQ_OVFL``
    count). The adapter reports a rise as an rx overrun.
    """

    mode = "thread"
    handed_over = 0  # messages handed to the loop, counted by the receiving thread only
    handled = 0  # ... and handled there, counted by the loop only
    dropped = 0

    def __init__(
        self,
        bus: can.BusABC,
        loop: asyncio.AbstractEventLoop,
        on_message: OnMessage,
        quick: Quick | None = None,
    ):
        self.bus, self.loop, self.on_message, self.quick = bus, loop, on_message, quick
        self.active = True
        self._queue: deque[can.Message] = deque()  # handed over, not yet handled
        self._scheduled = False  # a _deliver_queued is on its way to the loop
        self.exception: BaseException | None = (
            None  # what ended the receive thread, if anything did
        )
        self._thread = threading.Thread(
            target=self._receive_thread, name=f"can-rx {bus.channel_info}", daemon=True
        )
        self._thread.start()

    def _receive_thread(self) -> None:
        recv, handle = self.bus.recv, self._from_thread
        try:
            while self.active:
                msg = recv(RECV_TIMEOUT_S)
                if msg is not None:
                    handle(msg)
        except (
            Exception
        ) as exc:  # a failing driver ends the thread; the adapter's state poll reports it
            if self.active:
                self.exception = exc
                log.error("CAN receive thread ended: %s", exc)

    @property
    def idle(self) -> bool:
        """Every message handed to the loop has been handled."""
        return self.handed_over == self.handled

    def _from_thread(self, msg: can.Message) -> None:
        if not self.active:
            return
        quick = self.quick
        if quick is not None and self.idle and quick(msg):
            return
        if self.handed_over - self.handled >= HANDOVER_LIMIT:
            self.dropped += 1  # the loop is that far behind: an overrun, not unbounded memory
            return
        self.handed_over += 1
        self._queue.append(msg)  # before the flag is read: the loop clears it before draining
        if not self._scheduled:
            self._scheduled = True
            try:
                self.loop.call_soon_threadsafe(self._deliver_queued)
            except RuntimeError:  # loop closed during shutdown
                pass

    def _deliver_queued(self) -> None:
        """On the loop: everything the thread queued so far, in order."""
        self._scheduled = False
        queue = self._queue
        while queue:
            msg = queue.popleft()
            try:
                if self.active:
                    self.on_message(msg)
            except Exception as exc:  # reported as the loop reports a failing callback
                self.loop.call_exception_handler(
                    {"message": f"CAN message {msg} not handled", "exception": exc}
                )
            finally:
                self.handled += 1

    def stop(self) -> None:
        self.active = False
        if self._thread is not threading.current_thread():
            self._thread.join(5 * RECV_TIMEOUT_S)


class ReaderReceiver(Receiver):
    mode = "add-reader"

    def __init__(
        self, bus: can.BusABC, loop: asyncio.AbstractEventLoop, on_message: OnMessage, fd: int
    ):
        self.bus, self.loop, self.on_message = bus, loop, on_message
        self.active = True
        self.errors = 0
        self._fd = fd
        loop.add_reader(fd, self._readable)

    def _readable(self) -> None:
        while self.active:
            try:
                msg = self.bus.recv(0)
            except (can.CanError, OSError) as exc:
                self._receive_failed(exc)
                return
            if msg is None:
                return
            self.on_message(msg)

    def _receive_failed(self, exc: BaseException) -> None:
        """Count and log (the first, then every 1000th) a failed read; watch the socket again."""
        self.errors += 1
        if self.errors == 1 or self.errors % 1000 == 0:
            log.warning("CAN receive failed (%d so far): %s", self.errors, exc)
        self._watch_again()

    def _watch_again(self) -> None:
        """Register the socket again after a receive error (ENETDOWN: the interface went down).

        uvloop (libuv) stops watching a descriptor that reported an error, so the front
        would stay deaf once the interface is up again; asyncio's loop keeps watching.
        Registering again gives both the same behaviour: frames are heard as soon as the
        interface is back, and a socket that keeps failing keeps being counted.
        """
        if self.active:
            self.loop.remove_reader(self._fd)
            self.loop.add_reader(self._fd, self._readable)

    def stop(self) -> None:
        self.active = False
        self.loop.remove_reader(self._fd)


class RawSocketReceiver(ReaderReceiver):
    """SocketCAN read from its raw socket on the loop (:mod:`.socketcan_raw`): one ``recv``
    per frame, up to :data:`RAW_BATCH` frames per wake-up (the loop's timers run between)."""

    mode = "socketcan-raw"

    def __init__(
        self,
        bus: can.BusABC,
        loop: asyncio.AbstractEventLoop,
        on_raw: OnRaw,
        sock: socket.socket,
    ):
        self.on_raw = on_raw
        self._sock = sock
        try:  # the kernel then tells, with each frame, how many the socket buffer dropped
            sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            self._counts_drops = True
        except OSError:
            self._counts_drops = False
        super().__init__(bus, loop, lambda msg: None, sock.fileno())

    def _drop_count(self) -> None:
        """The first frame of a wake-up read with ``recvmsg``: its ancillary data carries the
        socket's drop counter as it was when the frame was queued (one ``recvmsg`` per wake-up,
        not per frame; frames dropped while the loop was away show on the first frame queued
        after them, at a later wake-up)."""
        try:
            raw, ancillary, _, _ = self._sock.recvmsg(FRAME.size, ANCILLARY, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return
        for level, kind, value in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(value) >= 4:
                self.dropped = int.from_bytes(value[:4], sys.byteorder)
        if len(raw) == FRAME.size:
            self.on_raw(*FRAME.unpack(raw))

    def _readable(self) -> None:
        recv, unpack, on_raw = self._sock.recv, FRAME.unpack, self.on_raw
        if self._counts_drops and self.active:
            try:
                self._drop_count()
            except OSError as exc:
                self._receive_failed(exc)
                return
        for _ in range(RAW_BATCH):
            if not self.active:
                return
            try:
                raw = recv(FRAME.size, socket.MSG_DONTWAIT)
            except BlockingIOError:
                return
            except OSError as exc:
                self._receive_failed(exc)
                return
            if len(raw) == FRAME.size:
                word, dlc, data = unpack(raw)
                on_raw(word, dlc, data)


def _fileno(bus: can.BusABC) -> int | None:
    try:
        fd = bus.fileno()
    except (NotImplementedError, AttributeError, OSError, ValueError):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


def start_receiver(
    bus: can.BusABC,
    loop: asyncio.AbstractEventLoop,
    on_message: OnMessage,
    quick: Quick | None = None,
    on_raw: OnRaw | None = None,
) -> Receiver:
    """Deliver the bus's messages to ``on_message`` on ``loop`` (call from the loop's thread);
    to ``on_raw(can_id_and_flags, dlc, data8)`` instead where the bus is SocketCAN's raw
    socket and ``on_raw`` is given (:mod:`.socketcan_raw`)."""
    sock = raw_socket(bus) if on_raw is not None else None
    if sock is not None and on_raw is not None:
        return RawSocketReceiver(bus, loop, on_raw, sock)
    fd = _fileno(bus)
    if fd is not None:
        return ReaderReceiver(bus, loop, on_message, fd)
    return Receiver(bus, loop, on_message, quick)
