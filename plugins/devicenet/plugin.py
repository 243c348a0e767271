"""The ``devicenet`` front: a DeviceNet Group 2 Only slave on any python-can bus.

The sans-I/O :class:`~.engine.DeviceNetSlave` runs on the event loop through core's CAN
front base, shared with the canopen front (:class:`fieldgate.can.front.CanFront`: the bus,
receive path, timers, bus-off, bit-rate switching; configuration: :mod:`.config`). Input changes reach change-of-state
connections through a process-image subscription; I/O connection timeouts and releases
go to ``context.masters.lost`` with the outputs this front serves, a new allocation to
``masters.ok``. A duplicate MAC ID stops the slave (silent) and is logged and reported in
the front's status.
"""

from __future__ import annotations

from typing import Any, cast

from fieldgate.can.adapter import CanEngine
from fieldgate.can.front import CanFront
from fieldgate.events import FAULT
from fieldgate.health import HealthEvent, ModuleHealth
from fieldgate.host_watchdog import HostWatchdogs
from fieldgate.image import Change, Subscription
from fieldgate.metric_samples import Sample, counter, gauge, master_output_writes, state_gauges
from fieldgate.module_info import ModuleInfo
from fieldgate.plugin import GatewayContext, PluginStartError, Registry, hookimpl

from .assembly import Assemblies, plural
from .config import DeviceNetFrontConfig
from .engine import DeviceNetSlave
from .settings import BAUD_RATES, Settings
from .slave_state import DEVICE_STATES
from .store import NetworkStore

# receive counters of frames that were served (the other rx_ counters are frames dropped)
SERVED_COUNTERS = frozenset(
    {"rx_poll_outputs", "rx_poll_idle", "rx_cos_cyclic_outputs", "rx_cos_cyclic_idle"}
)
RS485_BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)  # the display's codes 0-7
CONNECTION_NAMES = ("explicit", "poll", "bit-strobe", "cos-cyclic", "cos-cyclic-data")


