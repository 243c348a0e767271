"""Device profiles (``style``) and master profiles (``master``) of the ``canopen`` front.

A **style** is the device fieldgate replaces: every default its manual gives, applied
without extra keys (docs/canopen-io.md, "Device profiles"):

``icpdas`` (ICP DAS I-7232D / I-7231D, seed-000 / seed-001)
    node guarding only (no 0x1016/0x1017, seed-000 §2.3), guard time and life time
    factor 0 (the master sets them), the node keeps its NMT state on a guarding failure,
    error modes off (0x6206/0x6443 = 0: outputs hold), EMCY ``00 FF 80 0A`` before an NMT
    reset, a 5-entry 0x1003, analog changes are no TPDO events, SYNC loss only an EMCY,
    the CAN controller and overrun EMCYs of its table (§2.5).

``na9161`` (CREVIS NA-9161, seed-004)
    guarding 200 ms x 2, one 0x1016 entry and 0x1017, PRE-OPERATIONAL on a guarding,
    heartbeat or SYNC failure, every output to 0 on an error event (0x6206 = 0xFF, 0x6207 =
    0x00, 0x6443 = 1, 0x6444 = 0), SYNC loss is an error event (§4.8), a 20-entry 0x1003 and
    EMCY queue whose overflow is reported, expedited writes shorter than an unsigned object
    zero-extended (its own examples write U32 with 2 bytes), analog changes fire TPDOs (the
    NA-9161 has no 0x6421-0x6426).

A **master profile** is what a PLC requires of its slaves, separate from the style:

``generic`` (default)
    nothing beyond CiA 301.

``delta-as300`` (Delta AS300 with AS-FCOPM, seed-002)
    heartbeat only (REQ-AS-06): 0x1017 is served with a producer time of
    :data:`AS300_PRODUCER_MS`; a 0x1016 entry watches the master's heartbeat (node 1 every
    200 ms, REQ-AS-07) with a consumer time of :data:`AS300_CONSUMER_MS` (2.5 periods: one
    lost heartbeat never trips it, two in a row always do); PDOs without mapped data are
    invalid, so the master never waits for a PDO that cannot come (E1/E2); the node-ID is
    1..64 and not the master's own (REQ-AS-01, E8).

Where a style and a master profile conflict (an I-7232D has no heartbeat, the AS300
supervises by nothing else) the master profile's requirement wins and :func:`resolve`
returns one note saying so (``fieldgate validate`` prints it). Every key of the topology
still overrides both.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

Style = Literal["icpdas", "na9161"]
StartPolicy = Literal["async", "all", "none"]
MasterName = Literal["generic", "delta-as300"]
MasterLost = Literal["pre-operational", "no-change", "stopped"]
AnalogEvents = Literal["change", "interrupt"]
SyncLoss = Literal["error-event", "emcy"]

# one EMCY of the CAN controller's health: (code, error register bits, manufacturer bytes)
ControllerEmcy = tuple[int, int, bytes]
CONTROLLER_CONDITIONS = ("warning", "passive", "rx_overrun", "tx_overrun", "controller_overrun")

AS300_NODE_ID = 1  # the AS300's own default node-ID (seed-002 §1.11)
AS300_MASTER_HEARTBEAT_MS = 200  # "Master heartbeat time" default (seed-002 §1.11)
AS300_CONSUMER_MS = 500  # 2.5 x 200 ms: one lost heartbeat tolerated, two in a row detected
AS300_PRODUCER_MS = 1000  # REQ-AS-06: a non-zero factory default, so the master can supervise us
AS300_MAX_SLAVE_ID = 64  # the AS300 monitors node-IDs 1..64 (seed-002 §1.1)
AS300_EVENT_TIMER_MS = 100  # REQ-AS-15: the Delta slave's default event timer
AS300_BITRATES = (20_000, 50_000, 125_000, 250_000, 500_000, 1_000_000)  # seed-002 §1.2, REQ-AS-02


@dataclass(frozen=True)
class DeviceProfile:
    name: Style
    device: str
    heartbeat_producer: bool  # 0x1017 in the dictionary
    heartbeat_consumers: int  # 0x1016 entries (0: no 0x1016)
    guard_time_ms: int
    life_time_factor: int
    on_master_lost: MasterLost
    emcy_history: int
    emcy_queue: int
    emcy_on_nmt_reset: bool
    sdo_zero_extend: bool
    outputs_to_zero: bool  # outputs without a configured error mode go to 0 on an error event
    analog_events: AnalogEvents
    sync_loss: SyncLoss
    short_ao_error_writes: tuple[int, ...]  # objects that take the manuals' 2-byte writes
    tpdo_on_start: StartPolicy  # TPDOs sent on entering Operational
    hw_config_emcy_unsaved: bool  # "Changed HW configuration" EMCY at power-on without a save
    stored_cob_ids_kept: bool  # saved node-ID-dependent COB-IDs keep their values (AMBIG-24)
    controller_emcy: dict[str, ControllerEmcy] = field(default_factory=dict)


ICPDAS = DeviceProfile(
    name="icpdas",
    device="ICP DAS I-7232D / I-7231D",
    heartbeat_producer=False,
    heartbeat_consumers=0,
    guard_time_ms=0,
    life_time_factor=0,
    on_master_lost="no-change",
    emcy_history=5,
    emcy_queue=16,
    emcy_on_nmt_reset=True,
    sdo_zero_extend=False,
    outputs_to_zero=False,
    analog_events="interrupt",
    sync_loss="emcy",
    short_ao_error_writes=(0x6443, 0x6444),  # printed UNSIGNED16 in both ICP DAS manuals
    tpdo_on_start="none",  # TV-07: "No response frame. The node goes to Operational"
    hw_config_emcy_unsaved=False,
    stored_cob_ids_kept=False,
    controller_emcy={  # seed-000 §2.5, seed-001 §3.5
        "warning": (0x1000, 0x81, b"\x01"),
        "passive": (0x1000, 0x81, b"\x01"),
        "rx_overrun": (0x8110, 0x11, b"\x04"),
        "tx_overrun": (0x8110, 0x11, b"\x05"),
        "controller_overrun": (0x8110, 0x11, b"\x06"),
    },
)

NA9161 = DeviceProfile(
    name="na9161",
    device="CREVIS NA-9161",
    heartbeat_producer=True,
    heartbeat_consumers=1,
    guard_time_ms=200,
    life_time_factor=2,
    on_master_lost="pre-operational",
    emcy_history=20,
    emcy_queue=20,
    emcy_on_nmt_reset=False,
    sdo_zero_extend=True,
    outputs_to_zero=True,
    analog_events="change",
    sync_loss="error-event",
    short_ao_error_writes=(0x6444,),  # printed U16 in the NA-9161's table
    tpdo_on_start="all",  # §4.2: every TPDO once at Start
    hw_config_emcy_unsaved=True,  # §4.5, 0x1010: sent at power-on while running on defaults
    stored_cob_ids_kept=True,  # 0x1010 [AMBIG-24]: stored COB-IDs survive a node-ID change
    # the NA-9161's EMCY table is missing from its manual (AMBIG-1): CiA 301 codes, byte 3 the
    # Beckhoff-style communication bits the extract cites (0x80 warning limit, 0x10/0x20 Rx/Tx
    # overrun), as our SYNC loss 0x8100 02 already does
    controller_emcy={
        "warning": (0x8100, 0x11, b"\x80"),
        "passive": (0x8120, 0x11, b"\x80"),
        "rx_overrun": (0x8110, 0x11, b"\x10"),
        "tx_overrun": (0x8110, 0x11, b"\x20"),
        "controller_overrun": (0x8110, 0x11, b"\x10"),
    },
)

STYLES: dict[str, DeviceProfile] = {p.name: p for p in (ICPDAS, NA9161)}

# what the box a style replaces holds, by the type of the back behind it: (device, modules,
# addresses); fieldgate takes more (a superset), validate says where a topology would not go
# back onto the real box (audit 000 #40, 001 #12)
BOX_LIMITS: dict[tuple[str, str], tuple[str, int, tuple[int, int]]] = {
    ("icpdas", "modbus"): ("I-7232D", 10, (0x01, 0x0F)),  # seed-000 §1.3, §3.7
    ("icpdas", "dcon"): ("I-7231D", 15, (0x01, 0x0F)),  # seed-001 §2.2 rule 1
}


@dataclass(frozen=True)
class MasterProfile:
    name: MasterName
    device: str
    node_id: int | None = None  # the master's own node-ID (a slave must not use it)
    max_slave_id: int = 127
    heartbeat_producer_ms: int | None = None  # heartbeat required: 0x1017 served, this default
    master_heartbeat_ms: int | None = None  # the master's heartbeat period
    consumer_time_ms: int | None = None  # 0x1016 entry watching the master
    empty_pdos_invalid: bool = False  # a PDO with nothing mapped starts invalid
    tpdo_on_start: StartPolicy | None = None  # TPDOs the master needs at Start (E2)
    analog_event_timer_ms: int = 0  # analog TPDOs' event timer where the style has none
    bitrates: tuple[int, ...] = ()  # the rates the master offers (empty: any)


GENERIC = MasterProfile("generic", "any CiA 301 master")
DELTA_AS300 = MasterProfile(
    "delta-as300",
    "Delta AS300 (AS-FCOPM)",
    node_id=AS300_NODE_ID,
    max_slave_id=AS300_MAX_SLAVE_ID,
    heartbeat_producer_ms=AS300_PRODUCER_MS,
    master_heartbeat_ms=AS300_MASTER_HEARTBEAT_MS,
    consumer_time_ms=AS300_CONSUMER_MS,
    empty_pdos_invalid=True,
    tpdo_on_start="async",  # E2: a TPDO that never comes; REQ-AS-15: each async TPDO at Start
    analog_event_timer_ms=AS300_EVENT_TIMER_MS,
    bitrates=AS300_BITRATES,
)
MASTERS: dict[str, MasterProfile] = {p.name: p for p in (GENERIC, DELTA_AS300)}


@dataclass(frozen=True)
class ConsumerEntry:
    """One 0x1016 default: the node-ID watched and the consumer time (ms)."""

    node: int
    time_ms: int

    @property
    def value(self) -> int:
        return (self.node & 0xFF) << 16 | (self.time_ms & 0xFFFF)


@dataclass(frozen=True)
class Resolved:
    """What a canopen front runs with: the style's defaults, the master profile's
    requirements, then the topology's keys."""

    style: DeviceProfile
    master: MasterProfile
    master_node_id: int | None
    heartbeat_ms: int | None  # None: no 0x1017 object
    consumer_entries: tuple[ConsumerEntry, ...]
    heartbeat_consumers: int  # 0x1016 sub-indices (0: no 0x1016)
    guard_time_ms: int
    life_time_factor: int
    on_master_lost: MasterLost
    emcy_history: int
    emcy_queue: int
    emcy_on_nmt_reset: bool
    sdo_zero_extend: bool
    outputs_to_zero: bool
    analog_events: AnalogEvents
    sync_loss: SyncLoss
    empty_pdos_invalid: bool
    tpdo_on_start: StartPolicy
    analog_event_timer_ms: int
    notes: tuple[str, ...] = ()


