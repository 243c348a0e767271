"""Binds a sans-I/O CAN engine (the CANopen ``Node``, the DeviceNet engine) to a python-can bus and the asyncio clock.

The adapter is the engine binding and its timers; the receive path (what happens to each
received frame, quick answers on the receive thread) is :mod:`.receive`'s, the CAN
controller (bus-off, error state, overruns, bit-rate switch) :mod:`.controller`'s. A
front drives it through :class:`~.front.CanFront`.

* Any python-can interface works: ``interface``, ``channel``, ``bitrate`` and extra
  options go to ``can.Bus`` unchanged (socketcan, virtual, pcan, kvaser, slcan, ...).
* Received messages reach the node on the event loop through
  :func:`~.busrx.start_receiver`: ``add_reader`` on SocketCAN (no thread), a
  receive thread hopping with ``loop.call_soon_threadsafe`` on other interfaces (and on
  the virtual bus when the engine answers quickly, below), pushed straight from the
  sender on the virtual bus otherwise.
* Quick answers (an engine with ``quick_answer``: SDO reads answered on the receive
  thread) and what reaches the engine: :mod:`.receive`. Everything the loop does with the
  engine (frames, timers, ``pump``, ``tick``, bus-state changes) holds
  :attr:`CanAdapter.engine_lock`; closing and reopening the bus (bit-rate switch) stop
  quick answers under the lock first.
* Timers: after every call into the node, one ``loop.call_at`` is armed for the node's
  next deadline. ``now`` is ``loop.time()`` (monotonic seconds); the receive thread reads
  ``time.monotonic()``, the same clock, never behind the loop's.
* Bus-off, the controller's error state and overruns: :mod:`.controller`. Send failures
  are counted, never raised.
* Receiving that has died fails :attr:`CanAdapter.failed` (:mod:`.receive`); the front's
  ``run()`` raises and the runtime restarts the front with back-off.
* SocketCAN: python-can's bus is opened, filtered and closed as usual, but frames are read
  from and written to its raw socket directly where :mod:`.socketcan_raw` allows (one
  system call per frame instead of two, no ``can.Message``), with a receive buffer for
  about 2,500 frames (``rx_buffer_bytes`` in the status) so a burst that arrives while the
  process is not scheduled waits instead of being dropped; elsewhere ``bus.recv`` and
  ``bus.send``.
* Remote frames keep their DLC; 29-bit frames are counted and dropped (the node uses
  11-bit identifiers only).
* Acceptance filters: an engine with ``listen_ids()`` (the CAN-IDs it takes frames on, as
  configured now, or None for every frame; the same object while unchanged) gets them as
  the bus's filters (:mod:`.filters`: merged into a few ``(id, mask)`` pairs, then
  ``bus.set_filters``: ``CAN_RAW_FILTER`` on SocketCAN, hardware or python-can's own
  filtering elsewhere). They are checked after every call into the engine and re-applied
  before that call's frames are sent, so a new COB-ID is heard before the answer that
  confirms it leaves. A frame that still arrives outside the set (a widened filter, a frame
  queued before the change) is counted in ``rx_ignored`` and never reaches the engine.
  SocketCAN error frames have their own subscription (``CAN_RAW_ERR_FILTER``) and stay on.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import threading
from collections import Counter
from collections.abc import Callable
from typing import Any, Protocol

import can

from fieldgate.plugin import PluginStartError

from . import filters as acceptance
from . import socketcan_raw as raw
from .controller import Controller
from .frame import Frame
from .interface import InterfaceControl
from .receive import RX_ERRORS_FATAL, ReceivePath, to_frame

log = logging.getLogger("fieldgate.can.adapter")

__all__ = ["RX_ERRORS_FATAL", "CanAdapter", "CanEngine", "open_bus", "to_frame", "to_message"]


class CanEngine(Protocol):
    """What the adapter needs of a sans-I/O engine: frames and times in, frames out."""

    @property
    def deadline_after_call(self) -> float | None:
        """``next_deadline()`` as of the end of the last receive(), tick() or flush()."""

    def boot(self, now: float) -> list[Frame]: ...
    def receive(self, frame: Frame, now: float) -> list[Frame]: ...
    def tick(self, now: float) -> list[Frame]: ...
    def flush(self) -> list[Frame]: ...
    def next_deadline(self) -> float | None: ...
    def on_bit_timing(self, callback: Callable[..., Any]) -> None: ...


ENOBUFS = 105
STATE_POLL_S = 1.0


def open_bus(
    interface: str, channel: str | None, bitrate: int | None, options: dict[str, Any] | None = None
) -> can.BusABC:
    """``can.Bus(...)`` with a one-line :class:`PluginStartError` on failure."""
    kwargs = dict(options or {})
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    if interface not in can.VALID_INTERFACES:
        raise PluginStartError(
            f"unknown CAN interface {interface!r} (python-can knows: {', '.join(sorted(can.VALID_INTERFACES))})"
        )
    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except can.CanInterfaceNotImplementedError as exc:
        raise PluginStartError(
            f"CAN interface {interface!r} not available here: {_one_line(exc)}"
        ) from None
    except (can.CanError, OSError, ValueError, TypeError, ImportError) as exc:
        raise PluginStartError(
            f"cannot open CAN {interface} channel {channel!r}: {_one_line(exc)}"
        ) from None


def _no_buffer_space(exc: BaseException) -> bool:
    """A send refused because the driver's transmit queue is full (ENOBUFS)."""
    code = getattr(exc, "errno", None) or getattr(exc, "error_code", None)
    return code == ENOBUFS or "No buffer space" in str(exc)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def to_message(frame: Frame) -> can.Message:
    if frame.rtr:
        return can.Message(
            arbitration_id=frame.can_id,
            is_extended_id=False,
            is_remote_frame=True,
            dlc=frame.length,
        )
    data = frame.data
    # Positional (timestamp, arbitration_id, is_extended_id, is_remote_frame, is_error_frame,
    # channel, dlc, data): two thirds of the keyword call's time on every frame sent.
    # tests/canopen/test_canopen_adapter.py checks it against the keyword form.
    return can.Message(0.0, frame.can_id, False, False, False, None, len(data), data)


