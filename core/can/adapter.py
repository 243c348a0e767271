"""Binds a sans-I/O CAN engine (the CANopen ``Node``, the DeviceNet engine) to a python-can bus and the asyncio clock.

* Any python-can interface works: ``interface``, ``channel``, ``bitrate`` and extra
  options go to ``can.Bus`` unchanged (socketcan, virtual, pcan, kvaser, slcan, ...).
* Received messages reach the node on the event loop through
  :func:`~.busrx.start_receiver`: ``add_reader`` on SocketCAN (no thread), a
  receive thread hopping with ``loop.call_soon_threadsafe`` on other interfaces (and on
  the virtual bus when the engine answers quickly, below), pushed straight from the
  sender on the virtual bus otherwise.
* Quick answers: an engine with ``quick_answer(can_id, data, now)`` (the CANopen node:
  SDO reads) answers those on the receive thread, without waking the loop. Everything the
  loop does with the engine (frames, timers, ``pump``, ``tick``, bus-state changes) holds
  :attr:`CanAdapter.engine_lock`, and the receive thread only *tries* the lock, only
  when every earlier frame has been handled; otherwise the frame goes to the loop. So
  the engine still sees one call at a time, in frame order. Closing and reopening the
  bus (bit-rate switch) stop quick answers under the lock first.
* Timers: after every call into the node, one ``loop.call_at`` is armed for the node's
  next deadline. ``now`` is ``loop.time()`` (monotonic seconds); the receive thread reads
  ``time.monotonic()``, the same clock, never behind the loop's.
* Bus-off: SocketCAN error frames (``CAN_ERR_BUSOFF`` / ``CAN_ERR_RESTARTED``) and
  interfaces that report ``bus.state == ERROR`` (checked once a second) are passed to
  ``on_bus_state``. Send failures are counted, never raised.
* Controller health, passed to ``on_controller(event, now)``: the error state
  (``error-active``, ``warning``, ``passive``) from SocketCAN's controller error frames
  (``CAN_ERR_CRTL``: warning, passive, back to active; ``CAN_ERR_CNT``'s error counters
  where the driver gives no state) and from ``bus.state`` (ACTIVE / PASSIVE) where
  python-can reports it; overruns: ``controller-overrun`` (``CAN_ERR_CRTL_RX/TX_OVERFLOW``:
  the controller lost frames), ``rx-overrun`` (the gateway's receive queue: SocketCAN's
  socket buffer dropped frames, ``SO_RXQ_OVFL``, or the receive thread's hand-over queue
  was full), ``tx-overrun`` (the driver's transmit queue was full: ENOBUFS). Overruns are
  events; the front decides how long one stays an error.
* Receiving that has died (the receive thread ended on a driver exception, or the
  reader failed ``RX_ERRORS_FATAL`` times within one poll) sets :attr:`CanAdapter.failed`;
  the front's ``run()`` raises and the runtime restarts the front with back-off.
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
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, Protocol, cast

import can

from fieldgate.plugin import PluginStartError

from . import filters as acceptance
from . import socketcan_raw as raw
from .busrx import Receiver, start_receiver
from .frame import Frame

log = logging.getLogger("fieldgate.can.adapter")


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


class QuickAnswering(Protocol):
    """An engine that can answer a read on the receive thread (optional; see :meth:`CanAdapter._quick`)."""

    def quick_answer(self, can_id: int, data: bytes | bytearray, now: float) -> Frame | None: ...


CAN_ERR_CRTL = 0x04  # controller problems, details in data[1]
CAN_ERR_BUSOFF = 0x40
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CNT = 0x200  # data[6] / data[7]: TX / RX error counters (Linux 6.3+)
CRTL_RX_OVERFLOW, CRTL_TX_OVERFLOW = 0x01, 0x02
CRTL_WARNING = 0x04 | 0x08  # RX / TX error counter reached the warning level (96)
CRTL_PASSIVE = 0x10 | 0x20  # RX / TX error counter reached the error-passive level (128)
CRTL_ACTIVE = 0x40  # back to error-active
WARNING_LEVEL, PASSIVE_LEVEL = 96, 128
CONTROLLER_STATES = ("error-active", "warning", "passive")
OVERRUNS = ("rx", "tx", "controller")
ENOBUFS = 105
STATE_POLL_S = 1.0
RX_ERRORS_FATAL = 100  # receive errors within one state poll that count as a dead bus


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


_new_frame = tuple.__new__  # Frame(...) without its Python-level __new__: two per SDO request
_pack = raw.FRAME.pack


def to_frame(msg: can.Message) -> Frame:
    if msg.is_remote_frame:
        return Frame(msg.arbitration_id, b"", rtr=True, dlc=msg.dlc)
    return _new_frame(Frame, (msg.arbitration_id, bytes(msg.data), False, None))


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
    ):
        self.node = node
        self.bus = bus
        self.loop = loop
        self.on_bus_state = on_bus_state
        self.on_controller = on_controller
        self.controller_state = "error-active"
        self._state_passive = False  # set from bus.state (not from error frames)
        self.overruns: Counter[str] = Counter()
        self._rx_overruns_seen = 0
        self.transmit_allowed = transmit_allowed
        self._reopen = reopen
        self.counters: Counter[str] = Counter()
        self.rx_frames = self.tx_frames = 0  # the two per-frame counts, kept as plain integers
        self.rx_ignored = 0  # received, but not on an identifier the engine listens to
        self._listen_ids: Callable[[], Any] | None = getattr(node, "listen_ids", None)
        self._listen_source: object = None  # what listen_ids() returned last
        self.listen: frozenset[int] | None = None  # the engine's listen set; None: every frame
        self.filters: list[acceptance.Filter] | None = None  # as applied to the bus
        self.max_filters = acceptance.MAX_FILTERS
        self._raw_send: Callable[[bytes], int] | None = None  # SocketCAN's socket.send, if usable
        self._bind_bus()
        self._timer: asyncio.TimerHandle | None = None
        self._armed_at = 0.0
        self._state_timer: asyncio.TimerHandle | None = None
        self._receiver: Receiver | None = None
        self._bus_off = False
        self._state_bus_off = False
        self._rx_errors_seen = 0
        self.closed = False
        self._switching = False  # the bus is being reopened at a new bit rate
        self.engine_lock = (
            threading.RLock()
        )  # the loop holds it while it calls the engine (re-entered when a
        # process-image event raised inside an engine call pumps again); see the module notes
        self.quick_answers = 0
        self.failed: asyncio.Future[None] = (
            loop.create_future()
        )  # set when receiving is dead: run() raises

    # -- life cycle ------------------------------------------------------------------
    def start(self, boot: bool = True) -> None:
        with self.engine_lock:
            self._refresh_filters()
        self._receiver = self._start_receiver()
        with self.engine_lock:
            if boot:
                frames = self.node.boot(self.now)
                self._refresh_filters()
                self._send(frames)
            self._arm()
        self._state_timer = self.loop.call_later(STATE_POLL_S, self._poll_bus_state)
        self.node.on_bit_timing(self._bit_timing)

    def close(self) -> None:
        with (
            self.engine_lock
        ):  # a read being answered on the receive thread finishes first; none after
            self.closed = True
        for handle in (self._timer, self._state_timer):
            if handle is not None:
                handle.cancel()
        if self._receiver is not None:
            self._receiver.stop()
            self._receiver = None
        try:
            self.bus.shutdown()
        except Exception as exc:  # a broken driver must not stop the gateway's shutdown
            log.warning("CAN bus shutdown failed: %s", _one_line(exc))

    @property
    def now(self) -> float:
        return self.loop.time()

    def _bind_bus(self) -> None:
        """Use SocketCAN's raw socket for sending where :mod:`.socketcan_raw` allows."""
        sock = raw.raw_socket(self.bus)
        self._raw_send = None if sock is None else sock.send
        if sock is not None:
            try:
                self.counters["rx_buffer_bytes"] = raw.enlarge_receive_buffer(sock)
            except OSError as exc:
                log.warning("CAN receive buffer left as it is: %s", _one_line(exc))

    # -- receive -----------------------------------------------------------------------
    def _start_receiver(self) -> Receiver:
        quick = self._quick if hasattr(self.node, "quick_answer") else None
        return start_receiver(self.bus, self.loop, self._receive, quick, self._receive_raw)

    def _receive_raw(self, word: int, dlc: int, data: bytes) -> None:
        """One frame read from SocketCAN's raw socket (the fast path of :meth:`_receive`)."""
        if word & raw.OTHER_FLAGS:
            self._receive(raw.to_message(word, dlc, data))
            return
        if self.closed:
            return
        with self.engine_lock:
            self.rx_frames += 1
            can_id = word & raw.CAN_SFF_MASK
            listen = self.listen
            if listen is not None and can_id not in listen:
                self.rx_ignored += 1
                return
            if word & raw.CAN_RTR_FLAG:
                frame = Frame(can_id, b"", rtr=True, dlc=dlc)
            else:
                frame = _new_frame(Frame, (can_id, data[:dlc], False, None))
            self._engine_receive(frame)

    def _receive(self, msg: can.Message) -> None:
        """One received message: the node's answers go out before anything else happens."""
        if self.closed:
            return
        with self.engine_lock:
            if msg.is_error_frame or msg.is_extended_id or msg.is_fd:
                self._receive_other(msg)
                return
            self.rx_frames += 1
            listen = self.listen
            if listen is not None and msg.arbitration_id not in listen:
                self.rx_ignored += 1
                return
            self._engine_receive(to_frame(msg))

    def _engine_receive(self, frame: Frame) -> None:
        """Under the engine lock, a frame of ours (both receive paths): the node takes it, a
        listen set it changed becomes the bus's filters, its answers go out."""
        now = self.loop.time()
        node = self.node
        frames = node.receive(frame, now)
        if self._listen_ids is not None and self._listen_ids() is not self._listen_source:
            self._refresh_filters()
        self._arm(node.deadline_after_call, known=True)
        if frames:  # last: only returns follow the answer, so the waiting peer runs at once
            self._send(frames, now)

    def _quick(self, msg: can.Message) -> bool:
        """On the receive thread: answer ``msg`` at once if the engine can (True), else False.

        Never blocks (the lock is only tried) and never raises (the receive thread would end).
        """
        if msg.is_remote_frame or msg.is_error_frame or msg.is_extended_id or msg.is_fd:
            return False
        lock = self.engine_lock
        if not lock.acquire(False):
            return False
        try:
            if self.closed or self._switching:
                return False
            # the monotonic clock the loop's time is read from (never behind it, so a timer
            # due by the loop's clock is due here too); uvloop's time() is the loop thread's
            now = time.monotonic()
            try:
                answer = cast(QuickAnswering, self.node).quick_answer(
                    msg.arbitration_id, msg.data, now
                )
            except Exception:  # the loop's path handles (and logs) whatever went wrong here
                return False
            if answer is None:
                return False
            self.rx_frames += 1
            self.quick_answers += 1
            try:
                self._send((answer,), now)
            except Exception as exc:  # answered and counted: the loop must not answer again
                self.counters["tx_errors"] += 1
                log.warning("CAN send failed: %s", _one_line(exc))
            return True
        finally:
            lock.release()

    def _receive_other(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self._error_frame(msg)
        elif msg.is_extended_id:
            self.counters["rx_extended_dropped"] += 1
        else:
            self.counters["rx_fd_dropped"] += 1
        self._arm()

    def _error_frame(self, msg: can.Message) -> None:
        self.counters["rx_error_frames"] += 1
        err, data = msg.arbitration_id, bytes(msg.data).ljust(8, b"\0")
        if err & CAN_ERR_BUSOFF:
            self._set_bus_off(True)
        elif err & CAN_ERR_RESTARTED:
            self._set_bus_off(False)
            self._set_controller_state("error-active")
        if err & CAN_ERR_CRTL:
            crtl = data[1]
            if crtl & (CRTL_RX_OVERFLOW | CRTL_TX_OVERFLOW):
                self.overrun("controller")
            if crtl & CRTL_PASSIVE:
                self._set_controller_state("passive")
            elif crtl & CRTL_WARNING:
                self._set_controller_state("warning")
            elif crtl & CRTL_ACTIVE:
                self._set_controller_state("error-active")
        elif err & CAN_ERR_CNT:  # no state from the driver: the counters say it
            worst = max(data[6], data[7])
            self._set_controller_state(
                "passive"
                if worst >= PASSIVE_LEVEL
                else ("warning" if worst >= WARNING_LEVEL else "error-active")
            )

    def _set_controller_state(self, state: str) -> None:
        if state == self.controller_state:
            return
        self.controller_state = state
        self.counters[f"controller_{state}"] += 1
        if self.on_controller is not None:
            self.on_controller(state, self.now)
            self._send(self.node.flush())

    def overrun(self, kind: str) -> None:
        """Frames were lost: ``rx`` (the gateway's receive queue), ``tx`` (the driver's transmit
        queue) or ``controller`` (the CAN controller's own buffers)."""
        self.overruns[kind] += 1
        if self.on_controller is not None:
            self.on_controller(f"{kind}-overrun", self.now)
            # what the engine queued (an EMCY) goes out from the loop, never from inside a
            # send that just failed (a full transmit queue would fail it again, and again)
            try:
                self.loop.call_soon_threadsafe(self._pump_unless_closed)
            except RuntimeError:  # the loop is closed: the gateway is stopping
                pass

    def _poll_bus_state(self) -> None:
        if self.closed:
            return
        try:
            state = self.bus.state
        except Exception:
            state = None
        with self.engine_lock:
            if state is can.BusState.ERROR:
                self._state_bus_off = True
                self._set_bus_off(True)
            elif state is not None and self._state_bus_off:
                self._state_bus_off = False
                self._set_bus_off(False)
            if state is can.BusState.PASSIVE:
                self._state_passive = True
                self._set_controller_state("passive")
            elif state is can.BusState.ACTIVE and self._state_passive:
                self._state_passive = False
                self._set_controller_state("error-active")
            dropped = getattr(self._receiver, "dropped", 0)
            if isinstance(dropped, int) and dropped > self._rx_overruns_seen:
                self._rx_overruns_seen = dropped
                self.overrun("rx")
        self._check_receiver()
        self._state_timer = self.loop.call_later(STATE_POLL_S, self._poll_bus_state)

    def _check_receiver(self) -> None:
        """A dead receive thread, or a reader failing on every call, fails the adapter."""
        receiver = self._receiver
        exc = getattr(receiver, "exception", None)
        errors = getattr(receiver, "errors", 0)
        if (
            exc is None
            and isinstance(errors, int)
            and errors - self._rx_errors_seen >= RX_ERRORS_FATAL
        ):
            exc = can.CanOperationError(
                f"{errors - self._rx_errors_seen} receive errors in {STATE_POLL_S:g} s"
            )
        self._rx_errors_seen = errors if isinstance(errors, int) else 0
        if exc is not None:
            self._receive_failed(exc)

    def _receive_failed(self, exc: BaseException) -> None:
        self.counters["rx_failures"] += 1
        if not self.failed.done():
            log.error("CAN receive failed: %s", _one_line(exc))
            self.failed.set_exception(RuntimeError(f"CAN receive failed: {_one_line(exc)}"))

    def _set_bus_off(self, bus_off: bool) -> None:
        if bus_off == self._bus_off:
            return
        self._bus_off = bus_off
        self.counters["bus_off_events" if bus_off else "bus_off_recoveries"] += 1
        if self.on_bus_state is not None:
            self.on_bus_state(bus_off, self.now)
        self._send(self.node.flush())

    # -- transmit and timers ---------------------------------------------------------------
    def _send(self, frames: list[Frame] | tuple[Frame, ...], now: float | None = None) -> None:
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
                    self.overrun("tx")
                if self.counters["tx_errors"] == 1 or self.counters["tx_errors"] % 1000 == 0:
                    log.warning(
                        "CAN send failed (%d so far): %s",
                        self.counters["tx_errors"],
                        _one_line(exc),
                    )

    def pump(self, action: Callable[[], object] | None = None) -> None:
        """Run ``action`` on the engine from outside its frame and timer calls (raise an EMCY,
        note changed inputs), then send what the engine queued and re-arm timers."""
        with self.engine_lock:
            if action is not None:
                action()
            frames = self.node.flush()
            self._refresh_filters()
            self._send(frames)
            self._arm(self.node.deadline_after_call, known=True)

    def _pump_unless_closed(self) -> None:
        if not self.closed:
            self.pump()

    def run_engine(self) -> None:
        """Let the engine act now (a process-image event changed its inputs): tick, send, re-arm."""
        with self.engine_lock:
            frames = self.node.tick(self.now)  # (drains what was queued, notes the deadline)
            self._refresh_filters()
            self._send(frames)
            self._arm(self.node.deadline_after_call, known=True)

    def _arm(self, deadline: float | None = None, known: bool = False) -> None:
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
            self._send(frames)
            self._arm(self.node.deadline_after_call, known=True)

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
        self._apply_filters()

    def _apply_filters(self) -> None:
        listen = self.listen
        merged = None if listen is None else acceptance.merge(listen, self.max_filters)
        try:
            self.bus.set_filters(None if merged is None else acceptance.to_python_can(merged))
        except (can.CanError, OSError, ValueError, NotImplementedError) as exc:
            self.counters["filter_errors"] += 1
            log.warning("CAN acceptance filters not set (every frame is read): %s", _one_line(exc))
        self.filters = merged
        self.counters["filter_updates"] += 1

    # -- LSS bit timing ---------------------------------------------------------------------
    def _bit_timing(self, bitrate: int, delay_s: float) -> None:
        if self._reopen is None:
            self.counters["bit_timing_ignored"] += 1
            return
        self.loop.call_later(delay_s, self._switch_bitrate, bitrate)

    def _switch_bitrate(self, bitrate: int) -> None:
        reopen = self._reopen
        if self.closed or reopen is None:  # (None: _bit_timing schedules no switch)
            return
        log.info("switching the CAN bit rate to %d bit/s", bitrate)
        with self.engine_lock:  # no read is answered on the receive thread until the new bus is up
            self._switching = True
        if self._receiver is not None:
            self._receiver.stop()
        try:
            self.bus.shutdown()
            self.bus = reopen(bitrate)
            self._bind_bus()
        except PluginStartError as exc:
            log.error("cannot reopen the CAN bus at %d bit/s: %s", bitrate, exc)
            self.counters["bit_timing_failures"] += 1
            return
        with self.engine_lock:
            self._apply_filters()
        self._receiver = self._start_receiver()
        self._switching = False
        self.counters["bit_timing_switches"] += 1

    def status(self) -> dict[str, Any]:
        return {
            "rx": self.rx_frames,
            "rx_ignored": self.rx_ignored,
            "tx": self.tx_frames,
            "quick_answers": self.quick_answers,
            **self.counters,
            "filters": None if self.filters is None else acceptance.describe(self.filters),
            "bus_off": self._bus_off,
            "controller": "bus-off" if self._bus_off else self.controller_state,
            "overruns": {kind: self.overruns[kind] for kind in OVERRUNS},
            "rx_dropped": getattr(self._receiver, "dropped", 0),
        }
