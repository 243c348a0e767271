"""The CiA 401 I/O device as one node service: the profile and manufacturer objects over the
process image, and what the node's PDOs may map.

::

    io = IoDevice(IoSettings(style="icpdas"), image, channels, origin="can", health=context.health,
                  masters=context.masters, front="can")
    settings = NodeSettings(node_id=5, identity=Identity(device_type=io.device_type),  # 0x1000
                            pdo=io.pdo_config)   # the PDO service maps these objects
    node = build_node(settings); node.add_service(io)

What it does on the node:

* adds the CiA 401 objects (:mod:`.objects`), the special bytes (:mod:`..na9161.special`)
  and the manufacturer objects (:mod:`.manufacturer`) to ``node.od``, each entry bound to
  its getter/setter (the process image is the truth);
* reports process-image events to the node's PDO service (``object_changed``: the one
  call from CiA 401 into CiA 301 on the way from a DI change to a TPDO; the PDO service
  wakes the node, whose driver runs it);
* module offline: EMCY 0xFF00 ``0B <address>`` (unless the front raises it itself);
* stores the PDO parameters and CiA 401 settings with 0x1010 (:mod:`.iostore`);
* with ``master_events`` (a standalone device; the canopen front owns it itself), the
  master state (:class:`~..master_state.MasterState`): master lost (``node.on_master``:
  life guarding, heartbeat consumer, bus-off) or, when ``error_on_stopped`` (the
  NA-9161), NMT Stopped: ``masters.lost(front, reason, outputs)`` drives every output
  with an error mode to its error value; ``masters.ok`` when neither holds any more.
  Outputs keep their error values until new data is written (NA-9161 §9.7.3).

``na9161`` style: 0x4500 (:mod:`..na9161.fnbus`). A written data mode or slot deactivation
takes effect at the next NMT Reset Node: the layout, the CiA 401 and special objects,
0x2020 and the PDO set (with its default mapping: :meth:`PdoService.serve`) are built again
and bound in place of the old ones, before the stored settings are reloaded.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

from fieldgate.health import HealthRegistry
from fieldgate.host_watchdog import HostWatchdogs
from fieldgate.image import Channel, ProcessImage
from fieldgate.masters import MasterMonitor
from fieldgate.module_info import ModuleInfo

from ..cia301.cobid import check_cob_id
from ..cia301.entries import Abort, Directory, bind_object
from ..cia301.nmt import NmtState
from ..cia301.pdo.defaults import PdoDefaults, PdoSetting
from ..cia301.pdo.engine import PdoEngine
from ..cia301.pdo.mapping import Pdo, PdoMapping
from ..cia301.pdo.service import PdoConfig, PdoService
from ..cia301.service import NodeHost, Service
from ..master_state import MasterState
from ..na9161.fnbus import FnBusRegister
from ..na9161.slots import SlotObjects
from ..na9161.special import SpecialBytes, input_events
from ..profiles import STYLES
from .iostore import IoStore
from .layouts import STYLE_PDO_COUNT, IoLayout, Style, build_layout, default_pdos
from .manufacturer import ManufacturerObjects
from .objects import SHORT_WRITES, cia401_objects
from .profile import Profile401


@dataclass
class IoSettings:
    style: Style = "icpdas"
    pdo_count: int | None = None  # per direction; default 32 (icpdas) / 8 (na9161)
    mapping_closed: bool = False  # icpdas: analog from PDO1 when a direction has no digital data
    compressed: bool = True  # na9161: digital bits packed across modules
    start_policy: Literal["async", "all", "none"] | None = (
        None  # TPDOs sent on entering Operational
    )
    error_on_stopped: bool | None = None  # NMT Stopped is an output error event (na9161)
    do_error_default: tuple[int, int] | None = (
        None  # (0x6206, 0x6207) for outputs without a configured mode
    )
    bit_mapping: bool = False  # 0x6020-/0x6220- bit objects, 1-bit mapping, dummy 0x0001
    analog_events: Literal["change", "interrupt"] | None = None  # default: the style's
    short_ao_error_writes: tuple[int, ...] | None = None  # 2-byte writes taken (0x6443/0x6444)
    empty_pdos_invalid: bool = False  # default PDOs without data start invalid (master profile)
    analog_event_timer_ms: int = 0  # analog TPDOs' event timer where the style has none (master)
    tpdo_settings: dict[int, PdoSetting] = field(default_factory=dict)  # the topology's tpdos:
    rpdo_settings: dict[int, PdoSetting] = field(default_factory=dict)  # the topology's rpdos:

    @property
    def analog(self) -> Literal["change", "interrupt"]:
        """AI changes: every one a TPDO event (na9161) or only through 0x6423/0x6421."""
        return self.analog_events or STYLES[self.style].analog_events

    @property
    def short_writes(self) -> tuple[int, ...]:
        if self.short_ao_error_writes is not None:
            return self.short_ao_error_writes
        return STYLES[self.style].short_ao_error_writes

    @property
    def granularity(self) -> int:
        return 1 if self.bit_mapping else 8

    @property
    def count(self) -> int:
        return self.pdo_count or STYLE_PDO_COUNT[self.style]

    @property
    def policy(self) -> Literal["async", "all", "none"]:
        return self.start_policy or STYLES[self.style].tpdo_on_start

    @property
    def stopped_is_error(self) -> bool:
        return self.style == "na9161" if self.error_on_stopped is None else self.error_on_stopped


class IoDevice(Service):
    name = "io"
    active_states: ClassVar[frozenset[NmtState]] = frozenset()  # takes no frames, no SYNC
    layout: IoLayout
    defaults: PdoDefaults
    profile: Profile401

    def __init__(
        self,
        settings: IoSettings,
        image: ProcessImage,
        channels: Sequence[Channel],
        *,
        origin: str = "canopen",
        health: HealthRegistry | None = None,
        masters: Any = None,
        front: str | None = None,
        host_watchdogs: HostWatchdogs | None = None,
        models: dict[tuple[str, int], str] | None = None,
        master_events: bool = True,
        module_emcy: bool = True,
        module_info: ModuleInfo | None = None,
    ):
        super().__init__()
        self.settings = settings
        self.image = image
        self.front = front or origin
        self.origin = origin
        self.channels = list(channels)
        self.models = models or {}
        self._build_layout(settings.compressed, frozenset())
        health = health or HealthRegistry()
        self.fnbus = (
            FnBusRegister(
                self.layout.modules,
                health,
                compressed=settings.compressed,
                check=lambda compressed, inactive: build_layout(
                    self.channels,
                    settings.style,
                    compressed=compressed,
                    models=self.models,
                    inactive=inactive,
                ),
            )
            if settings.style == "na9161"
            else None
        )
        # the NA-9161's per-slot objects (0x2000/0x2200 memory, 0x4501, 0x4502, 0x4504): every
        # slot keeps its number, deactivated or not, so they are built once
        self.slots = (
            SlotObjects(image, self.layout.modules, self.channels, origin, module_info)
            if settings.style == "na9161"
            else None
        )
        self.manufacturer = ManufacturerObjects(
            self.layout,
            health,
            style=settings.style,
            host_watchdogs=host_watchdogs,
            module_emcy=module_emcy,
        )
        # the master-state owner, unless the front owns it (master_events False)
        self.master_state = (
            MasterState(
                masters if masters is not None else MasterMonitor(image),
                self.front,
                lambda: self.profile.output_ids(),
                stopped_is_error=settings.stopped_is_error,
            )
            if master_events
            else None
        )
        self.directory = self._directory()
        self.pdo: PdoService | None = None  # the node's, found when attached
        self.store = IoStore(self)
        self._attached = False
        self._powered_on = False

    def _build_layout(self, compressed: bool, inactive: frozenset[int]) -> None:
        """The layout-dependent parts: layout, default PDOs, CiA 401 objects."""
        self.layout, self.defaults, self.profile = build_io(
            self.settings,
            self.image,
            self.channels,
            self.origin,
            models=self.models,
            compressed=compressed,
            inactive=inactive,
        )

    def _directory(self) -> Directory:
        fnbus = self.fnbus.objects() if self.fnbus is not None else []
        slots = self.slots.objects() if self.slots is not None else []
        special = SpecialBytes(self.layout, self.profile.outputs).objects()
        return Directory(
            cia401_objects(self.profile) + special + self.manufacturer.objects() + fnbus + slots,
            batch=self.profile.outputs.batch,
        )

    @property
    def pdo_config(self) -> PdoConfig:
        """What the node's PDO service maps and starts from (its ``NodeSettings.pdo``)."""
        settings = self.settings
        return PdoConfig(
            self.directory,
            self.defaults.tpdo,
            self.defaults.rpdo,
            start_policy=settings.policy,
            rpdo_timing=settings.style == "na9161",
            granularity=settings.granularity,
        )

    @property
    def engine(self) -> PdoEngine | None:
        """The node's PDO engine (its PDO service's), once attached."""
        return self.pdo.engine if self.pdo is not None else None

    def _rebuild(self) -> None:
        """Reset node with a new data mode or slot set (0x4500): the image's objects again."""
        node = self.node
        assert self.fnbus is not None
        for obj in self.directory:
            node.od.remove(obj.index)
        self.profile.detach()
        self.fnbus.apply()
        self._build_layout(self.fnbus.compressed, self.fnbus.inactive)
        self.manufacturer.layout = self.layout
        self.directory = self._directory()
        if self.pdo is not None:
            self.pdo.serve(self.pdo_config)
        for obj in self.directory:
            bind_object(node.od, obj)
        if (0x1000, 0) in node.od:  # the DI/DO/AI/AO bits of the new image (the reset reloads it)
            node.od.variable(0x1000, 0).default = self.device_type
            node.od.set(0x1000, 0, self.device_type, notify=False)
        self._report_events()

    @property
    def device_type(self) -> int:
        return self.layout.device_type

    # -- Service ----------------------------------------------------------------------------
    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        try:
            self.pdo = node.service("pdo")
        except KeyError:  # a node without PDOs: the objects are served by SDO only
            self.pdo = None
        for obj in self.directory:
            bind_object(node.od, obj)
        for index in self.settings.short_writes:
            node.od.accept_short_writes(index, 2, SHORT_WRITES[index])
        self.store.attach(node)
        self._report_events()
        emcy = node.emcy
        if emcy is not None:
            self.manufacturer.attach(
                lambda code, reg, mfr: self._outside(lambda: emcy.raise_error(code, reg, mfr)),
                lambda code, mfr: self._outside(lambda: emcy.clear_error(code, mfr)),
            )
        if self.master_state is not None:
            self.master_state.attach(node)
        self._attached = True

    def _report_events(self) -> None:
        """The profile's events go to the PDO service: the DI-change-to-TPDO path."""
        if self.pdo is not None:
            self.profile.attach(self.pdo.object_changed)

    def detach(self) -> None:
        self.profile.detach()
        self.manufacturer.detach()

    def on_reset_communication(self, now: float) -> None:
        if self._attached:  # (the PDO service has reset its PDOs: the stored ones apply)
            self.store.load_communication()

    def on_reset_application(self, now: float) -> None:
        if not self._attached:
            return
        if self.fnbus is not None:
            if not self._powered_on:  # power-on: the 0x4500 settings a 0x1010 save kept
                self.fnbus.load(self.store.fnbus_settings())
            if self.fnbus.pending:
                self._rebuild()
        self._powered_on = True
        self.store.load_application()

    def status(self) -> dict[str, Any]:
        """Its counters, the PDO service's (``services.io`` of the status API and the live
        page show the PDO figures here) and the master state when it owns it."""
        pdo = self.pdo.status() if self.pdo is not None else {}
        master = {"master_lost": self.master_state.lost} if self.master_state is not None else {}
        return {**dict(self.counters), **pdo, **master}

    def _outside(self, action: Callable[[], Any]) -> None:
        """An EMCY from outside the node's calls (a module's health): the node is woken."""
        action()
        self.node.wake()


