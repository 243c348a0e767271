"""The ``canopen`` front's configuration: the bus, the node, its style and master profile, the I/O.

The bus settings are core's (:class:`fieldgate.can.front.CanBusConfig`, the bit rate one
of CiA 301's); the CiA 401 options (:class:`IoFrontOptions`: style, PDO count, packing,
bit mapping, the topology's ``tpdos:`` / ``rpdos:``) feed the I/O device
(:mod:`.front401`); every default of a style and a master profile is :mod:`.profiles`'.

YAML::

    fronts:
      - name: can
        type: canopen
        node_id: 5
        style: na9161          # or icpdas (default)
        compressed: true       # na9161: digital bits packed across modules (0x4500:2)
        bit_mapping: false     # 0x6020-/0x6220- bit objects, 1-bit PDO mapping
        pdo_count: 8           # PDOs per direction (default 32 icpdas / 8 na9161)
"""

from __future__ import annotations

import re
from fnmatch import fnmatchcase
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from fieldgate import __version__
from fieldgate.can.front import CanBusConfig
from fieldgate.image import Kind
from fieldgate.plugin import GatewayContext
from fieldgate.topology import FrontConfig
from fieldgate.topology.model import StrictModel

from .cia301.cobid import restricted
from .cia301.pdo.defaults import PdoSetting
from .cia305.lss import BIT_TIMING_TABLES
from .front401 import check_io
from .profiles import (
    BOX_LIMITS,
    AnalogEvents,
    MasterLost,
    MasterName,
    Resolved,
    SyncLoss,
    node_id_problem,
    resolve,
)

MAPPING_ENTRY = re.compile(
    r"^\s*(0x[0-9a-fA-F]{1,4}|\d+)\s*:\s*(0x[0-9a-fA-F]{1,2}|\d+)\s*/\s*(\d+)\s*$"
)


def mapping_entry_value(entry: int | str) -> int:
    """A mapping entry as the topology writes it: ``"0x6401:2/16"`` (index:sub/bits) or the
    CiA 301 value ``0x64010210``; ValueError when it is neither."""
    if isinstance(entry, int):
        if not 0 <= entry <= 0xFFFFFFFF:
            raise ValueError(
                f"{entry:#x} is not a 32-bit mapping entry (index << 16 | sub << 8 | bits)"
            )
        return entry
    match = MAPPING_ENTRY.match(entry)
    if match is None:
        raise ValueError(
            f"{entry!r}: write a mapping entry as 'index:sub/bits', e.g. '0x6401:2/16'"
        )
    index, sub, bits = (int(part, 0) for part in match.groups())
    if index > 0xFFFF or sub > 0xFF or not 1 <= bits <= 64:
        raise ValueError(f"{entry!r}: index 0..0xFFFF, sub-index 0..255, 1..64 bits")
    return index << 16 | sub << 8 | bits


class PdoSettings(StrictModel):
    """One PDO's communication and mapping defaults (0x1400-/0x1800- and 0x1600-/0x1A00-)."""

    cob_id: int | None = Field(
        None,
        ge=1,
        le=0x7FF,
        description="the CAN-ID (not counted from the node-ID); giving one makes the PDO valid unless valid: false",
    )
    valid: bool | None = Field(None, description="bit 31 of sub 1 clear (true) or set (false)")
    transmission_type: int | None = Field(
        None,
        ge=0,
        le=255,
        description="sub 2: 0 acyclic SYNC, 1-240 every n-th SYNC, 252/253 RTR (TPDO), 254/255 event",
    )
    inhibit_time: int | None = Field(
        None,
        ge=0,
        le=65535,
        description="sub 3, in 100 us (TPDOs; RPDOs of the na9161 style store it)",
    )
    event_timer_ms: int | None = Field(
        None,
        ge=0,
        le=65535,
        description="sub 5, ms (TPDOs of type 254/255; RPDOs of the na9161 style store it)",
    )
    mapping: list[int | str] | None = Field(
        None,
        max_length=8,
        description="the mapped objects, e.g. ['0x6000:1/8', '0x6401:1/16']; at most 64 bits",
    )

    @field_validator("transmission_type")
    @classmethod
    def _known_type(cls, value: int | None) -> int | None:
        if value is not None and 241 <= value <= 251:
            raise ValueError("transmission types 241..251 are reserved (CiA 301)")
        return value

    @field_validator("mapping")
    @classmethod
    def _entries(cls, value: list[int | str] | None) -> list[int | str] | None:
        if value is not None:
            for entry in value:
                mapping_entry_value(entry)
        return value

    def setting(self) -> PdoSetting:
        return PdoSetting(
            cob_id=self.cob_id,
            valid=self.valid,
            trans_type=self.transmission_type,
            inhibit=self.inhibit_time,
            event_timer=self.event_timer_ms,
            entries=None
            if self.mapping is None
            else tuple(mapping_entry_value(e) for e in self.mapping),
        )


