"""Receive CAN messages on the event loop with as few thread hops as the bus allows.

``start_receiver(bus, loop, on_message, quick=None)`` calls ``on_message(msg)`` on the
event loop's thread for every message the bus receives, in order:

* buses with a file descriptor (SocketCAN): ``loop.add_reader``, reading until the socket
  is empty, without a thread;
* every other interface (pcan, kvaser, ixxat, ... and python-can's ``virtual`` when a
  ``quick`` answerer is given): a receive thread blocked in ``bus.recv`` that hops to
  the loop (``call_soon_threadsafe``); a driver exception ends it and is kept in
  :attr:`Receiver.exception` (the adapter fails the front, which restarts);
* python-can's in-process ``virtual`` bus without ``quick``: the sender's thread hands
  each message straight to the loop (``call_soon_threadsafe``) through a stand-in for the
  bus's receive queue, so no receive thread sits in between (python-can 4.6 keeps one
  ``queue.Queue`` per bus in the channel's list and ``send`` calls ``put`` on each; the
  stand-in has ``put``).

``quick(msg) -> bool``, given, runs on the receive thread first and returns True when it
has handled the message completely (the CANopen front answers SDO reads there, see
:meth:`fieldgate.plugins.canopen.node.Node.quick_answer`). It is asked only when every
message handed to the loop before has been handled (:attr:`Receiver.idle`), so the
answers keep the order of the requests; anything it declines goes to the loop.

A receive thread costs one extra thread wake-up per frame that goes to the loop; an SDO
read answered on it costs none, like canopen's LocalNode (bench/canopen_sdo.py).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable

import can
from can.interfaces import virtual

log = logging.getLogger("fieldgate.can.busrx")

OnMessage = Callable[[can.Message], None]
Quick = Callable[[can.Message], bool]
RECV_TIMEOUT_S = 0.1  # how often the receive thread looks at whether it should stop


class Receiver:
    """A running receive path; :meth:`stop` before shutting the bus down."""

    mode = "thread"
    handed_over = 0  # messages handed to the loop, counted by the receiving thread only
    handled = 0  # ... and handled there, counted by the loop only

    def __init__(
        self,
        bus: can.BusABC,
        loop: asyncio.AbstractEventLoop,
        on_message: OnMessage,
        quick: Quick | None = None,
    ):
        self.bus, self.loop, self.on_message, self.quick = bus, loop, on_message, quick
        self.active = True
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
        self.handed_over += 1
        try:
            self.loop.call_soon_threadsafe(self._deliver, msg)
        except RuntimeError:  # loop closed during shutdown
            pass

    def _deliver(self, msg: can.Message) -> None:
        try:
            if self.active:
                self.on_message(msg)
        finally:
            self.handled += 1

    def stop(self) -> None:
        self.active = False
        if self._thread is not threading.current_thread():
            self._thread.join(5 * RECV_TIMEOUT_S)


class _LoopQueue:
    """Stands in for a virtual bus's receive queue: ``put`` delivers on the loop."""

    def __init__(self, receiver: VirtualReceiver):
        self.receiver = receiver

    def put(self, msg: can.Message, block: bool = True, timeout: float | None = None) -> None:
        receiver = self.receiver
        if receiver.active:
            try:
                receiver.loop.call_soon_threadsafe(receiver._deliver, msg)
            except RuntimeError:  # loop closed during shutdown
                pass

    def get(self, block: bool = True, timeout: float | None = None):
        raise can.CanOperationError(
            "this virtual bus delivers to the event loop; recv() is not available"
        )


class VirtualReceiver(Receiver):
    mode = "virtual-push"

    def __init__(
        self, bus: virtual.VirtualBus, loop: asyncio.AbstractEventLoop, on_message: OnMessage
    ):
        self.bus, self.loop, self.on_message = bus, loop, on_message
        self.active = True
        stand_in = _LoopQueue(self)
        with virtual.channels_lock:
            queues = bus.channel
            position = next(i for i, q in enumerate(queues) if q is bus.queue)
            pending = []
            while not bus.queue.empty():  # anything received before we took over
                pending.append(bus.queue.get_nowait())
            queues[position] = stand_in
            bus.queue = stand_in  # VirtualBus.shutdown() removes bus.queue from the channel
        for msg in pending:
            loop.call_soon_threadsafe(self._deliver, msg)

    def stop(self) -> None:
        self.active = False


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
                self.errors += 1
                if self.errors == 1 or self.errors % 1000 == 0:
                    log.warning("CAN receive failed (%d so far): %s", self.errors, exc)
                self._watch_again()
                return
            if msg is None:
                return
            self.on_message(msg)

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


def _usable_virtual(bus: can.BusABC) -> bool:
    return (
        isinstance(bus, virtual.VirtualBus)
        and isinstance(getattr(bus, "channel", None), list)
        and any(q is getattr(bus, "queue", None) for q in bus.channel)
    )


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
) -> Receiver:
    """Deliver the bus's messages to ``on_message`` on ``loop`` (call from the loop's thread)."""
    fd = _fileno(bus)
    if fd is not None:
        return ReaderReceiver(bus, loop, on_message, fd)
    if quick is None and _usable_virtual(bus):
        return VirtualReceiver(bus, loop, on_message)
    return Receiver(bus, loop, on_message, quick)
