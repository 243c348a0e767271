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

import asyncio
import hashlib
from collections.abc import Callable, Iterable
from functools import partial
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from fieldgate import __version__
from fieldgate.can.adapter import CanAdapter, open_bus
from fieldgate.can.busmetrics import can_bus_samples
from fieldgate.can.frame import Frame
from fieldgate.events import BUS_OFF, BUS_ON, CAN_OVERRUN, CAN_STATE, EMCY_SENT, NMT_STATE
from fieldgate.health import HealthEvent, ModuleHealth
from fieldgate.image import Channel
from fieldgate.metric_samples import Sample, counter, gauge, master_output_writes, state_gauges
from fieldgate.plugin import Front, GatewayContext, Registry, hookimpl
from fieldgate.topology import FrontConfig
from fieldgate.topology.model import StrictModel

from .canhealth import CanHealth
from .cia301.builder import Identity, NodeSettings, build_node
from .cia301.cobid import restricted
from .cia301.nmt import NmtState
from .cia301.node import Node
from .cia305.lss import BIT_TIMING_TABLES, LssService, LssStore
from .cia401.iodevice import IoDevice
from .cia401.layouts import device_type as io_device_type
from .eds import eds_for
from .front401 import IoFrontOptions, check_io, io_device, io_settings
from .locations import point_locations
from .master_state import MasterState
from .profiles import (
    AnalogEvents,
    MasterLost,
    MasterName,
    Resolved,
    SyncLoss,
    node_id_problem,
    resolve,
)

MODULE_FAILURE_CODE = 0xFF00
MODULE_FAILURE_REGISTER = 0x81
# seed-000 §2.5: "COM port access error" (the I-7232D's RS-485 port); both styles, as the
# NA-9161's table is missing from its manual
COM_PORT_ERROR = (0x5000, 0x81, b"\x03")

NodeExtension = Callable[["CanopenFront", Node], None]
_node_extensions: list[NodeExtension] = []


def add_node_extension(extension: NodeExtension) -> None:
    """Register ``extension(front, node)``, run for every canopen front before boot.

    This is where a service of another package adds itself: the node's dictionary then
    has its objects when the store is loaded and the node boots.
    """
    if extension not in _node_extensions:
        _node_extensions.append(extension)


def _invalid(message: str, loc: tuple[str, ...]) -> PydanticCustomError:
    """A validation error reported at ``loc`` below the front, with our message alone."""
    return PydanticCustomError(
        "canopen_config", message.replace("{", "{{").replace("}", "}}"), {"loc": loc}
    )


class ConsumerHeartbeat(StrictModel):
    node: int = Field(ge=1, le=127, description="node-ID whose heartbeat is watched")
    time_ms: int = Field(
        ge=1, le=65535, description="consumer time: longer than that node's producer time"
    )


class IdentitySettings(StrictModel):
    device_type: int | None = Field(
        None,
        ge=0,
        le=0xFFFFFFFF,
        description="0x1000; default 0x0191 (CiA 401) with bits 16-19 set for DI/DO/AI/AO present",
    )
    vendor_id: int = Field(0, ge=0, le=0xFFFFFFFF, description="0x1018:1 (also the LSS address)")
    product_code: int = Field(0, ge=0, le=0xFFFFFFFF, description="0x1018:2")
    revision: int = Field(0, ge=0, le=0xFFFFFFFF, description="0x1018:3")
    serial: int = Field(0, ge=0, le=0xFFFFFFFF, description="0x1018:4")
    device_name: str = Field(
        "fieldgate", max_length=255, description="0x1008 manufacturer device name"
    )
    hardware_version: str = Field("", max_length=255, description="0x1009")
    software_version: str = Field(f"fieldgate {__version__}", max_length=255, description="0x100A")


CIA_BITRATES = tuple(sorted(set().union(*(table.values() for table in BIT_TIMING_TABLES.values()))))