def _given(cfg: Any, name: str) -> bool:
    """Whether the topology set ``name`` (a key present, null or not)."""
    return name in getattr(cfg, "model_fields_set", set())


def resolve(cfg: Any) -> Resolved:
    """The effective settings of a ``canopen`` front configuration (a CanopenFrontConfig)."""
    style = STYLES[cfg.style]
    master = MASTERS[cfg.master]
    notes: list[str] = []
    master_id = cfg.master_node_id if _given(cfg, "master_node_id") else master.node_id
    heartbeat = _heartbeat_producer(cfg, style, master, notes)
    entries, consumers = _heartbeat_consumers(cfg, style, master, master_id, notes)
    if cfg.bit_mapping and master.name == "delta-as300":
        notes.append(
            "master delta-as300 maps 8/16/32/64-bit types only (REQ-AS-12): the default PDOs stay "
            "byte-aligned; 1-bit entries of bit_mapping are for other masters"
        )

    def pick(name: str, default: Any) -> Any:
        value = getattr(cfg, name)
        return default if value is None else value

    start = _tpdo_on_start(cfg, style, master, notes)
    # analog TPDOs' event timer: what the master needs where the style leaves it 0
    analog_timer = 0
    if master.analog_event_timer_ms and analog_events_of(cfg, style) == "interrupt":
        analog_timer = master.analog_event_timer_ms  # (validate's note: the config's, with AI)
    if master.bitrates and isinstance(cfg.bitrate, int) and cfg.bitrate not in master.bitrates:
        notes.append(
            f"master {master.name} offers {', '.join(f'{r // 1000}k' for r in master.bitrates)} "
            f"bit/s only: bitrate {cfg.bitrate} is not one of them"
        )

    return Resolved(
        style=style,
        master=master,
        master_node_id=master_id,
        heartbeat_ms=heartbeat,
        consumer_entries=entries,
        heartbeat_consumers=consumers,
        guard_time_ms=pick("guard_time_ms", style.guard_time_ms),
        life_time_factor=pick("life_time_factor", style.life_time_factor),
        on_master_lost=pick("on_master_lost", style.on_master_lost),
        emcy_history=pick("emcy_history", style.emcy_history),
        emcy_queue=pick("emcy_queue", style.emcy_queue),
        emcy_on_nmt_reset=pick("emcy_on_nmt_reset", style.emcy_on_nmt_reset),
        sdo_zero_extend=pick("sdo_zero_extend", style.sdo_zero_extend),
        outputs_to_zero=(
            style.outputs_to_zero
            if cfg.error_mode_default is None
            else cfg.error_mode_default == "zero"
        ),
        analog_events=pick("analog_events", style.analog_events),
        sync_loss=pick("sync_loss", style.sync_loss),
        empty_pdos_invalid=master.empty_pdos_invalid,
        tpdo_on_start=start,
        analog_event_timer_ms=analog_timer,
        notes=tuple(notes),
    )