def build_io(
    settings: IoSettings,
    image: ProcessImage,
    channels: Sequence[Channel],
    origin: str,
    *,
    models: dict[tuple[str, int], str] | None = None,
    compressed: bool | None = None,
    inactive: frozenset[int] = frozenset(),
) -> tuple[IoLayout, PdoDefaults, Profile401]:
    """The layout, the default PDOs and the CiA 401 objects of a front's channels: what a
    running front builds, and what ``fieldgate validate`` checks (:class:`LayoutError` when
    the channels do not fit the style: 32 slots and 64 bytes of the NA-9161, the PDOs)."""
    layout = build_layout(
        channels,
        settings.style,
        compressed=settings.compressed if compressed is None else compressed,
        models=models or {},
        inactive=inactive,
    )
    defaults = default_pdos(
        layout,
        settings.style,
        count=settings.count,
        mapping_closed=settings.mapping_closed,
        empty_invalid=settings.empty_pdos_invalid,
        tpdo_settings=settings.tpdo_settings,
        rpdo_settings=settings.rpdo_settings,
        analog_event_timer_ms=settings.analog_event_timer_ms,
    )
    profile = Profile401(
        image,
        layout,
        origin,
        bit_objects=settings.bit_mapping,
        analog_events=settings.analog,
        extra_events=input_events(layout),
    )
    return layout, defaults, profile