class CanopenFrontConfig(FrontConfig, IoFrontOptions):
    type: Literal["canopen"] = "canopen"
    interface: str = Field(
        "socketcan",
        description="python-can interface: socketcan, virtual, pcan, kvaser, slcan, ...",
    )
    channel: str | None = Field(
        "can0",
        description="python-can channel (can0, vcan0, PCAN_USBBUS1, a virtual channel name, ...)",
    )
    bitrate: int | None = Field(
        125_000,
        description="CAN bit rate in bit/s, one of CiA 301's (passed to can.Bus; LSS may change it); null for an interface configured outside fieldgate",
    )
    bus_options: dict[str, Any] = Field(
        default_factory=dict, description="extra keyword arguments for can.Bus"
    )
    node_id: int | None = Field(
        ...,
        ge=1,
        le=127,
        description="node-ID 1..127, required (a real device has a switch; no value is safe on every bus); null = unconfigured, wait for LSS",
    )
    master: MasterName = Field(
        "generic",
        description="master profile: what the PLC requires of its slaves; delta-as300 = heartbeat only, a 0x1016 entry watching the master, node-ID 1..64 and not the master's",
    )
    master_node_id: int | None = Field(
        None,
        ge=1,
        le=127,
        description="the master's node-ID; default: the master profile's (delta-as300: 1, generic: none)",
    )
    heartbeat_ms: int | None = Field(
        None,
        ge=0,
        le=65535,
        description="0x1017 producer heartbeat time default (0 = off); default: the style's (na9161 0, icpdas no 0x1017: guarding only), 1000 with master delta-as300; null = no 0x1017",
    )
    guard_time_ms: int | None = Field(
        None,
        ge=0,
        le=32767,
        description="0x100C guard time default; default 0 (icpdas), 200 (na9161)",
    )
    life_time_factor: int | None = Field(
        None,
        ge=0,
        le=255,
        description="0x100D life time factor default; default 0 (icpdas), 2 (na9161)",
    )
    heartbeat_consumers: int | None = Field(
        None,
        ge=0,
        le=127,
        description="number of 0x1016 heartbeat consumer entries; default: the style's (icpdas 0, na9161 1), at least the consumer_heartbeats given",
    )
    consumer_heartbeats: list[ConsumerHeartbeat] = Field(
        default_factory=list,
        description="0x1016 defaults, in order: the heartbeats this node watches; default: the master's heartbeat with master delta-as300 (node 1, 500 ms)",
    )
    on_master_lost: MasterLost | None = Field(
        None,
        description="0x1029:1 default: NMT state change on life guarding / heartbeat timeout / bus-off; default no-change (icpdas), pre-operational (na9161)",
    )
    error_mode_default: Literal["hold", "zero"] | None = Field(
        None,
        description="outputs whose module sets no error_mode: hold (icpdas: 0x6206/0x6443 = 0) or go to 0 (na9161: 0x6206 = 0xFF, 0x6207 = 0, 0x6443 = 1, 0x6444 = 0)",
    )
    analog_events: AnalogEvents | None = Field(
        None,
        description="change: every AI change is a TPDO event, no 0x6421-0x6426 (na9161); interrupt: only with 0x6423 and 0x6421 (icpdas, default FALSE: analog changes send no TPDO)",
    )
    sync_loss: SyncLoss | None = Field(
        None,
        description="SYNC lost (0x1006): emcy = EMCY 0x8100 only (icpdas); error-event = also outputs to their error values and 0x1029 (na9161)",
    )
    sync_cob_id: int = Field(0x80, ge=1, le=0x7FF, description="0x1005 default SYNC COB-ID")
    emcy_on_nmt_reset: bool | None = Field(
        None,
        description="send EMCY 00 FF 80 0A 00 00 00 00 before an NMT reset node/communication; default true (icpdas, as the I-7232D/I-7231D), false (na9161)",
    )
    emcy_history: int | None = Field(
        None,
        ge=5,
        le=254,
        description="depth of the 0x1003 pre-defined error field; default 5 (icpdas), 20 (na9161)",
    )
    emcy_queue: int | None = Field(
        None,
        ge=1,
        le=254,
        description="EMCYs held back by the 0x1015 inhibit time; an overflow sends the overrun EMCY at once; default 16 (icpdas), 20 (na9161)",
    )
    sdo_timeout_ms: int = Field(
        1000, ge=10, le=60_000, description="server-side SDO transfer timeout"
    )
    sdo_block_size: int = Field(127, ge=1, le=127, description="block size the SDO server offers")
    sdo_zero_extend: bool | None = Field(
        None,
        description="accept expedited writes shorter than an unsigned object and zero-extend them; default true (na9161: its examples write U32 with 2 bytes), false (icpdas: abort 0607 0013)",
    )
    sdo_servers: int = Field(
        1,
        ge=1,
        le=128,
        description="SDO server channels: 1 = only 0x1200; N adds 0x1201..0x1200+N-1, each invalid until its COB-IDs are written",
    )
    store_file: str | None = Field(
        None,
        description="0x1010/0x1011 store file (relative to the state dir); default <front name>.canopen.json",
    )
    lss_table: Literal["cia", "i7232d"] = Field(
        "cia", description="LSS bit-timing table: CiA 305, or the I-7232D's own"
    )
    lss_store_file: str | None = Field(
        None,
        description="LSS store file (relative to the state dir); default <front name>.lss.json",
    )
    module_emcy: bool = Field(
        True, description="send EMCY 00 FF 81 0B <address> when a served module goes offline"
    )
    identity: IdentitySettings = Field(default_factory=IdentitySettings)

    @field_validator("bitrate")
    @classmethod
    def _standard_bitrate(cls, value: int | None) -> int | None:
        if value is not None and value not in CIA_BITRATES:
            raise ValueError(
                f"expected one of the CiA 301 bit rates {', '.join(map(str, CIA_BITRATES))} bit/s, "
                f"or null when the interface's own configuration sets it"
            )
        return value

    @model_validator(mode="after")
    def _profile_checks(self) -> CanopenFrontConfig:
        problem = node_id_problem(self)
        if problem is not None:
            raise _invalid(problem, ("node_id",))
        entries = [e.node for e in self.consumer_heartbeats]
        if len(set(entries)) != len(entries):
            raise _invalid(
                "each node-ID once: CiA 301 refuses two 0x1016 entries for one node",
                ("consumer_heartbeats",),
            )
        if self.heartbeat_consumers is not None and len(entries) > self.heartbeat_consumers:
            raise _invalid(
                f"{len(entries)} consumer_heartbeats need at least {len(entries)} entries",
                ("heartbeat_consumers",),
            )
        return self

    @property
    def profile(self) -> Resolved:
        """The style's defaults, the master profile's requirements and this topology's keys."""
        return resolve(self)

    def validation_warnings(self) -> list[str]:
        """What ``fieldgate validate`` says beside "valid": where the master profile overrode the style."""
        return list(self.profile.notes)

    def check(self, topology: Any) -> list[tuple[tuple[Any, ...], str]]:
        """The limits ``run`` applies when the front starts, at validation: the style's image
        (the NA-9161's 32 slots and 64 bytes per direction), the default PDOs, bit objects."""
        return check_io(self, GatewayContext.build(topology))

    @field_validator("sync_cob_id")
    @classmethod
    def _sync_cob_id_not_restricted(cls, value: int) -> int:
        if restricted(value):
            raise ValueError(
                f"0x{value:03X} is a restricted CAN-ID (CiA 301 §7.3.5); 0x80 is the usual SYNC COB-ID"
            )
        return value


