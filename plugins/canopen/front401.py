"""Wiring the CiA 401 I/O device into the ``canopen`` front.

The front's configuration gains the :class:`IoFrontOptions` fields; :func:`io_device`
builds the :class:`~.cia401.iodevice.IoDevice` every canopen front adds to its node before
it boots (its objects are what the node's PDO service maps). The front itself owns the
master state (error control's monitoring and, with ``error_on_stopped``, NMT Stopped:
:mod:`.master_state`) and the module-offline EMCY, so the I/O device only adds what is
its own: the CiA 401 and manufacturer objects (0x2001-0x2003 through the gateway's
``HostWatchdogs.from_context``), the events that become TPDOs and the acknowledgement of
a module error by clearing its 0x2000 counter.

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
from typing import Any, Literal

from pydantic import Field, field_validator

from fieldgate.host_watchdog import HostWatchdogs
from fieldgate.image import ErrorMode
from fieldgate.topology.model import StrictModel

from .cia301.pdo.defaults import PdoSetting
from .cia401.iodevice import IoDevice, IoSettings, build_io, check_pdo_settings
from .cia401.layouts import LayoutError

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
        description="TPDOs sent once on entering Operational; default async (icpdas) / all (na9161)",
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


def io_settings(options: Any) -> IoSettings:
    """The I/O device's settings from a front configuration (its resolved device and master
    profile, :mod:`.profiles`, when it has one)."""
    profile = getattr(options, "profile", None)
    settings = IoSettings(
        style=options.style,
        pdo_count=options.pdo_count,
        mapping_closed=options.mapping_closed,
        compressed=options.compressed,
        start_policy=options.tpdo_on_start,
        error_on_stopped=options.error_on_stopped,
        bit_mapping=options.bit_mapping,
        tpdo_settings={n: p.setting() for n, p in options.tpdos.items()},
        rpdo_settings={n: p.setting() for n, p in options.rpdos.items()},
    )
    if profile is not None:
        settings.analog_events = profile.analog_events
        settings.short_ao_error_writes = profile.style.short_ao_error_writes
        settings.empty_pdos_invalid = profile.empty_pdos_invalid
    return settings


def check_io(cfg: Any, context: Any) -> list[tuple[tuple[Any, ...], str]]:
    """What :func:`install` would refuse for this front configuration, as validation issues."""
    models = {(b.name, m.address): m.model or "" for b in context.topology.backs for m in b.modules}
    settings = io_settings(cfg)
    channels = context.front_channels(cfg)
    try:
        build_io(settings, context.image, channels, cfg.name, models=models)
    except LayoutError as exc:
        return [((), str(exc))]
    if not cfg.tpdos and not cfg.rpdos:
        return []
    io = IoDevice(
        settings, context.image, channels, origin=cfg.name, models=models, master_events=False
    )
    return [
        ((field, number), message)
        for field, number, message in check_pdo_settings(io, cfg.node_id or 0)
    ]


def default_error_modes(front: Any) -> list[str]:
    """With ``error_mode_default: zero`` (the NA-9161: 0x6206 = 0xFF, 0x6207 = 0x00, 0x6443 = 1,
    0x6444 = 0), every digital and analog output this front serves whose module sets no
    error mode of its own (``error_mode`` / ``error_modes``) goes to 0 on an error event.
    Returns the channel ids given that default."""
    cfg, ctx = front.config, front.context
    if not cfg.profile.outputs_to_zero:
        return []
    modules = {(b.name, m.address): m for b in ctx.topology.backs for m in b.modules}
    changed = []
    for ch in ctx.front_channels(cfg):
        if not ch.kind.is_output or ch.kind.is_special:
            continue
        module = modules.get((ch.source.back, ch.source.module))
        local = f"{ch.kind.value}{ch.source.index}"
        if module is not None and (
            "error_mode" in module.model_fields_set or local in module.error_modes
        ):
            continue
        ctx.image.set_error_mode(ch.id, ErrorMode.to(False if ch.kind.is_digital else 0))
        changed.append(ch.id)
    return changed


def io_device(front: Any) -> IoDevice:
    """The I/O device of a canopen front (``front.config``, ``front.context``), replacing the
    one of a previous start; outputs without an error mode of their own get the style's
    (:func:`default_error_modes`) first, so the objects start with them."""
    previous = getattr(front, "io", None)
    if previous is not None:
        previous.detach()
    default_error_modes(front)
    cfg, ctx = front.config, front.context
    models = {(b.name, m.address): m.model or "" for b in ctx.topology.backs for m in b.modules}
    return IoDevice(
        io_settings(cfg),
        ctx.image,
        ctx.front_channels(cfg),
        origin=front.name,
        health=ctx.health,
        masters=ctx.masters,
        front=front.name,
        host_watchdogs=HostWatchdogs.from_context(ctx),
        models=models,
        master_events=False,
        module_emcy=False,
    )