_pack = raw.FRAME.pack


class CanAdapter:
    def __init__(
        self,
        node: CanEngine,
        bus: can.BusABC,
        loop: asyncio.AbstractEventLoop,
        *,
        on_bus_state: Callable[[bool, float], None] | None = None,
        transmit_allowed: Callable[[float], bool] | None = None,
        reopen: Callable[[int], can.BusABC] | None = None,
        on_controller: Callable[[str, float], None] | None = None,
        interface: InterfaceControl | None = None,
        bus_off_restart: Callable[[], float | None] | None = None,
        on_link: Callable[[str | None, float], None] | None = None,
    ):
        self.node = node
        self.bus = bus
        self.loop = loop
        self.transmit_allowed = transmit_allowed
        self.reopen = reopen  # a new bus at another bit rate (LSS, DeviceNet baud rate)
        self.interface = interface  # the SocketCAN interface fieldgate controls, if any
        self.bus_off_restart = (
            bus_off_restart  # the front's restart delay after bus-off (None: hold)
        )
        self.on_link = on_link  # the interface set as configured (None) or why not
        self.counters: Counter[str] = Counter()
        self.rx_frames = self.tx_frames = 0  # the two per-frame counts, kept as plain integers
        self.rx_ignored = 0  # received, but not on an identifier the engine listens to
        self.quick_answers = 0
        self._listen_ids: Callable[[], Any] | None = getattr(node, "listen_ids", None)
        self._listen_source: object = None  # what listen_ids() returned last
        self.listen: frozenset[int] | None = None  # the engine's listen set; None: every frame
        self.filters: list[acceptance.Filter] | None = None  # as applied to the bus
        self.max_filters = acceptance.MAX_FILTERS
        self._raw_send: Callable[[bytes], int] | None = None  # SocketCAN's socket.send, if usable
        self.controller = Controller(self, on_bus_state, on_controller)
        self.receiving = ReceivePath(self)
        self.bind_bus()
        self._timer: asyncio.TimerHandle | None = None
        self._armed_at = 0.0
        self._state_timer: asyncio.TimerHandle | None = None
        self.closed = False
        self.switching = False  # the bus is being reopened at a new bit rate
        # the loop holds it while it calls the engine (re-entered when a process-image event
        # raised inside an engine call pumps again); see .receive
        self.engine_lock = threading.RLock()
        # set when receiving is dead: the front's run() raises
        self.failed: asyncio.Future[None] = loop.create_future()

    # -- life cycle ------------------------------------------------------------------
    def start(self, boot: bool = True) -> None:
        with self.engine_lock:
            self._refresh_filters()
        self.receiving.start()
        with self.engine_lock:
            if boot:
                frames = self.node.boot(self.now)
                self._refresh_filters()
                self.send(frames)
            self.arm()
        self._state_timer = self.loop.call_later(STATE_POLL_S, self._poll_bus_state)
        self.node.on_bit_timing(self.controller.bit_timing)

    def close(self) -> None:
        # a read being answered on the receive thread finishes first; none after
        with self.engine_lock:
            self.closed = True
        self.controller.close()
        for handle in (self._timer, self._state_timer):
            if handle is not None:
                handle.cancel()
        self.receiving.stop()
        try:
            self.bus.shutdown()
        except Exception as exc:  # a broken driver must not stop the gateway's shutdown
            log.warning("CAN bus shutdown failed: %s", _one_line(exc))

    @property
    def now(self) -> float:
        return self.loop.time()

    def bind_bus(self) -> None:
        """Use SocketCAN's raw socket for sending where :mod:`.socketcan_raw` allows."""
        sock = raw.raw_socket(self.bus)
        self._raw_send = None if sock is None else sock.send
        if sock is not None:
            try:
                self.counters["rx_buffer_bytes"] = raw.enlarge_receive_buffer(sock)
            except OSError as exc:
                log.warning("CAN receive buffer left as it is: %s", _one_line(exc))

    def fail(self, exc: BaseException) -> None:
        """Receiving has died: :attr:`failed` raises in the front's ``run()``, which restarts it."""
        self.counters["rx_failures"] += 1
        if not self.failed.done():
            log.error("CAN receive failed: %s", _one_line(exc))
            self.failed.set_exception(RuntimeError(f"CAN receive failed: {_one_line(exc)}"))

    # -- the engine's calls ------------------------------------------------------------------
    def engine_receive(self, frame: Frame) -> None:
        """Under the engine lock, a frame of ours (both receive paths): the node takes it, a
        listen set it changed becomes the bus's filters, its answers go out."""
        now = self.loop.time()
        node = self.node
        frames = node.receive(frame, now)
        if self._listen_ids is not None and self._listen_ids() is not self._listen_source:
            self._refresh_filters()
        self.arm(node.deadline_after_call, known=True)
        if frames:  # last: only returns follow the answer, so the waiting peer runs at once
            self.send(frames, now)

    def pump(self, action: Callable[[], object] | None = None) -> None:
        """Run ``action`` on the engine from outside its frame and timer calls (raise an EMCY,
        note changed inputs), then send what the engine queued and re-arm timers."""
        with self.engine_lock:
            if action is not None:
                action()
            frames = self.node.flush()
            self._refresh_filters()
            self.send(frames)
            self.arm(self.node.deadline_after_call, known=True)

    def pump_unless_closed(self) -> None:
        if not self.closed:
            self.pump()

    def run_engine(self) -> None:
        """Let the engine act now (a process-image event changed its inputs): tick, send, re-arm."""
        with self.engine_lock:
            frames = self.node.tick(self.now)  # (drains what was queued, notes the deadline)
            self._refresh_filters()
            self.send(frames)
            self.arm(self.node.deadline_after_call, known=True)

    # -- transmit ----------------------------------------------------------------------------
    def send(self, frames: list[Frame] | tuple[Frame, ...], now: float | None = None) -> None:
        """Send the engine's frames (the caller holds :attr:`engine_lock`)."""
        if not frames:
            return
        now = self.loop.time() if now is None else now
        if self.transmit_allowed is not None and not self.transmit_allowed(now):
            self.counters["tx_suppressed"] += len(frames)
            return
        raw_send = self._raw_send
        for frame in frames:
            try:
                if raw_send is not None:
                    can_id, data, rtr, _ = frame
                    if rtr:
                        raw_send(_pack(can_id | raw.CAN_RTR_FLAG, frame.length, b""))
                    elif len(data) <= 8:
                        raw_send(_pack(can_id, len(data), data))
                    else:
                        raise ValueError(f"{len(data)} data bytes in a classic CAN frame")
                else:
                    self.bus.send(to_message(frame))
                self.tx_frames += 1
            except (can.CanError, OSError, ValueError, struct.error) as exc:
                self.counters["tx_errors"] += 1
                if _no_buffer_space(exc):
                    self.controller.overrun("tx")
                if self.counters["tx_errors"] == 1 or self.counters["tx_errors"] % 1000 == 0:
                    log.warning(
                        "CAN send failed (%d so far): %s",
                        self.counters["tx_errors"],
                        _one_line(exc),
                    )

    def send_answer(self, answer: Frame, now: float) -> None:
        """A quick answer from the receive thread (answered and counted: a failed send is not
        left for the loop to answer again)."""
        try:
            self.send((answer,), now)
        except Exception as exc:
            self.counters["tx_errors"] += 1
            log.warning("CAN send failed: %s", _one_line(exc))

    # -- timers ------------------------------------------------------------------------------
    def arm(self, deadline: float | None = None, known: bool = False) -> None:
        """Have ``_tick`` run by the node's next deadline.

        An armed timer that fires no later than the deadline is kept (an early tick only
        re-arms), so the per-frame cost is a comparison, not a cancel and a new timer.
        """
        if self.closed:
            return
        if not known:
            deadline = self.node.next_deadline()
        if deadline is None:
            return
        if self._timer is not None:
            if self._armed_at <= deadline:
                return
            self._timer.cancel()
        self._armed_at = deadline
        self._timer = self.loop.call_at(max(deadline, self.now), self._tick)

    def _tick(self) -> None:
        self._timer = None
        if self.closed:
            return
        with self.engine_lock:
            frames = self.node.tick(self.now)
            if self._listen_ids is not None and self._listen_ids() is not self._listen_source:
                self._refresh_filters()
            self.send(frames)
            self.arm(self.node.deadline_after_call, known=True)

    def _poll_bus_state(self) -> None:
        """Once a second: python-can's bus state and the receiver's drops to the controller,
        and whether receiving still works."""
        if self.closed:
            return
        try:
            state = self.bus.state
        except Exception:
            state = None
        with self.engine_lock:
            self.controller.poll(state, self.receiving.dropped)
        self.check_receiver()
        self._state_timer = self.loop.call_later(STATE_POLL_S, self._poll_bus_state)

    def check_receiver(self) -> None:
        self.receiving.check(STATE_POLL_S)

    # -- acceptance filters -----------------------------------------------------------------
    def _refresh_filters(self) -> None:
        """Give the bus the engine's listen set if it changed (the caller holds the lock)."""
        get = self._listen_ids
        if get is None or self.closed:
            return
        source = get()
        if source is self._listen_source:
            return
        self._listen_source = source
        listen = None if source is None else frozenset(source)
        if listen == self.listen and self.filters is not None:
            return
        self.listen = listen
        self.apply_filters()

    def apply_filters(self) -> None:
        listen = self.listen
        merged = None if listen is None else acceptance.merge(listen, self.max_filters)
        try:
            self.bus.set_filters(None if merged is None else acceptance.to_python_can(merged))
        except (can.CanError, OSError, ValueError, NotImplementedError) as exc:
            self.counters["filter_errors"] += 1
            log.warning("CAN acceptance filters not set (every frame is read): %s", _one_line(exc))
        self.filters = merged
        self.counters["filter_updates"] += 1

    def status(self) -> dict[str, Any]:
        counts = dict(
            rx=self.rx_frames,
            rx_ignored=self.rx_ignored,
            tx=self.tx_frames,
            quick_answers=self.quick_answers,
        )
        filters = None if self.filters is None else acceptance.describe(self.filters)
        return {
            **counts,
            **self.counters,
            "filters": filters,
            **self.controller.status(),
            "rx_dropped": self.receiving.dropped,
        }
