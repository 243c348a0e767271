"""What the adapter knows of the CAN controller: bus-off, the error state, overruns, bit rate.

* Bus-off: SocketCAN error frames (``CAN_ERR_BUSOFF`` / ``CAN_ERR_RESTARTED``) and
  interfaces that report ``bus.state == ERROR`` (the adapter polls it once a second) are
  passed to ``on_bus_state(bus_off, now)``.
* The error state (``error-active``, ``warning``, ``passive``), passed to
  ``on_controller(state, now)``: from SocketCAN's controller error frames (``CAN_ERR_CRTL``:
  warning, passive, back to active; ``CAN_ERR_CNT``'s error counters where the driver
  gives no state) and from ``bus.state`` (ACTIVE / PASSIVE) where python-can reports it.
* Overruns, passed to ``on_controller("<kind>-overrun", now)``: ``controller``
  (``CAN_ERR_CRTL_RX/TX_OVERFLOW``: the controller lost frames), ``rx`` (the gateway's
  receive queue: SocketCAN's socket buffer dropped frames, ``SO_RXQ_OVFL``, or the receive
  thread's hand-over queue was full), ``tx`` (the driver's transmit queue was full:
  ENOBUFS). Overruns are events; the front decides how long one stays an error.
* Bit rate: an engine's bit-timing request (LSS activate bit timing, a DeviceNet baud rate
  change) reopens the bus at the new rate after its delay (``reopen``), with no read
  answered on the receive thread meanwhile.

What the front's callbacks queue in the engine (an EMCY) goes out at once, or, for an
overrun, from the loop's next turn (never from inside a send that just failed).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections import Counter
from collections.abc import Callable
from typing import Any, Protocol

import can

from fieldgate.plugin import PluginStartError

from .frame import Frame
from .interface import InterfaceControl

log = logging.getLogger("fieldgate.can.adapter")

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


class Flushing(Protocol):
    def flush(self) -> list[Frame]: ...


class Receiving(Protocol):
    def start(self) -> None: ...
    def stop(self) -> None: ...


class ControllerHost(Protocol):
    """What the controller uses of the adapter (:class:`~.adapter.CanAdapter` is one)."""

    bus: can.BusABC
    loop: asyncio.AbstractEventLoop
    engine_lock: threading.RLock
    closed: bool
    switching: bool
    counters: Counter[str]
    reopen: Callable[[int], can.BusABC] | None
    receiving: Receiving
    interface: InterfaceControl | None
    bus_off_restart: Callable[[], float | None] | None
    on_link: Callable[[str | None, float], None] | None

    @property
    def node(self) -> Flushing: ...  # the engine

    @property
    def now(self) -> float: ...

    def send(self, frames: list[Frame] | tuple[Frame, ...], now: float | None = None) -> None: ...
    def pump_unless_closed(self) -> None: ...
    def bind_bus(self) -> None: ...
    def fail(self, exc: BaseException) -> None: ...
    def apply_filters(self) -> None: ...


class Controller:
    def __init__(
        self,
        adapter: ControllerHost,
        on_bus_state: Callable[[bool, float], None] | None = None,
        on_controller: Callable[[str, float], None] | None = None,
    ):
        self.adapter = adapter
        self.counters = adapter.counters  # one set of counters in the adapter's status
        self.on_bus_state = on_bus_state
        self.on_controller = on_controller
        self.state = "error-active"
        self.bus_off = False
        self.overruns: Counter[str] = Counter()
        self._state_passive = False  # set from bus.state (not from error frames)
        self._state_bus_off = False  # set from bus.state
        self._rx_overruns_seen = 0
        self._tasks: set[asyncio.Task[None]] = set()  # link work in flight (reads, switches)
        self._restart: asyncio.TimerHandle | None = None  # the front's restart after bus-off

    def close(self) -> None:
        """The adapter closes: nothing scheduled runs any more."""
        if self._restart is not None:
            self._restart.cancel()
        for task in list(self._tasks):
            task.cancel()

    def _spawn(self, work: Callable[[], Any]) -> None:
        """Run ``work()`` (a coroutine) on the adapter's loop, from any thread."""

        def start() -> None:
            if self.adapter.closed:
                return
            task = self.adapter.loop.create_task(work())
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

        try:
            self.adapter.loop.call_soon_threadsafe(start)
        except RuntimeError:  # the loop is closed: the gateway is stopping
            pass

    # -- what the bus says ---------------------------------------------------------------
    def error_frame(self, msg: can.Message) -> None:
        self.counters["rx_error_frames"] += 1
        err, data = msg.arbitration_id, bytes(msg.data).ljust(8, b"\0")
        if err & CAN_ERR_BUSOFF:
            self.set_bus_off(True)
        elif err & CAN_ERR_RESTARTED:
            self.set_bus_off(False)
            self.set_state("error-active")
        if err & CAN_ERR_CRTL:
            crtl = data[1]
            if crtl & (CRTL_RX_OVERFLOW | CRTL_TX_OVERFLOW):
                self.overrun("controller")
            if crtl & CRTL_PASSIVE:
                self.set_state("passive")
            elif crtl & CRTL_WARNING:
                self.set_state("warning")
            elif crtl & CRTL_ACTIVE:
                self.set_state("error-active")
        elif err & CAN_ERR_CNT:  # no state from the driver: the counters say it
            worst = max(data[6], data[7])
            self.set_state(
                "passive"
                if worst >= PASSIVE_LEVEL
                else ("warning" if worst >= WARNING_LEVEL else "error-active")
            )

    def poll(self, state: can.BusState | None, dropped: object) -> None:
        """The state poll (the caller holds the engine lock): python-can's ``bus.state``
        (None: the interface has none) and the receiver's dropped frames."""
        if state is can.BusState.ERROR:
            self._state_bus_off = True
            self.set_bus_off(True)
        elif state is not None and self._state_bus_off:
            self._state_bus_off = False
            self.set_bus_off(False)
        if state is can.BusState.PASSIVE:
            self._state_passive = True
            self.set_state("passive")
        elif state is can.BusState.ACTIVE and self._state_passive:
            self._state_passive = False
            self.set_state("error-active")
        if isinstance(dropped, int) and dropped > self._rx_overruns_seen:
            self._rx_overruns_seen = dropped
            self.overrun("rx")

    # -- what the front hears --------------------------------------------------------------
    def set_state(self, state: str) -> None:
        if state == self.state:
            return
        self.state = state
        self.counters[f"controller_{state}"] += 1
        if self.on_controller is not None:
            self.on_controller(state, self.adapter.now)
            self.adapter.send(self.adapter.node.flush())

    def overrun(self, kind: str) -> None:
        """Frames were lost: ``rx`` (the gateway's receive queue), ``tx`` (the driver's transmit
        queue) or ``controller`` (the CAN controller's own buffers)."""
        self.overruns[kind] += 1
        if self.on_controller is not None:
            self.on_controller(f"{kind}-overrun", self.adapter.now)
            # what the engine queued (an EMCY) goes out from the loop, never from inside a
            # send that just failed (a full transmit queue would fail it again, and again)
            try:
                self.adapter.loop.call_soon_threadsafe(self.adapter.pump_unless_closed)
            except RuntimeError:  # the loop is closed: the gateway is stopping
                pass

    def set_bus_off(self, bus_off: bool) -> None:
        if bus_off == self.bus_off:
            return
        self.bus_off = bus_off
        self.counters["bus_off_events" if bus_off else "bus_off_recoveries"] += 1
        if self.on_bus_state is not None:
            self.on_bus_state(bus_off, self.adapter.now)
        self.adapter.send(self.adapter.node.flush())
        if self.adapter.interface is not None:
            self._spawn(self._read_link_after_bus_state)

    # -- the interface (SocketCAN under fieldgate's control) -----------------------------------
    async def _read_link_after_bus_state(self) -> None:
        """Bus-off or its end: the kernel's view (state, error counters, its bus-off and restart
        counts); after bus-off, the front's own restart where the kernel has none (restart-ms 0)."""
        interface = self.adapter.interface
        assert interface is not None
        await interface.refresh()
        self._reconcile()
        if not self.bus_off or interface.kernel_restarts or self._restart is not None:
            return
        delay = self.adapter.bus_off_restart() if self.adapter.bus_off_restart else None
        if delay is None:
            log.warning(
                "%s: bus-off: the controller stays off (no automatic recovery)", interface.channel
            )
            return
        self._restart = self.adapter.loop.call_later(
            delay, lambda: self._spawn(self._restart_after_bus_off)
        )

    async def _restart_after_bus_off(self) -> None:
        self._restart = None
        interface = self.adapter.interface
        if interface is None or not self.bus_off or self.adapter.closed:
            return
        problem = await interface.restart()
        if problem is not None:
            log.error("%s: bus-off not recovered: %s", interface.channel, problem)
        self._reconcile()

    def _reconcile(self) -> None:
        """Take the kernel's word for bus-off where its error frame did not come (a restart by
        down/up sends none; a driver without error frames)."""
        interface = self.adapter.interface
        link = interface.link if interface is not None else None
        if link is None or link.state is None or self.adapter.closed:
            return
        with self.adapter.engine_lock:
            if link.state == "bus-off":
                self.set_bus_off(True)
            elif link.up and link.state in ("error-active", "error-warning", "error-passive"):
                if self.bus_off:
                    self.set_bus_off(False)
                    self.set_state("error-active")

    # -- bit rate ---------------------------------------------------------------------------
    def bit_timing(self, bitrate: int, delay_s: float) -> None:
        """The engine asks for another bit rate in ``delay_s``."""
        if self.adapter.reopen is None:
            self.counters["bit_timing_ignored"] += 1
            self.adapter.loop.call_soon(self._switched, bitrate, None)
            return
        self.adapter.loop.call_later(
            delay_s, lambda: self._spawn(lambda: self.switch_bitrate(bitrate))
        )

    async def switch_bitrate(self, bitrate: int) -> None:
        """Close the bus, set the interface to ``bitrate`` (where fieldgate controls it: through
        netlink, in a thread), open the bus again; the engine and the front hear how it went."""
        adapter = self.adapter
        reopen = adapter.reopen
        if adapter.closed or reopen is None:  # (None: bit_timing schedules no switch)
            return
        log.info("switching the CAN bit rate to %d bit/s", bitrate)
        with (
            adapter.engine_lock
        ):  # no read is answered on the receive thread until the new bus is up
            adapter.switching = True
        adapter.receiving.stop()
        try:
            adapter.bus.shutdown()
        except Exception as exc:  # a broken driver: the bus is reopened anyway
            log.warning("CAN bus shutdown failed: %s", exc)
        problem = None
        if adapter.interface is not None:
            problem = await adapter.interface.apply(bitrate)
            if problem is not None:
                log.error("%s; the node runs with the interface as it is", problem)
        if self._closed():  # (closed while the interface was set)
            return
        try:
            adapter.bus = reopen(bitrate)
            adapter.bind_bus()
        except PluginStartError as exc:
            log.error("cannot reopen the CAN bus at %d bit/s: %s", bitrate, exc)
            self.counters["bit_timing_failures"] += 1
            adapter.fail(exc)  # the front restarts on its configured settings
            return
        with adapter.engine_lock:
            adapter.apply_filters()
        adapter.receiving.start()
        adapter.switching = False
        self.counters["bit_timing_switches" if problem is None else "bit_timing_failures"] += 1
        self._switched(bitrate, problem)

    def _closed(self) -> bool:
        return self.adapter.closed

    def _switched(self, bitrate: int, problem: str | None) -> None:
        """The engine (``bit_timing_done``, e.g. DeviceNet's duplicate MAC check waits for it) and
        the front (``on_link``: an EMCY, a status bit) hear the switch's outcome."""
        adapter = self.adapter
        done: Callable[[bool, float], None] | None = getattr(adapter.node, "bit_timing_done", None)
        with adapter.engine_lock:
            if adapter.interface is not None and adapter.on_link is not None:
                adapter.on_link(problem, adapter.now)
            if done is not None:
                done(problem is None, adapter.now)
        adapter.pump_unless_closed()

    def status(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "bus_off": self.bus_off,
            "controller": "bus-off" if self.bus_off else self.state,
            "overruns": {kind: self.overruns[kind] for kind in OVERRUNS},
        }
        if self.adapter.interface is not None:
            out["link"] = self.adapter.interface.status()
        return out
