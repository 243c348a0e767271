"""Wiring the CiA 401 I/O device into the ``canopen`` front.

:func:`io_device` builds the :class:`~.cia401.iodevice.IoDevice` every canopen front adds to
its node before it boots (its objects are what the node's PDO service maps), from the
front's :class:`~.config.IoFrontOptions` (:func:`io_settings`); :func:`check_io` is what
``fieldgate validate`` checks of it. The front itself owns the master state (error
control's monitoring and, with ``error_on_stopped``, NMT Stopped: :mod:`.master_state`) and
the module-offline EMCY, so the I/O device only adds what is its own: the CiA 401 and
manufacturer objects (0x2001-0x2003 through the gateway's ``HostWatchdogs.from_context``),
the events that become TPDOs and the acknowledgement of a module error by clearing its
0x2000 counter.
"""

from __future__ import annotations

from typing import Any

from fieldgate.host_watchdog import HostWatchdogs
from fieldgate.image import ErrorMode
from fieldgate.module_info import ModuleInfo

from .cia401.iodevice import IoDevice, IoSettings, build_io, check_pdo_settings
from .cia401.layouts import LayoutError


def io_settings(options: Any) -> IoSettings:
    """The I/O device's settings from a front configuration (its resolved device and master
    profile, :mod:`.profiles`, when it has one)."""
    profile = getattr(options, "profile", None)
    settings = IoSettings(
        style=options.style,
        pdo_count=options.pdo_count,
        mapping_closed=options.mapping_closed,
        compressed=options.compressed,
        start_policy=getattr(profile, "tpdo_on_start", None) or options.tpdo_on_start,
        error_on_stopped=options.error_on_stopped,
        bit_mapping=options.bit_mapping,
        tpdo_settings={n: p.setting() for n, p in options.tpdos.items()},
        rpdo_settings={n: p.setting() for n, p in options.rpdos.items()},
    )
    if profile is not None:
        settings.analog_events = profile.analog_events
        settings.short_ao_error_writes = profile.style.short_ao_error_writes
        settings.empty_pdos_invalid = profile.empty_pdos_invalid
        settings.analog_event_timer_ms = profile.analog_event_timer_ms
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
        module_info=ModuleInfo.from_context(ctx),
    )