def check_pdo_settings(io: IoDevice, node_id: int) -> list[tuple[str, int, str]]:
    """What the PDO engine would refuse of the topology's ``tpdos:`` / ``rpdos:`` (the CiA 301
    rules a master's SDO writes meet: mapping entries, COB-IDs, transmission types, the
    RPDOs' sub 3/5), as ``(field, PDO number, message)``; the engine itself takes its
    defaults unchecked."""
    settings, defaults = io.settings, io.defaults
    mapping = PdoMapping(io.directory, settings.granularity)
    problems: list[tuple[str, int, str]] = []
    valid_ids: dict[int, str] = {}
    for field_name, transmit, given, pdos in (
        ("tpdos", True, settings.tpdo_settings, defaults.tpdo),
        ("rpdos", False, settings.rpdo_settings, defaults.rpdo),
    ):
        for number, default in enumerate(pdos, 1):
            pdo = Pdo(number, transmit, default)
            setting = given.get(number)
            if setting is not None:
                problem = _pdo_setting_problem(setting, pdo, mapping, settings.style)
                if problem:
                    problems.append((field_name, number, problem))
                    continue
            if default.valid and default.cob_base is not None and (node_id or default.absolute):
                can_id = default.cob_id(node_id) & 0x7FF
                if can_id in valid_ids and setting is not None:
                    problems.append(
                        (field_name, number, f"COB-ID 0x{can_id:03X} is {valid_ids[can_id]}'s too")
                    )
                valid_ids.setdefault(can_id, f"{'T' if transmit else 'R'}PDO{number}")
    return problems


