"""The base of every front on a CAN bus: the bus settings, the adapter, run/stop, module
health and the engine's wake-ups.

A CAN front is a sans-I/O engine (:class:`~.adapter.CanEngine`: ``boot``, ``receive``,
``tick``, ``flush``, ``next_deadline``, ``on_bit_timing``; ``listen_ids()`` for the
acceptance filters, ``quick_answer()`` for reads answered on the receive thread,
``on_wake(callback)`` for work queued from outside its calls) and a front class that
builds it. :class:`CanFront` does the rest, the same way for the CANopen and DeviceNet
fronts and for a third party's (docs/plugins.md, "A CAN front"):

* :meth:`CanFront.start` builds the engine (:meth:`~CanFront.build`), opens the bus with the
  configuration's ``interface``/``channel``/``bitrate``/``bus_options``
  (:class:`CanBusConfig`; :meth:`~CanFront.start_bitrate` may choose another rate, as LSS
  does), binds the engine to it (:class:`~.adapter.CanAdapter`: receive path, timers,
  filters, bus-off, bit-rate switches) and boots it;
* :meth:`CanFront.run` returns only when receiving from the bus has died (the runtime then
  restarts the front); :meth:`CanFront.stop` closes the bus;
* module health: :meth:`~CanFront.module_health` hears every module's offline/online
  events (subscribed once, however often the front restarts);
* bus-off and its recovery are published as gateway events (:meth:`~CanFront.on_bus_state`);
* wake-ups: work the engine queued outside its own calls (a TPDO for a changed input, an
  EMCY for a module gone offline) runs in the next loop turn, once however many wake-ups
  that turn brings (:meth:`~CanFront.wakeup`), never postponed further;
* :meth:`~CanFront.pump` runs an action on the engine and sends what it queued;
  :meth:`~CanFront.bus_status` and :meth:`~CanFront.bus_samples` are the bus's part of the
  front's ``status()`` and ``metrics()``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any, Literal

import can
from pydantic import Field

from fieldgate.events import BUS_OFF, BUS_ON
from fieldgate.health import HealthEvent, ModuleHealth
from fieldgate.metric_samples import Sample
from fieldgate.plugin import Front, GatewayContext
from fieldgate.topology.model import StrictModel

from .adapter import CanAdapter, CanEngine, open_bus
from .autobaud import AutoBaud
from .busmetrics import can_bus_samples
from .interface import InterfaceControl, controls


class CanBusConfig(StrictModel):
    """The bus of a CAN front: what python-can's ``can.Bus`` gets (a front narrows
    ``bitrate`` to the rates its protocol knows)."""

    interface: str = Field(
        "socketcan",
        description="python-can interface: socketcan, virtual, pcan, kvaser, slcan, ...",
    )
    channel: str | None = Field(
        "can0",
        description="python-can channel (can0, vcan0, PCAN_USBBUS1, a virtual channel name, ...)",
    )
    bitrate: int | Literal["auto"] | None = Field(
        125_000,
        description="CAN bit rate in bit/s (SocketCAN: set on the interface; other interfaces: passed to can.Bus); auto: found by listening before the engine boots (SocketCAN); null for an interface configured outside fieldgate",
    )
    bus_options: dict[str, Any] = Field(
        default_factory=dict, description="extra keyword arguments for can.Bus"
    )
    sample_point: float | None = Field(
        None,
        gt=0.5,
        lt=1.0,
        description="SocketCAN: the sample point set with the bit rate (e.g. 0.875); null: the kernel's (CiA's 87.5 % up to 800 kbit/s)",
    )
    restart_ms: int = Field(
        100,
        ge=0,
        le=60_000,
        description="bus-off recovery: the controller restarts this long after bus-off, by the kernel (ip link restart-ms) where fieldgate configures the interface, else by the front",
    )
    configure_interface: bool = Field(
        True,
        description="SocketCAN: apply bitrate, sample_point and restart_ms to the interface at start and at a protocol's bit-rate switch (needs CAP_NET_ADMIN); false where systemd-networkd or ip link owns it",
    )


class CanFront(Front):
    """A front whose engine speaks on a CAN bus; its configuration has :class:`CanBusConfig`'s fields."""

    def __init__(self, config: Any, context: GatewayContext):
        super().__init__(config, context)
        self.engine: CanEngine | None = None
        self.adapter: CanAdapter | None = None
        self._health_subscribed = False
        self._wake_scheduled = False
        cfg = self.config
        self.interface: InterfaceControl | None = (
            InterfaceControl(
                cfg.channel,
                cfg.sample_point,
                self.link_restart_ms(),
                managed=cfg.configure_interface,
            )
            if controls(cfg.interface, cfg.channel)
            else None
        )
        self.autobaud: AutoBaud | None = None
        self._opening: asyncio.Future[None] | None = None  # auto-baud, then the bus opens

    # -- what a CAN front says ----------------------------------------------------------------
    def build(self) -> CanEngine:
        """The front's engine, ready to boot (also called without a bus: ``fieldgate eds``)."""
        raise NotImplementedError

    def start_bitrate(self, engine: CanEngine) -> int | None:
        """The bit rate the bus opens at: the configuration's."""
        bitrate = self.config.bitrate
        return bitrate if isinstance(bitrate, int) else None

    def adapter_options(self, engine: CanEngine) -> dict[str, Any]:
        """More keyword arguments for :class:`~.adapter.CanAdapter` (``on_controller``,
        ``transmit_allowed``)."""
        return {}

    def watches_modules(self) -> bool:
        """Whether :meth:`module_health` hears the modules' health events."""
        return True

    def module_health(self, health: ModuleHealth, event: HealthEvent) -> None:
        """A module went offline, came back, had its error counter cleared."""

    def on_bus_state(self, bus_off: bool, now: float) -> None:
        """The controller went bus-off, or recovered: a gateway event."""
        if bus_off:
            self.context.events.publish(BUS_OFF, self.name, "CAN bus-off")
        else:
            self.context.events.publish(BUS_ON, self.name, "CAN bus recovered from bus-off")

    def after_start(self, engine: CanEngine, bitrate: int | None) -> None:
        """The engine booted on the bus: subscriptions of the front's own, its log line."""

    def before_stop(self) -> None:
        """Before the bus closes: cancel what :meth:`after_start` subscribed."""

    # -- the interface (SocketCAN, docs/can-link.md) --------------------------------------------
    def link_restart_ms(self) -> int | None:
        """The restart-ms set on the interface with the bit rate: the configuration's (the kernel
        restarts the controller after bus-off)."""
        restart_ms: int = self.config.restart_ms
        return restart_ms

    def bus_off_restart_s(self) -> float | None:
        """Where the kernel does not restart a bus-off controller (restart-ms 0): how long the
        front waits before it restarts it; None: the controller stays bus-off."""
        return float(self.config.restart_ms) / 1000.0

    def link_problem(self, problem: str | None, now: float) -> None:
        """The interface could not be set as configured (``problem``: the one line why; the
        node runs with the interface as it is), or, None, it is as configured now. A front
        shows it the way its device would (an EMCY, a status bit)."""

    def wants_autobaud(self, engine: CanEngine) -> bool:
        """Whether the bit rate is found by listening (:mod:`.autobaud`) before the engine boots:
        ``bitrate: auto``."""
        return bool(self.config.bitrate == "auto")

    def found_bitrate(self, engine: CanEngine, bitrate: int | None) -> None:
        """Auto-baud ended: the engine learns the rate found (None: none, the bus opens as it is)."""

    # -- life cycle ---------------------------------------------------------------------------
    def open_bus(self, bitrate: int | None) -> can.BusABC:
        cfg = self.config
        return open_bus(cfg.interface, cfg.channel, bitrate, cfg.bus_options)

    async def start(self) -> None:
        self.engine = engine = self.build()
        if self.wants_autobaud(engine):
            # the rate is found by listening first; run() opens the bus and boots the engine
            self.autobaud = AutoBaud(self.config.channel or "", self.interface)
            self._opening = asyncio.ensure_future(self._autobaud_then_open(engine))
            return
        await self._open(engine, self.start_bitrate(engine))

    async def _autobaud_then_open(self, engine: CanEngine) -> None:
        assert self.autobaud is not None
        bitrate = await self.autobaud.run(self.log)
        self.found_bitrate(engine, bitrate)
        await self._open(engine, bitrate)

    async def _open(self, engine: CanEngine, bitrate: int | None) -> None:
        """Set the interface (where fieldgate controls it), open the bus, boot the engine."""
        loop = asyncio.get_running_loop()
        problem = None
        if self.interface is not None and bitrate is not None:
            problem = await self.interface.apply(bitrate)
            if problem is not None:
                self.log.error("%s; the node runs with the interface as it is", problem)
        self.adapter = CanAdapter(
            engine,
            self.open_bus(bitrate),
            loop,
            on_bus_state=self.on_bus_state,
            reopen=self.open_bus,
            interface=self.interface,
            bus_off_restart=self.bus_off_restart_s,
            on_link=self.link_problem,
            **self.adapter_options(engine),
        )
        self.adapter.start()
        on_wake: Callable[[Callable[[], None]], None] | None = getattr(engine, "on_wake", None)
        if on_wake is not None:
            on_wake(self.wakeup)
        if self.watches_modules() and not self._health_subscribed:
            self._health_subscribed = True
            self.context.health.subscribe(self.module_health)
        self.after_start(engine, bitrate)
        if self.interface is not None:
            self.pump(lambda: self.link_problem(problem, loop.time()))

    async def run(self) -> None:
        """Everything is callback-driven; raises only when receiving from the bus has died."""
        if self._opening is not None:
            opening, self._opening = self._opening, None
            await opening
        if self.adapter is None:
            raise RuntimeError(f"front {self.name}: run() before start()")
        await self.adapter.failed

    async def stop(self) -> None:
        if self._opening is not None:
            self._opening.cancel()
            await asyncio.gather(self._opening, return_exceptions=True)
            self._opening = None
        if self.autobaud is not None:
            self.autobaud.stop()
        self.before_stop()
        if self.adapter is not None:
            self.adapter.close()
            self.adapter = None

    # -- the engine from outside its calls -----------------------------------------------------
    def wakeup(self) -> None:
        """Work queued from outside the engine's calls: one engine run in the next loop turn,
        however many wake-ups this turn brings, never postponed further."""
        if not self._wake_scheduled:
            self._wake_scheduled = True
            asyncio.get_running_loop().call_soon(self._run_engine)

    def _run_engine(self) -> None:
        self._wake_scheduled = False
        if self.adapter is not None:
            self.adapter.run_engine()

    def pump(self, action: Callable[[], object]) -> None:
        """Run ``action`` on the engine and send what it queued (before the bus is open: only
        run it; the boot sends it)."""
        if self.adapter is not None:
            self.adapter.pump(action)
        else:
            action()

    # -- status -------------------------------------------------------------------------------
    def bus_status(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "bus": self.adapter.status() if self.adapter else None,
            "interface": self.config.interface,
            "channel": self.config.channel,
        }
        if self.autobaud is not None:
            out["autobaud"] = self.autobaud.status()
        if self.adapter is None and self.interface is not None:  # (the adapter's status has it)
            out["link"] = self.interface.status()
        return out

    def bus_samples(self, ignored: int) -> list[Sample]:
        """The bus's series for /metrics; ``ignored``: frames the engine had no use for."""
        return can_bus_samples(self.adapter.status() if self.adapter else None, ignored)