def _heartbeat_producer(
    cfg: Any, style: DeviceProfile, master: MasterProfile, notes: list[str]
) -> int | None:
    """The heartbeat producer: the style's, the master's requirement, then heartbeat_ms."""
    if _given(cfg, "heartbeat_ms"):
        heartbeat: int | None = cfg.heartbeat_ms
        return heartbeat
    if master.heartbeat_producer_ms is not None:
        if not style.heartbeat_producer:
            notes.append(
                f"master {master.name} supervises its slaves by heartbeat only and the {style.name} "
                f"style ({style.device}) has none: 0x1016/0x1017 added, producer "
                f"{master.heartbeat_producer_ms} ms, guarding stays available"
            )
        return master.heartbeat_producer_ms
    return 0 if style.heartbeat_producer else None


def _heartbeat_consumers(
    cfg: Any,
    style: DeviceProfile,
    master: MasterProfile,
    master_id: int | None,
    notes: list[str],
) -> tuple[tuple[ConsumerEntry, ...], int]:
    """The heartbeat consumer entries (the topology's list, else the master profile's
    entry) and how many the object dictionary offers."""
    if _given(cfg, "consumer_heartbeats"):
        entries = tuple(ConsumerEntry(e.node, e.time_ms) for e in cfg.consumer_heartbeats)
        if (
            master.consumer_time_ms is not None
            and master_id is not None
            and all(e.node != master_id for e in entries)
        ):
            notes.append(
                f"consumer_heartbeats does not watch the master (node {master_id}): master loss "
                f"is detected only when the master writes 0x1016 itself"
            )
    elif master.consumer_time_ms is not None and master_id is not None:
        entries = (ConsumerEntry(master_id, master.consumer_time_ms),)
    else:
        entries = ()
    if _given(cfg, "heartbeat_consumers") and cfg.heartbeat_consumers is not None:
        consumers: int = cfg.heartbeat_consumers
    else:
        consumers = max(style.heartbeat_consumers, len(entries))
    return entries, consumers