def _pdo_setting_problem(
    setting: PdoSetting, pdo: Pdo, mapping: PdoMapping, style: str
) -> str | None:
    if setting.trans_type is not None and 252 <= setting.trans_type <= 253 and not pdo.transmit:
        return f"transmission type {setting.trans_type} is for TPDOs (RTR)"
    if (
        not pdo.transmit
        and style != "na9161"
        and (setting.inhibit is not None or setting.event_timer is not None)
    ):
        return "RPDOs of the icpdas style have no inhibit time or event timer (subs 1 and 2 only)"
    if setting.cob_id is not None:
        try:
            check_cob_id(setting.cob_id, "PDO", in_use=setting.valid is not False)
        except Abort as exc:
            return f"cob_id 0x{setting.cob_id:03X}: {_reason(exc)}"
    if pdo.default.valid and pdo.default.cob_base is None:
        return (
            f"{'T' if pdo.transmit else 'R'}PDO{pdo.number} has no predefined COB-ID: give cob_id"
        )
    if pdo.default.entries:
        try:
            mapping.compile(pdo, list(pdo.default.entries))
        except Abort as exc:
            return f"mapping: {_reason(exc)} (abort 0x{exc.code:08X})"
    return None


def _reason(exc: Abort) -> str:
    """An abort's text without its "SDO abort 0x..." prefix (a topology has no SDO)."""
    return str(exc).split(": ", 1)[-1]
