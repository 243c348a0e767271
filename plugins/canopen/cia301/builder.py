"""Assemble a CANopen slave Node with the CiA 301 communication services.

``build_node(settings)`` gives a :class:`~.node.Node` with identity objects, the SDO
server, EMCY producer, error control, SYNC, store/restore, the TIME consumer, the
additional SDO server channels (``settings.sdo_servers``) and, given ``settings.pdo`` (the
application's objects and default PDOs), the PDO service. The front (and tests) add
further services (LSS, the CiA 401 I/O device) with ``node.add_service``, then call
``node.service("store").load()`` and ``node.boot(now)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from canopen.objectdictionary import datatypes as dt

from .emcy import EmcyProducer
from .errctl import ErrorControl
from .node import Node
from .od import Dictionary
from .pdo.service import PdoConfig, PdoService
from .sdo import SdoServer
from .sdo_channel import SdoChannel, channel_indices
from .service import ALL_STATES, NodeHost, Service
from .store import StoreService
from .sync import SyncService
from .timestamp import TimeConsumer


@dataclass
class Identity:
    device_type: int = 0
    vendor_id: int = 0
    product_code: int = 0
    revision: int = 0
    serial: int = 0
    device_name: str = "fieldgate"
    hardware_version: str = ""
    software_version: str = ""


@dataclass
class NodeSettings:
    node_id: int | None  # 1..127, or None: unconfigured (LSS); no default, as no node-ID is safe
    identity: Identity = field(default_factory=Identity)
    heartbeat_ms: int | None = 0  # None: no 0x1017 (guarding only, the I-7232D)
    guard_time_ms: int = 0
    life_time_factor: int = 0
    heartbeat_consumers: int = 1
    consumer_heartbeats: tuple[int, ...] = ()  # 0x1016:1.. defaults, node << 16 | ms
    error_behaviour: int = 1  # 0x1029:1: 0 pre-operational, 1 no change, 2 stopped
    sync_loss_error_event: bool = False  # SYNC loss drives outputs to error values (NA-9161)
    emcy_history: int = 5
    emcy_queue: int = 16
    sdo_timeout_s: float = 1.0
    sdo_block_size: int = 127
    sdo_zero_extend: bool = False
    sdo_servers: int = 1  # SDO server channels in all: 0x1200, then 0x1201.. (see .sdo_channel)
    emcy_on_nmt_reset: bool = False
    sync_cob_id: int = 0x80
    store_path: Path | None = None
    fingerprint: str = ""
    announce_defaults: bool = False  # "Changed HW configuration" EMCY at power-on without a save
    keep_node_id_entries: bool = False  # saved node-ID-dependent COB-IDs survive a node-ID change
    pdo: PdoConfig | None = None  # the application's PDOs (the CiA 401 device's): none without


class IdentityObjects(Service):
    """0x1000, 0x1008/0x1009/0x100A and 0x1018 (all four sub-indices), read-only."""

    name = "identity"
    active_states = ALL_STATES

    def __init__(self, identity: Identity):
        super().__init__()
        self.identity = identity

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        ident, od = self.identity, node.od
        od.add_variable(0x1000, "Device type", dt.UNSIGNED32, "ro", ident.device_type)
        od.add_variable(
            0x1008, "Manufacturer device name", dt.VISIBLE_STRING, "const", ident.device_name
        )
        od.add_variable(
            0x1009,
            "Manufacturer hardware version",
            dt.VISIBLE_STRING,
            "const",
            ident.hardware_version,
        )
        od.add_variable(
            0x100A,
            "Manufacturer software version",
            dt.VISIBLE_STRING,
            "const",
            ident.software_version,
        )
        od.add_record(
            0x1018,
            "Identity object",
            [
                (1, "Vendor-ID", dt.UNSIGNED32, "ro", ident.vendor_id),
                (2, "Product code", dt.UNSIGNED32, "ro", ident.product_code),
                (3, "Revision number", dt.UNSIGNED32, "ro", ident.revision),
                (4, "Serial number", dt.UNSIGNED32, "ro", ident.serial),
            ],
        )


def build_node(settings: NodeSettings, name: str = "canopen", od: Dictionary | None = None) -> Node:
    """The node of ``settings``; ``od`` when its objects come from elsewhere too (a file)."""
    node = Node(settings.node_id, od=od, name=name)
    node.reset_emcy = settings.emcy_on_nmt_reset
    node.add_service(IdentityObjects(settings.identity))
    node.add_service(EmcyProducer(settings.emcy_history, settings.emcy_queue))
    node.add_service(
        ErrorControl(
            settings.guard_time_ms,
            settings.life_time_factor,
            settings.heartbeat_ms,
            settings.heartbeat_consumers,
            settings.error_behaviour,
            settings.consumer_heartbeats,
        )
    )
    node.add_service(SyncService(settings.sync_cob_id, settings.sync_loss_error_event))
    node.add_service(
        SdoServer(settings.sdo_timeout_s, settings.sdo_block_size, settings.sdo_zero_extend)
    )
    node.add_service(
        StoreService(
            settings.store_path,
            settings.fingerprint,
            announce_defaults=settings.announce_defaults,
            keep_node_id_entries=settings.keep_node_id_entries,
        )
    )
    node.add_service(TimeConsumer())
    for index in channel_indices(settings.sdo_servers):
        node.add_service(
            SdoChannel(
                index, settings.sdo_timeout_s, settings.sdo_block_size, settings.sdo_zero_extend
            )
        )
    if settings.pdo is not None:
        node.add_service(PdoService(settings.pdo))
    return node
