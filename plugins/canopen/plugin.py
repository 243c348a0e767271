"""The ``canopen`` front: a CiA 301 slave on any python-can bus, serving the process image.

Start-up order: build the CiA 401 I/O device (:mod:`.front401`), build the node (identity,
EMCY, error control, SYNC, SDO, store, the PDO service over the I/O device's objects), add
CAN health, LSS and the I/O device, run the *node extensions* (:func:`add_node_extension`),
load the store, open the bus, boot. Master loss (life
guarding, heartbeat consumer, bus-off, and NMT Stopped with ``error_on_stopped``)
goes to ``context.masters.lost`` with the outputs this front serves, through one
owner (:class:`~.master_state.MasterState`); module health (offline / back online) raises and clears
the EMCY ``00 FF 81 0B <address> 00 00 00``.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable, Iterable
from functools import partial
from typing import Any, cast

from fieldgate.can.adapter import CanEngine
from fieldgate.can.frame import Frame
from fieldgate.can.front import CanFront
from fieldgate.events import CAN_OVERRUN, CAN_STATE, EMCY_SENT, NMT_STATE
from fieldgate.health import HealthEvent, ModuleHealth
from fieldgate.image import Channel, Quality, Subscription
from fieldgate.metric_samples import Sample, counter, gauge, master_output_writes, state_gauges
from fieldgate.plugin import GatewayContext, Registry, hookimpl

from .canhealth import CanHealth
from .cia301.builder import Identity, NodeSettings, build_node
from .cia301.nmt import NmtState
from .cia301.node import Node
from .cia305.lss import LssService, LssStore
from .cia401.iodevice import IoDevice
from .cia401.layouts import device_type as io_device_type
from .config import CanopenFrontConfig
from .device.config import CanopenDeviceConfig
from .device.front import DeviceFront, device_eds_for
from .eds import eds_for
from .front401 import io_device, io_settings
from .locations import point_locations
from .master_state import MasterState

MODULE_FAILURE_CODE = 0xFF00
MODULE_FAILURE_REGISTER = 0x81
# seed-000 §2.5: "COM port access error" (the I-7232D's RS-485 port); both styles, as the
# NA-9161's table is missing from its manual
COM_PORT_ERROR = (0x5000, 0x81, b"\x03")
# a back behind the front reports an error of its own (a DCON back that found no module: the
# I-7231D's "DCON modules init error"): ours, the next number of the same 0x5000 family
BACK_ERROR = (0x5000, 0x81, b"\x04")
# the 24 V field supply missing (the field_power input): CiA 301's 0x3300 "output voltage",
# error register bits generic and voltage (the NA-9161's field power LED; its table is missing)
FIELD_POWER_ERROR = (0x3300, 0x05, b"")

NodeExtension = Callable[["CanopenFront", Node], None]
_node_extensions: list[NodeExtension] = []


def add_node_extension(extension: NodeExtension) -> None:
    """Register ``extension(front, node)``, run for every canopen front before boot.

    This is where a service of another package adds itself: the node's dictionary then
    has its objects when the store is loaded and the node boots.
    """
    if extension not in _node_extensions:
        _node_extensions.append(extension)


class CanopenFront(CanFront):
    def __init__(self, config: CanopenFrontConfig, context: GatewayContext):
        super().__init__(config, context)
        self.outputs: list[str] = []
        self.master: MasterState | None = None
        self.io: IoDevice | None = None
        self._modules: set[tuple[str, int]] = set()
        self._ports_subscribed = False
        self.field_power: bool | None = None  # None: not sensed (no field_power), or not read yet
        self._field_power_sub: Subscription | None = None

    @property
    def node(self) -> Node | None:
        """The running node (None before start); :meth:`build` makes one."""
        return cast("Node | None", self.engine)

    # -- assembling ---------------------------------------------------------------------
    def fingerprint(self, channels: Iterable[Channel]) -> str:
        text = "\n".join(f"{c.id}:{c.kind.value}" for c in channels)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def build(self) -> Node:
        cfg = self.config
        profile = cfg.profile
        channels = self.context.front_channels(cfg)
        self.field_power = None  # read again into this node (and its 0x4500)
        self.io = io = io_device(self)
        node = build_node(self._node_settings(channels, io), name=self.name)
        if profile.style.controller_emcy:
            node.add_service(CanHealth(profile.style.controller_emcy))
        node.add_service(
            LssService(
                bitrate=cfg.bitrate if isinstance(cfg.bitrate, int) else None,
                table=cfg.lss_table,
                store=LssStore(
                    self.context.state_file(cfg.lss_store_file, f"{self.name}.lss.json")
                ),
            )
        )
        node.add_service(io)
        for extension in list(_node_extensions):
            extension(self, node)
        node.service("store").load()
        self.outputs = [c.id for c in channels if c.kind.is_output]
        self._modules = {(c.source.back, c.source.module) for c in channels}
        self.master = MasterState(
            self.context.masters,
            self.name,
            self.outputs,
            stopped_is_error=io_settings(cfg).stopped_is_error,
        )
        self.master.attach(node)
        node.on_nmt(self._nmt_changed)
        if node.emcy is not None:
            node.emcy.on_sent = self._emcy_sent
        return node

    def _node_settings(self, channels: list[Channel], io: IoDevice) -> NodeSettings:
        """The CiA 301 node of this configuration: its style's and master profile's defaults
        under the topology's keys (:mod:`.profiles`), the PDOs over the I/O device's objects."""
        cfg = self.config
        profile = cfg.profile
        device_type = cfg.identity.device_type
        if device_type is None:
            device_type = io_device_type({c.kind for c in channels})
        ident = cfg.identity
        return NodeSettings(
            node_id=cfg.node_id,
            identity=Identity(
                device_type,
                ident.vendor_id,
                ident.product_code,
                ident.revision,
                ident.serial,
                ident.device_name,
                ident.hardware_version,
                ident.software_version,
            ),
            heartbeat_ms=profile.heartbeat_ms,
            guard_time_ms=profile.guard_time_ms,
            life_time_factor=profile.life_time_factor,
            heartbeat_consumers=profile.heartbeat_consumers,
            consumer_heartbeats=tuple(e.value for e in profile.consumer_entries),
            emcy_history=profile.emcy_history,
            emcy_queue=profile.emcy_queue,
            emcy_on_nmt_reset=profile.emcy_on_nmt_reset,
            error_behaviour=("pre-operational", "no-change", "stopped").index(
                profile.on_master_lost
            ),
            sync_loss_error_event=profile.sync_loss == "error-event",
            sdo_timeout_s=cfg.sdo_timeout_ms / 1000.0,
            sdo_block_size=cfg.sdo_block_size,
            sdo_zero_extend=profile.sdo_zero_extend,
            sdo_servers=cfg.sdo_servers,
            sync_cob_id=cfg.sync_cob_id,
            store_path=self.context.state_file(cfg.store_file, f"{self.name}.canopen.json"),
            fingerprint=self.fingerprint(channels),
            announce_defaults=profile.style.hw_config_emcy_unsaved,
            keep_node_id_entries=profile.style.stored_cob_ids_kept,
            pdo=io.pdo_config,
        )

    # -- events for people watching (fieldgate.events) -----------------------------------
    def _nmt_changed(self, old: NmtState, new: NmtState) -> None:
        self.context.events.publish(
            NMT_STATE, self.name, f"NMT {old.label} -> {new.label}", old=old.label, new=new.label
        )

    def _emcy_sent(self, frame: Frame) -> None:
        data = frame.data
        code = int.from_bytes(data[0:2], "little")
        self.context.events.publish(
            EMCY_SENT,
            self.name,
            f"EMCY {code:04X} register {data[2]:02X} data {data[3:].hex(' ').upper()}",
            code=f"{code:04X}",
            register=data[2],
            data=data[3:].hex(),
        )

    def _can_health(self) -> CanHealth | None:
        """The node's CAN health service (None: no node, or a style without controller EMCYs)."""
        if self.node is None:
            return None
        try:
            return cast(CanHealth, self.node.service("can_health"))
        except KeyError:
            return None

    def _controller(self, event: str, now: float) -> None:
        """The adapter saw the CAN controller's error state change, or frames lost."""
        if self.node is None:
            return
        health = self.node.service("can_health")
        if event.endswith("-overrun"):
            kind = event.removesuffix("-overrun")
            if health.overrun(kind, now):  # an event per overrun error, not per lost frame
                self.context.events.publish(
                    CAN_OVERRUN, self.name, f"CAN {kind} overrun: frames lost", overrun=kind
                )
        else:
            self.context.events.publish(
                CAN_STATE, self.name, f"CAN controller {event}", state=event
            )
            health.controller(event, now)

    def on_bus_state(self, bus_off: bool, now: float) -> None:
        super().on_bus_state(bus_off, now)
        if self.node is not None:
            self.node.service("error_control").bus_state(bus_off, now)

    def link_problem(self, problem: str | None, now: float) -> None:
        """The interface not set as configured (at start, at an LSS bit-rate switch): EMCY
        ``00 81 11 0D`` while so (docs/can-link.md)."""
        health = self._can_health()
        if health is not None:
            health.link(problem, now)

    # -- life cycle (CanFront) -----------------------------------------------------------------
    def start_bitrate(self, engine: CanEngine) -> int | None:
        """The bit rate LSS stored, else the configuration's."""
        bitrate: int | None = cast(Node, engine).service("lss").bitrate
        configured = self.config.bitrate
        return bitrate or (configured if isinstance(configured, int) else None)

    def wants_autobaud(self, engine: CanEngine) -> bool:
        """``bitrate: auto`` and no rate stored by LSS: listen for the bus's rate before boot-up."""
        return self.config.bitrate == "auto" and not cast(Node, engine).service("lss").bitrate

    def found_bitrate(self, engine: CanEngine, bitrate: int | None) -> None:
        """The rate auto-baud found is the one LSS reports and stores."""
        lss = cast(Node, engine).service("lss")
        if lss.slave is not None:
            lss.slave.bitrate = bitrate

    def adapter_options(self, engine: CanEngine) -> dict[str, Any]:
        lss = cast(Node, engine).service("lss")
        return {"on_controller": self._controller, "transmit_allowed": lss.transmit_allowed}

    def watches_modules(self) -> bool:
        return bool(self.config.module_emcy)

    def after_start(self, engine: CanEngine, bitrate: int | None) -> None:
        cfg, node = self.config, cast(Node, engine)
        if cfg.module_emcy:  # modules offline before this node booted (a port missing at start)
            for health in self.context.health.modules():
                if health.key in self._modules and not health.online:
                    self.module_health(health, HealthEvent.OFFLINE)
        if not self._ports_subscribed:
            self._ports_subscribed = True
            self.context.health.subscribe_ports(lambda *_: self._ports_changed())
            self.context.health.subscribe_backs(lambda *_: self._backs_changed())
        self._ports_changed()  # a port already missing (the front restarted meanwhile)
        self._backs_changed()
        if cfg.field_power is not None and self._field_power_sub is None:
            self._field_power_sub = self.context.image.subscribe_batch(
                lambda _: self._field_power_changed(), ids=[cfg.field_power]
            )
        self._field_power_changed()
        self.log.info(
            "CANopen node %s on %s/%s at %s bit/s",
            node.node_id if node.configured else "unconfigured",
            cfg.interface,
            cfg.channel,
            bitrate,
        )

    # -- module health ------------------------------------------------------------------
    def module_health(self, health: ModuleHealth, event: HealthEvent) -> None:
        if (
            self.node is None
            or self.node.emcy is None
            or health.key not in self._modules
            or not 0 <= health.address <= 255
        ):
            return
        manufacturer, emcy = bytes([0x0B, health.address]), self.node.emcy
        if event is HealthEvent.OFFLINE:
            action = partial(
                emcy.raise_error, MODULE_FAILURE_CODE, MODULE_FAILURE_REGISTER, manufacturer
            )
        elif event is HealthEvent.ONLINE:
            action = partial(emcy.clear_error, MODULE_FAILURE_CODE, manufacturer)
        else:
            return
        self.pump(action)

    # -- serial ports of the backs behind this front ------------------------------------------
    def _ports_changed(self) -> None:
        """EMCY "COM port access error" (00 50 81 03) while a port of a back whose modules
        this front serves is missing; its error reset when every such port is open again."""
        if self.node is None or self.node.emcy is None:
            return
        lost = self.context.health.ports_lost
        self._error_while(COM_PORT_ERROR, any(b in lost for b in self._backs()))

    def _backs_changed(self) -> None:
        """EMCY ``00 50 81 04`` (with 0x1001) while a back this front serves reports an error of
        its own (a ``modules: auto`` DCON back that found no module), its reset when none does."""
        errors = self.context.health.back_errors
        self._error_while(BACK_ERROR, any(b in errors for b in self._backs()))

    def _field_power_changed(self) -> None:
        """The ``field_power`` input: false with good quality, or its module offline (the
        modules usually hang on the same supply), is "field power missing"; not read yet is
        not known. Missing: 0x4500:1 byte 3 = 0x80 (na9161) and EMCY ``00 33 05``."""
        cid = self.config.field_power
        if cid is None or cid not in self.context.image:
            return
        channel = self.context.image[cid]
        if channel.quality is Quality.GOOD:
            present: bool | None = bool(channel.value)
        elif channel.quality is Quality.COMM_FAULT:
            present = False
        else:
            present = self.field_power  # not read yet, stale: as known before
        if present is None or present == self.field_power:
            return
        self.field_power = present
        self.log.log(
            logging.INFO if present else logging.WARNING,
            "field power %s (%s)",
            "present" if present else "missing",
            cid,
        )
        if self.io is not None and self.io.fnbus is not None:
            self.io.fnbus.field_power_missing = not present
        self._error_while(FIELD_POWER_ERROR, not present)

    def before_stop(self) -> None:
        if self._field_power_sub is not None:
            self._field_power_sub.cancel()
            self._field_power_sub = None

    def _backs(self) -> list[str]:
        """The backs this front serves, with or without channels yet."""
        return self.context.front_backs(self.config)

    def _error_while(self, error: tuple[int, int, bytes], active: bool) -> None:
        if self.node is None or self.node.emcy is None:
            return
        emcy = self.node.emcy
        code, register, manufacturer = error
        if active:
            self.pump(partial(emcy.raise_error, code, register, manufacturer))
        else:
            self.pump(partial(emcy.clear_error, code, manufacturer))

    def point_locations(self) -> dict[str, list[str]]:
        """Where each point is served: CiA 401 object/sub and PDO byte/bit (status API)."""
        io = self.io
        if io is None:
            return {}
        engine = io.engine
        pdos = (engine.tpdos + engine.rpdos) if engine is not None else []
        return point_locations(io.layout, pdos)

    def metrics(self) -> list[Sample]:
        """Series for /metrics (contract: fieldgate.http.metrics), read from the node's counters."""
        if self.node is None:
            return []
        node_status = self.node.status()
        services = node_status["services"]
        pdo, emcy, sdo = (services.get(name, {}) for name in ("pdo", "emcy", "sdo"))
        losses = self.master.status().get("losses", 0) if self.master else 0
        ignored = node_status["counters"].get("ignored", 0) + pdo.get("frames_ignored", 0)
        return [
            *state_gauges(
                "canopen_nmt_state",
                "1 for the NMT state the node is in",
                [state.label for state in NmtState],
                self.node.state.label,
            ),
            counter("canopen_emcy_sent_total", "EMCY frames sent", emcy.get("sent", 0)),
            gauge("canopen_emcy_active", "EMCY errors active now", len(emcy.get("active", []))),
            counter("canopen_sdo_requests_total", "SDO requests served", sdo.get("requests", 0)),
            counter(
                "canopen_sdo_aborts_total",
                "SDO transfers aborted by the server",
                sdo.get("aborts", 0),
            ),
            counter("canopen_tpdo_sent_total", "TPDOs sent", pdo.get("tpdo_sent", 0)),
            master_output_writes(pdo.get("rpdo_received", 0)),
            counter(
                "master_losses_total",
                "times the front lost its master (guarding, heartbeat, bus-off, ...)",
                losses,
            ),
            *self.bus_samples(ignored),
            *(
                [
                    gauge(
                        "canopen_field_power",
                        "1 while the field supply is present",
                        self.field_power,
                    )
                ]
                if self.field_power is not None
                else []
            ),
        ]

    def status(self) -> dict[str, Any]:
        if self.node is None:
            return {}
        return {
            **self.node.status(),
            "master": self.master.status() if self.master else None,
            "field_power": self.field_power,
            **self.bus_status(),
        }


@hookimpl
def fieldgate_register(registry: Registry) -> None:
    registry.add_front(
        "canopen", CanopenFrontConfig, CanopenFront, "CANopen CiA 301 slave on any python-can bus"
    )
    registry.add_eds("canopen", eds_for)
    registry.add_front(
        "canopen-device",
        CanopenDeviceConfig,
        DeviceFront,
        "CANopen device of your own: any EDS/DCF, Python hooks, process-image bindings",
    )
    registry.add_eds("canopen-device", device_eds_for)