def _tpdo_on_start(
    cfg: Any, style: DeviceProfile, master: MasterProfile, notes: list[str]
) -> StartPolicy:
    """TPDOs at Start: the style's, what the master needs, then tpdo_on_start."""
    start = style.tpdo_on_start
    if cfg.tpdo_on_start is not None:
        start = cfg.tpdo_on_start
    elif master.tpdo_on_start is not None and master.tpdo_on_start != style.tpdo_on_start:
        if style.tpdo_on_start == "none":
            start = master.tpdo_on_start
            notes.append(
                f"master {master.name} waits for every configured TPDO after Start (E2) and the "
                f"{style.name} style sends none then: each asynchronous TPDO once at Start "
                f"(tpdo_on_start: {start})"
            )
    return start


def analog_events_of(cfg: Any, style: DeviceProfile) -> AnalogEvents:
    value: AnalogEvents | None = getattr(cfg, "analog_events", None)
    return value or style.analog_events


def node_id_problem(cfg: Any) -> str | None:
    """Why ``node_id`` cannot be used with this master profile, or None."""
    node_id = cfg.node_id
    if node_id is None:
        return None
    master = MASTERS[cfg.master]
    master_id = cfg.master_node_id if _given(cfg, "master_node_id") else master.node_id
    if master_id is not None and node_id == master_id:
        whose = (
            "master_node_id" if _given(cfg, "master_node_id") else f"the {master.device}'s default"
        )
        return (
            f"node-ID {node_id} is the master's own ({whose}); two nodes with one node-ID "
            f"collide (the AS300 shows E8): give this slave another"
        )
    if node_id > master.max_slave_id:
        return f"master {master.name} monitors node-IDs 1..{master.max_slave_id} only"
    return None