class CanopenFront(Front):
    def __init__(self, config: CanopenFrontConfig, context: GatewayContext):
        super().__init__(config, context)
        self.node: Node | None = None
        self.adapter: CanAdapter | None = None
        self.outputs: list[str] = []
        self.master: MasterState | None = None
        self.io: IoDevice | None = None
        self._wake_scheduled = False
        self._modules: set[tuple[str, int]] = set()
        self._health_subscribed = False
        self._ports_subscribed = False
        self._failed: asyncio.Future[None] | None = None

    # -- assembling ---------------------------------------------------------------------
    def _state_path(self, configured: str | None, default: str) -> Path:
        path = Path(configured or default)
        return path if path.is_absolute() else self.context.state_dir / path

    def fingerprint(self, channels: Iterable[Channel]) -> str:
        text = "\n".join(f"{c.id}:{c.kind.value}" for c in channels)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def build(self) -> Node:
        cfg = self.config
        profile = cfg.profile
        channels = self.context.front_channels(cfg)
        io = io_device(self)
        device_type = cfg.identity.device_type
        if device_type is None:
            device_type = io_device_type({c.kind for c in channels})
        ident = cfg.identity
        settings = NodeSettings(
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
            store_path=self._state_path(cfg.store_file, f"{self.name}.canopen.json"),
            fingerprint=self.fingerprint(channels),
            pdo=io.pdo_config,
        )
        node = build_node(settings, name=self.name)
        if profile.style.controller_emcy:
            node.add_service(CanHealth(profile.style.controller_emcy))
        node.add_service(
            LssService(
                bitrate=cfg.bitrate,
                table=cfg.lss_table,
                store=LssStore(self._state_path(cfg.lss_store_file, f"{self.name}.lss.json")),
            )
        )
        node.add_service(io)
        self.io = io
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

    def _bus_state(self, off: bool, now: float) -> None:
        if off:
            self.context.events.publish(BUS_OFF, self.name, "CAN bus-off")
        else:
            self.context.events.publish(BUS_ON, self.name, "CAN bus recovered from bus-off")
        if self.node is not None:
            self.node.service("error_control").bus_state(off, now)

    # -- life cycle ---------------------------------------------------------------------
    async def start(self) -> None:
        cfg = self.config
        loop = asyncio.get_running_loop()
        self.node = node = self.build()
        bitrate = node.service("lss").bitrate or cfg.bitrate
        bus = open_bus(cfg.interface, cfg.channel, bitrate, cfg.bus_options)
        lss = self.node.service("lss")
        self.adapter = CanAdapter(
            self.node,
            bus,
            loop,
            on_bus_state=self._bus_state,
            on_controller=self._controller,
            transmit_allowed=lss.transmit_allowed,
            reopen=lambda rate: open_bus(cfg.interface, cfg.channel, rate, cfg.bus_options),
        )
        self.adapter.start()
        node.on_wake(self._wakeup)
        if cfg.module_emcy and not self._health_subscribed:
            self._health_subscribed = True
            self.context.health.subscribe(self._module_health)
        if cfg.module_emcy:  # modules offline before this node booted (a port missing at start)
            for health in self.context.health.modules():
                if health.key in self._modules and not health.online:
                    self._module_health(health, HealthEvent.OFFLINE)
        if not self._ports_subscribed:
            self._ports_subscribed = True
            self.context.health.subscribe_ports(lambda *_: self._ports_changed())
        self._ports_changed()  # a port already missing (the front restarted meanwhile)
        self.log.info(
            "CANopen node %s on %s/%s at %s bit/s",
            self.node.node_id if self.node.configured else "unconfigured",
            cfg.interface,
            cfg.channel,
            bitrate,
        )

    def _wakeup(self) -> None:
        """Work queued from outside the node's calls (a TPDO, an EMCY): one engine run in the
        next loop turn, however many wake-ups this turn brings, never postponed further."""
        if not self._wake_scheduled:
            self._wake_scheduled = True
            asyncio.get_running_loop().call_soon(self._run_engine)

    def _run_engine(self) -> None:
        self._wake_scheduled = False
        if self.adapter is not None:
            self.adapter.run_engine()

    async def run(self) -> None:
        """Everything is callback-driven; raises only when receiving from the bus has died."""
        if self.adapter is None:
            raise RuntimeError(f"front {self.name}: run() before start()")
        await self.adapter.failed

    async def stop(self) -> None:
        if self.adapter is not None:
            self.adapter.close()
            self.adapter = None

    # -- module health ------------------------------------------------------------------
    def _module_health(self, health: ModuleHealth, event: HealthEvent) -> None:
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
        if self.adapter is not None:
            self.adapter.pump(action)
        else:
            action()

    # -- serial ports of the backs behind this front ------------------------------------------
    def _ports_changed(self) -> None:
        """EMCY "COM port access error" (00 50 81 03) while a port of a back whose modules
        this front serves is missing; its error reset when every such port is open again."""
        if self.node is None or self.node.emcy is None:
            return
        emcy = self.node.emcy
        backs = {back for back, _ in self._modules}
        missing = sorted(b for b in backs if b in self.context.health.ports_lost)
        code, register, manufacturer = COM_PORT_ERROR
        if missing:
            action = partial(emcy.raise_error, code, register, manufacturer)
        else:
            action = partial(emcy.clear_error, code, manufacturer)
        if self.adapter is not None:
            self.adapter.pump(action)
        else:
            action()

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
            *can_bus_samples(self.adapter.status() if self.adapter else None, ignored),
        ]

    def status(self) -> dict[str, Any]:
        if self.node is None:
            return {}
        return {
            **self.node.status(),
            "master": self.master.status() if self.master else None,
            "bus": self.adapter.status() if self.adapter else None,
            "interface": self.config.interface,
            "channel": self.config.channel,
        }


@hookimpl
def fieldgate_register(registry: Registry) -> None:
    registry.add_front(
        "canopen", CanopenFrontConfig, CanopenFront, "CANopen CiA 301 slave on any python-can bus"
    )
    registry.add_eds("canopen", eds_for)