class DeviceNetFront(CanFront):
    def __init__(self, config: DeviceNetFrontConfig, context: GatewayContext):
        super().__init__(config, context)
        self.outputs: list[str] = []
        self._modules: set[tuple[str, int]] = set()
        self._offline: set[tuple[str, int]] = set()
        self._subscription: Subscription | None = None
        self._backs_subscribed = False

    @property
    def slave(self) -> DeviceNetSlave | None:
        """The running slave (None before start); :meth:`build` makes one."""
        return cast("DeviceNetSlave | None", self.engine)

    @slave.setter
    def slave(self, slave: DeviceNetSlave | None) -> None:
        self.engine = slave

    def build(self) -> DeviceNetSlave:
        cfg, ident = self.config, self.config.identity
        store = NetworkStore(
            self.context.state_file(cfg.store_file, f"{self.name}.devicenet.json"),
            (cfg.mac_id, BAUD_RATES.index(cfg.bitrate)),
        )
        mac_id, baud_code = store.load() or (cfg.mac_id, BAUD_RATES.index(cfg.bitrate))
        channels = self.context.front_channels(cfg)
        assemblies = Assemblies(self.context.image, channels, origin=f"{self.name}:devicenet")
        settings = Settings(
            mac_id=mac_id,
            baud_code=baud_code,
            vendor_id=ident.vendor_id,
            device_type=ident.device_type,
            product_code=ident.product_code,
            major_revision=ident.major_revision,
            minor_revision=ident.minor_revision,
            serial=ident.serial,
            product_name=ident.product_name,
            tolerate_trailing_bytes=not cfg.strict_lengths,
            dup_mac_interval_s=cfg.dup_mac_timeout_ms / 1000.0,
            io_paths=cfg.io_paths.selection(),
        )
        try:
            slave = DeviceNetSlave(settings, assemblies)
        except ValueError as exc:  # a path that names an assembly this front does not serve
            raise PluginStartError(str(exc)) from None
        self.outputs = assemblies.output_ids()
        self._modules = {(c.source.back, c.source.module) for c in channels}
        slave.module_errors = self._module_errors
        slave.host_watchdogs = HostWatchdogs.from_context(self.context)
        slave.module_info = ModuleInfo.from_context(self.context)
        slave.on_master(self._master_state)
        slave.on_settings(store.save)
        slave.on_fault(self._fault)
        return slave

    # -- life cycle (CanFront) -----------------------------------------------------------------
    def start_bitrate(self, engine: CanEngine) -> int | None:
        """The bit rate the network store kept (a baud rate set over DeviceNet), else the
        configuration's."""
        return cast(DeviceNetSlave, engine).bitrate

    def after_start(self, engine: CanEngine, bitrate: int | None) -> None:
        cfg, slave = self.config, cast(DeviceNetSlave, engine)
        for note in cfg.validation_warnings():
            self.log.warning("%s", note)
        self._subscription = self.context.image.subscribe_batch(
            self._inputs_changed, ids=slave.assemblies.input_ids()
        )
        if not self._backs_subscribed:
            self._backs_subscribed = True
            self.context.health.subscribe_backs(lambda *_: self._backs_changed())
        self._backs_changed()
        self.log.info(
            "DeviceNet MAC %d on %s/%s at %d bit/s: %s",
            slave.mac_id,
            cfg.interface,
            cfg.channel,
            slave.bitrate,
            "; ".join(
                f"{kind} {plural(path.produced_size)} in"
                + (f" (0x{path.produce.instance:02X})" if path.produce else "")
                + (
                    f", {plural(path.consumed_size)} out (0x{path.consume.instance:02X})"
                    if path.consume
                    else ""
                )
                for kind, path in slave.paths.items()
            ),
        )

    def before_stop(self) -> None:
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None

    def _inputs_changed(self, changes: list[Change]) -> None:
        """One batch of input changes (a poll reply): the slave hears of it once."""
        if self.adapter is None or self.slave is None:
            return
        if any(change.old_value != change.value for change in changes):
            adapter, slave = self.adapter, self.slave
            adapter.pump(lambda: slave.inputs_changed(adapter.now))

    def _backs_changed(self) -> None:
        """A back this front serves reports an error of its own (no module found): the Identity
        status's major recoverable fault, object 0x64's operation state ``1`` (the I-7241D's
        7-segment), the status API's ``back_fault`` and ``display``."""
        if self.slave is None:
            return
        errors = self.context.health.back_errors
        served = [b for b in self.context.front_backs(self.config) if b in errors]
        self.slave.back_fault = "; ".join(f"{b}: {errors[b]}" for b in served) or None

    def display(self) -> str:
        """The I-7241D's 7-segment display (seed-003 §1.4): operation state (``n`` / ``1``),
        MAC ID in hex, CAN baud code, the RS-485 baud code of the serial back served (``-``
        without one)."""
        assert self.slave is not None
        rs485 = "-"
        for back in self.context.topology.backs:
            baud = getattr(back, "baudrate", None)
            if back.name in self.context.front_backs(self.config) and baud in RS485_BAUDS:
                rs485 = str(RS485_BAUDS.index(baud))
                break
        slave = self.slave
        return f"{slave.operation_state}{slave.mac_id:02X}{slave.baud_code}{rs485}"

    def _fault(self, reason: str) -> None:
        self.log.error("DeviceNet communication fault: %s", reason)
        self.context.events.publish(FAULT, self.name, f"DeviceNet communication fault: {reason}")

    def on_bus_state(self, bus_off: bool, now: float) -> None:
        if bus_off and self.slave is not None:  # the DeviceNet object's bus-off counter
            self.slave.bus_off_count = min(255, self.slave.bus_off_count + 1)
        super().on_bus_state(bus_off, now)

    # -- the interface (CanFront) ------------------------------------------------------------
    def link_restart_ms(self) -> int | None:
        """0: the kernel never restarts the controller by itself; the DeviceNet object's BOI
        attribute decides (:meth:`bus_off_restart_s`)."""
        return 0

    def bus_off_restart_s(self) -> float | None:
        """ODVA's BOI (DeviceNet object attribute 3): 0 (the default) holds the controller in
        bus-off, 1 restarts it, ``restart_ms`` after bus-off, and communication continues."""
        if self.slave is None or not self.slave.bus_off_interrupt:
            return None
        return float(self.config.restart_ms) / 1000.0

    def link_problem(self, problem: str | None, now: float) -> None:
        """The interface not set as configured (a baud rate not applied): the Identity status's
        minor recoverable fault bit, the status API's ``link_fault``."""
        if self.slave is not None:
            self.slave.link_fault = problem

    def _master_state(self, ok: bool, reason: str) -> None:
        if ok:
            self.context.masters.ok(self.name, reason)
        else:
            self.context.masters.lost(self.name, reason, self.outputs)

    def _module_errors(self, back: str, address: int) -> int:
        try:
            return self.context.health.get(back, address).error_counter
        except KeyError:
            return 0

    def module_health(self, health: ModuleHealth, event: HealthEvent) -> None:
        if health.key not in self._modules or self.slave is None:
            return
        if event is HealthEvent.OFFLINE:
            self._offline.add(health.key)
        elif event is HealthEvent.ONLINE:
            self._offline.discard(health.key)
        self.slave.module_fault = bool(self._offline)

    def point_locations(self) -> dict[str, list[str]]:
        """Where each point is served: assembly instance, byte and bit, and its place in the
        I/O messages whose path carries that assembly (poll response / request, ...)."""
        if self.slave is None:
            return {}
        # category assembly instance -> [(message, offset)] for every path through it: the
        # poll's, and another connection's where its path differs from the poll's
        names = {
            "poll": ("poll response", "poll request"),
            "strobe": ("bit-strobe response", ""),
            "cos": ("COS message", "COS data from the master"),
            "cyclic": ("cyclic message", "cyclic data from the master"),
        }
        poll = self.slave.paths["poll"]
        carried: dict[int, list[tuple[str, int]]] = {}
        for kind, path in self.slave.paths.items():
            for assembly, polled, name in (
                (path.produce, poll.produce, names[kind][0]),
                (path.consume, poll.consume, names[kind][1]),
            ):
                if assembly is None or (kind != "poll" and assembly is polled):
                    continue
                offset = 0
                for part in assembly.members:
                    carried.setdefault(part.instance, []).append((name, offset))
                    offset += part.size
        out: dict[str, list[str]] = {}
        for assembly in self.slave.assemblies.categories:
            where = carried.get(assembly.instance, [])
            if assembly.kind.is_digital:
                for byte, slots in enumerate(assembly.slots):
                    at = ", ".join(f"{name} byte {offset + byte}" for name, offset in where)
                    for bit, ch in enumerate(slots):
                        if ch is not None:
                            out[ch.id] = [
                                f"assembly {assembly.instance} byte {byte} bit {bit}"
                                + (f" ({at})" if at else "")
                            ]
            else:
                for n, ch in enumerate(assembly.slots):
                    at = ", ".join(
                        f"{name} bytes {offset + 2 * n}-{offset + 2 * n + 1}"
                        for name, offset in where
                    )
                    out[ch.id] = [
                        f"assembly {assembly.instance} bytes {2 * n}-{2 * n + 1}"
                        + (f" ({at}, little-endian)" if at else " (little-endian)")
                    ]
        return out

    def metrics(self) -> list[Sample]:
        """Series for /metrics (contract: fieldgate.http.metrics), read from the engine's counters."""
        if self.slave is None:
            return []
        st = self.slave.status()
        connections = st.get("connections", {})
        samples = state_gauges(
            "devicenet_state",
            "1 for the state the DeviceNet node is in",
            DEVICE_STATES,
            st["state"],
        )
        for name in CONNECTION_NAMES:
            state = connections.get(name, {}).get("state", "non_existent")
            samples.append(
                gauge(
                    "devicenet_connection_established",
                    "1 while a predefined master/slave connection is established",
                    state == "established",
                    connection=name,
                )
            )
            samples.append(
                counter(
                    "devicenet_connection_timeouts_total",
                    "inactivity/watchdog timeouts of a connection",
                    st.get(f"{name}_timeouts", 0),
                    connection=name,
                )
            )
        ignored = sum(
            v
            for k, v in st.items()
            if k.startswith("rx_") and isinstance(v, int) and k not in SERVED_COUNTERS
        )
        return [
            *samples,
            master_output_writes(st.get("rx_poll_outputs", 0) + st.get("rx_cos_cyclic_outputs", 0)),
            counter(
                "devicenet_cos_cyclic_produced_total",
                "change-of-state / cyclic productions sent",
                st.get("cos_cyclic_produced", 0),
            ),
            counter(
                "devicenet_cip_errors_total",
                "explicit requests answered with a CIP error",
                st.get("cip_errors", 0),
            ),
            *self.bus_samples(ignored),
        ]

    def status(self) -> dict[str, Any]:
        if self.slave is None:
            return {}
        return {**self.slave.status(), "display": self.display(), **self.bus_status()}


@hookimpl
def fieldgate_register(registry: Registry) -> None:
    registry.add_front(
        "devicenet",
        DeviceNetFrontConfig,
        DeviceNetFront,
        "DeviceNet Group 2 Only slave on any python-can bus",
    )
    from .eds import register_eds

    register_eds(registry)
