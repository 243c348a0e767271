"""The adapter's receive path: what happens to each frame the bus delivers, before the engine.

:func:`~.busrx.start_receiver` delivers the bus's frames (on the loop, or first to the
receive thread's quick step); :class:`ReceivePath` decides for each:

* error frames, 29-bit and CAN FD frames go to :meth:`ReceivePath.other`: the controller
  (:mod:`.controller`) reads error frames, the others are counted and dropped;
* a frame outside the engine's listen set (a widened filter, a frame queued before the
  set changed) is counted in ``rx_ignored`` and never reaches the engine;
* every other frame goes to the engine under the adapter's engine lock
  (:meth:`~.adapter.CanAdapter.engine_receive`), in the order received;
* quick answers (:meth:`ReceivePath.quick`): an engine with ``quick_answer(can_id, data,
  now)`` (the CANopen node: SDO reads) answers those on the receive thread, without waking
  the loop. The receive thread only *tries* the engine lock, only when every earlier frame
  has been handled; otherwise the frame goes to the loop. So the engine still sees one call
  at a time, in frame order.
* Receiving that has died (the receive thread ended on a driver exception, or the reader
  failed :data:`RX_ERRORS_FATAL` times within one state poll) fails the adapter
  (:meth:`ReceivePath.check`, from the adapter's state poll).
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import Counter
from typing import Any, Protocol, cast

import can

from . import socketcan_raw as raw
from .busrx import Receiver, start_receiver
from .frame import Frame

RX_ERRORS_FATAL = 100  # receive errors within one state poll that count as a dead bus

_new_frame = tuple.__new__  # Frame(...) without its Python-level __new__: two per SDO request


class QuickAnswering(Protocol):
    """An engine that can answer a read on the receive thread (optional; see :meth:`ReceivePath.quick`)."""

    def quick_answer(self, can_id: int, data: bytes | bytearray, now: float) -> Frame | None: ...


class ErrorFrames(Protocol):
    def error_frame(self, msg: can.Message) -> None: ...


class ReceiveHost(Protocol):
    """What the receive path uses of the adapter (:class:`~.adapter.CanAdapter` is one)."""

    node: Any  # the engine
    bus: can.BusABC
    loop: asyncio.AbstractEventLoop
    engine_lock: threading.RLock
    closed: bool
    switching: bool
    listen: frozenset[int] | None
    rx_frames: int
    rx_ignored: int
    quick_answers: int
    counters: Counter[str]

    @property
    def controller(self) -> ErrorFrames: ...

    def engine_receive(self, frame: Frame) -> None: ...
    def send_answer(self, answer: Frame, now: float) -> None: ...
    def arm(self, deadline: float | None = None, known: bool = False) -> None: ...
    def fail(self, exc: BaseException) -> None: ...


def to_frame(msg: can.Message) -> Frame:
    if msg.is_remote_frame:
        return Frame(msg.arbitration_id, b"", rtr=True, dlc=msg.dlc)
    return _new_frame(Frame, (msg.arbitration_id, bytes(msg.data), False, None))


class ReceivePath:
    def __init__(self, adapter: ReceiveHost):
        self.adapter = adapter
        self.receiver: Receiver | None = None
        self._rx_errors_seen = 0

    def start(self) -> None:
        adapter = self.adapter
        quick = self.quick if hasattr(adapter.node, "quick_answer") else None
        self.receiver = start_receiver(adapter.bus, adapter.loop, self.message, quick, self.raw)

    def stop(self) -> None:
        if self.receiver is not None:
            self.receiver.stop()
            self.receiver = None

    @property
    def dropped(self) -> object:
        """Frames the receiver lost before the loop saw them (an rx overrun)."""
        return getattr(self.receiver, "dropped", 0)

    def raw(self, word: int, dlc: int, data: bytes) -> None:
        """One frame read from SocketCAN's raw socket (the fast path of :meth:`message`)."""
        if word & raw.OTHER_FLAGS:
            self.message(raw.to_message(word, dlc, data))
            return
        adapter = self.adapter
        if adapter.closed:
            return
        with adapter.engine_lock:
            adapter.rx_frames += 1
            can_id = word & raw.CAN_SFF_MASK
            listen = adapter.listen
            if listen is not None and can_id not in listen:
                adapter.rx_ignored += 1
                return
            if word & raw.CAN_RTR_FLAG:
                frame = Frame(can_id, b"", rtr=True, dlc=dlc)
            else:
                frame = _new_frame(Frame, (can_id, data[:dlc], False, None))
            adapter.engine_receive(frame)

    def message(self, msg: can.Message) -> None:
        """One received message: the engine's answers go out before anything else happens."""
        adapter = self.adapter
        if adapter.closed:
            return
        with adapter.engine_lock:
            if msg.is_error_frame or msg.is_extended_id or msg.is_fd:
                self.other(msg)
                return
            adapter.rx_frames += 1
            listen = adapter.listen
            if listen is not None and msg.arbitration_id not in listen:
                adapter.rx_ignored += 1
                return
            adapter.engine_receive(to_frame(msg))

    def quick(self, msg: can.Message) -> bool:
        """On the receive thread: answer ``msg`` at once if the engine can (True), else False.

        Never blocks (the lock is only tried) and never raises (the receive thread would end).
        """
        if msg.is_remote_frame or msg.is_error_frame or msg.is_extended_id or msg.is_fd:
            return False
        adapter = self.adapter
        lock = adapter.engine_lock
        if not lock.acquire(False):
            return False
        try:
            if adapter.closed or adapter.switching:
                return False
            # the monotonic clock the loop's time is read from (never behind it, so a timer
            # due by the loop's clock is due here too); uvloop's time() is the loop thread's
            now = time.monotonic()
            try:
                answer = cast(QuickAnswering, adapter.node).quick_answer(
                    msg.arbitration_id, msg.data, now
                )
            except Exception:  # the loop's path handles (and logs) whatever went wrong here
                return False
            if answer is None:
                return False
            adapter.rx_frames += 1
            adapter.quick_answers += 1
            adapter.send_answer(answer, now)
            return True
        finally:
            lock.release()

    def other(self, msg: can.Message) -> None:
        """An error frame, a 29-bit or a CAN FD frame (the caller holds the engine lock)."""
        adapter = self.adapter
        if msg.is_error_frame:
            adapter.controller.error_frame(msg)
        elif msg.is_extended_id:
            adapter.counters["rx_extended_dropped"] += 1
        else:
            adapter.counters["rx_fd_dropped"] += 1
        adapter.arm()

    def check(self, period_s: float) -> None:
        """A dead receive thread, or a reader failing on every call (:data:`RX_ERRORS_FATAL`
        times since the last check, ``period_s`` ago), fails the adapter."""
        receiver = self.receiver
        exc = getattr(receiver, "exception", None)
        errors = getattr(receiver, "errors", 0)
        if (
            exc is None
            and isinstance(errors, int)
            and errors - self._rx_errors_seen >= RX_ERRORS_FATAL
        ):
            exc = can.CanOperationError(
                f"{errors - self._rx_errors_seen} receive errors in {period_s:g} s"
            )
        self._rx_errors_seen = errors if isinstance(errors, int) else 0
        if exc is not None:
            self.adapter.fail(exc)