class IoFrontOptions(StrictModel):
    style: Literal["icpdas", "na9161"] = Field(
        "icpdas",
        description="object and default PDO layout: icpdas (I-7232D/I-7231D) or na9161 (CREVIS NA-9161)",
    )
    pdo_count: int | None = Field(
        None, ge=1, le=512, description="RPDOs and TPDOs each; default 32 (icpdas) or 8 (na9161)"
    )
    mapping_closed: bool = Field(
        False,
        description="icpdas: analog data from PDO1 when a direction has no digital channels (the I-7232D utility's 'Mapping Closed')",
    )
    compressed: bool = Field(
        True,
        description="na9161: digital channels packed across modules (0x4500:2 = 1); false: each module starts a byte",
    )
    bit_mapping: bool = Field(
        False,
        description="CiA 401 bit objects 0x6020-/0x6220- and 1-bit PDO mapping (EDS Granularity=1, Dummy0001); default PDOs stay byte-aligned",
    )
    tpdo_on_start: Literal["async", "all", "none"] | None = Field(
        None,
        description="TPDOs sent once on entering Operational; default none (icpdas: TV-07, no frame after Start) / all (na9161); async under master delta-as300 (E2)",
    )
    error_on_stopped: bool | None = Field(
        None,
        description="NMT Stopped drives outputs to their error values; default false (icpdas) / true (na9161)",
    )
    tpdos: dict[int, PdoSettings] = Field(
        default_factory=dict,
        description="TPDO number (1..) -> its communication and mapping defaults, replacing the style's; written into the EDS",
    )
    rpdos: dict[int, PdoSettings] = Field(
        default_factory=dict,
        description="RPDO number (1..) -> its communication and mapping defaults, replacing the style's; written into the EDS",
    )


def box_limit_notes(back: Any, device: str, most: int, addresses: tuple[int, int]) -> list[str]:
    """What ``back``'s module list asks beyond ``device``'s limits (count, RS-485 addresses)."""
    modules = list(back.modules)
    low, high = addresses
    outside = [m.address for m in modules if not low <= m.address <= high]
    notes = []
    if len(modules) > most:
        notes.append(
            f"back {back.name} has {len(modules)} modules; the {device} holds at most {most}: "
            f"fieldgate serves them, the topology would not go back onto an {device}"
        )
    if outside:
        notes.append(
            f"back {back.name} has modules at {', '.join(map(str, outside))}; the {device} takes "
            f"RS-485 addresses {low}..{high} only: fieldgate serves them, the topology would not "
            f"go back onto an {device}"
        )
    return notes


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


class CanopenFrontConfig(FrontConfig, CanBusConfig, IoFrontOptions):
    type: Literal["canopen"] = "canopen"
    bitrate: int | Literal["auto"] | None = Field(
        125_000,
        description="CAN bit rate in bit/s, one of CiA 301's (LSS may change it); auto: found by listening (listen-only) at each standard rate before boot-up (SocketCAN, the NA-9161's switch code 9); null for an interface configured outside fieldgate",
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
    field_power: str | None = Field(
        None,
        description="an input channel wired to the 24 V field supply (e.g. rs485/m1/di7): false, or its module offline, is 'field power missing': 0x4500:1 byte 3 = 0x80 (na9161), EMCY 00 33 05, the status API; none: the supply is not sensed",
    )
    identity: IdentitySettings = Field(default_factory=IdentitySettings)

    @field_validator("bitrate")
    @classmethod
    def _standard_bitrate(cls, value: int | str | None) -> int | str | None:
        if value is not None and value != "auto" and value not in CIA_BITRATES:
            raise ValueError(
                f"expected one of the CiA 301 bit rates {', '.join(map(str, CIA_BITRATES))} bit/s, "
                f", auto (found by listening), or null when the interface's own configuration sets it"
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

    def topology_warnings(self, topology: Any) -> list[str]:
        """Where the topology goes beyond the box the style replaces (fieldgate serves it: a
        superset), so it would not go back onto that box (audit 000 #40, 001 #12)."""
        notes = []
        profile = self.profile
        analog_in = any(
            spec.kind is Kind.AI
            for spec in topology.channel_specs
            if self.expose is None or any(fnmatchcase(spec.id, p) for p in self.expose)
        )
        if profile.analog_event_timer_ms and analog_in:
            notes.append(
                f"master {profile.master.name} needs analog data to keep flowing (REQ-AS-15) "
                f"and the {profile.style.name} style sends analog changes as no TPDO event: "
                f"analog TPDOs get an event timer of {profile.analog_event_timer_ms} ms "
                "(tpdos: sets another)"
            )
        served = self.served_backs([b.name for b in topology.backs])
        for back in topology.backs:
            limits = BOX_LIMITS.get((self.style, back.type))
            if limits is None or back.name not in served:
                continue
            notes += box_limit_notes(back, *limits)
        return notes

    def check(self, topology: Any) -> list[tuple[tuple[Any, ...], str]]:
        """The limits ``run`` applies when the front starts, at validation: the style's image
        (the NA-9161's 32 slots and 64 bytes per direction), the default PDOs, bit objects;
        ``field_power`` names an input."""
        issues = check_io(self, GatewayContext.build(topology))
        if self.field_power is not None:
            spec = next((c for c in topology.channel_specs if c.id == self.field_power), None)
            if spec is None or spec.kind.is_output:
                issues.append(
                    (
                        ("field_power",),
                        f"{self.field_power!r} is no input channel of this topology (e.g. rs485/m1/di7)",
                    )
                )
        return issues

    @field_validator("sync_cob_id")
    @classmethod
    def _sync_cob_id_not_restricted(cls, value: int) -> int:
        if restricted(value):
            raise ValueError(
                f"0x{value:03X} is a restricted CAN-ID (CiA 301 §7.3.5); 0x80 is the usual SYNC COB-ID"
            )
        return value
