"""A DCON module's stored output values: the safe value its host watchdog applies and the
power-on value, set from the topology when the module first comes online and latched from
the current outputs on request (a front's "safe value = current" command).

``~AA5PPSS`` sets both on the I-7011 family; other modules store the value their outputs
hold at ``~AA5S``/``~AA5P`` (digital) or ``~AA5N``/``$AA4N`` (analog), so a configured value
is latched by driving the outputs through it for one transaction: what the module output
before is read back first and restored right after.
"""

from __future__ import annotations

import logging
from typing import Protocol

from . import codec
from .config import DconModuleConfig
from .formats import DataFormat, ao_text_to_raw
from .link import DconLink
from .profiles import AIDIO, AO_SINGLE, Profile
from .tables import TypeRange

log = logging.getLogger("fieldgate.dcon")


class ModuleWire(Protocol):
    """What the stored values need of a module (:class:`.module.DconModule`)."""

    config: DconModuleConfig
    profile: Profile
    address: int
    range: TypeRange | None
    data_format: DataFormat | None
    config_error: str

    @property
    def link(self) -> DconLink: ...
    @property
    def link_name(self) -> str: ...

    async def ask(self, body: str, lead: str = "$") -> str: ...
    async def command(self, text: str) -> None: ...
    async def write_analog(self, index: int, raw: int) -> None: ...


def _ao_channels(p: Profile) -> list[str]:
    return [""] if p.ao_style == AO_SINGLE else [str(i) for i in range(p.ao)]


async def store_configured(m: ModuleWire) -> None:
    """Safe and power-on values of the topology: ``~AA5PPSS`` (I-7011 family), else latch a
    value written first."""
    cfg, p = m.config, m.profile
    if cfg.safe_value is None and cfg.power_on_value is None:
        return
    if p.digital == AIDIO:
        current = await m.ask("4", "~")  # !AAPPSS
        pp = (
            cfg.power_on_value
            if cfg.power_on_value is not None
            else codec.hex_field(current[0:2], "power-on value")
        )
        ss = (
            cfg.safe_value
            if cfg.safe_value is not None
            else codec.hex_field(current[2:4], "safe value")
        )
        await m.ask(f"5{pp:02X}{ss:02X}", "~")
    elif p.do:
        if not await _latch_digital(m):
            return
    else:
        await _latch_analog(m)
    log.info("%s module %d (%s): safe/power-on values stored", m.link_name, m.address, p.model)


async def _latch_digital(m: ModuleWire) -> bool:
    """Returns False when the module already held both values (nothing written)."""
    cfg, p = m.config, m.profile
    wanted = [
        (letter, value)
        for letter, value in (("S", cfg.safe_value), ("P", cfg.power_on_value))
        if isinstance(value, int)  # (a bit pattern: the config checks it for digital modules)
    ]
    missing = [
        (letter, value)
        for letter, value in wanted
        if codec.hex_field((await m.ask(f"4{letter}", "~"))[:8], "DO value") != value
    ]
    if not missing:
        return False  # already stored: no need to drive the outputs through them
    before, _ = p.decode_dio(
        codec.data(await m.link.transact(codec.command("@", m.address)), m.address)
    )
    for letter, value in missing:
        await m.command(codec.command("@", m.address, p.encode_do(value)))
        await m.ask(f"5{letter}", "~")
    await m.command(codec.command("@", m.address, p.encode_do(before)))
    return True


async def _latch_analog(m: ModuleWire) -> None:
    cfg, p = m.config, m.profile
    data_format, type_range = m.data_format, m.range
    if type_range is None or data_format is None or m.config_error:
        return
    channels = _ao_channels(p)
    before = [ao_text_to_raw(await m.ask(f"6{ch}"), data_format, type_range)[0] for ch in channels]
    for value, (lead, body) in ((cfg.safe_value, ("~", "5")), (cfg.power_on_value, ("$", "4"))):
        if value is None:
            continue
        values = value if isinstance(value, list) else [value] * p.ao
        for index, raw in enumerate(values):
            await m.write_analog(index, raw)
            await m.ask(body + channels[index], lead)
    for index, raw in enumerate(before):
        await m.write_analog(index, raw)


async def latch_current(m: ModuleWire) -> None:
    """The module's current outputs become its safe values (what its host watchdog applies):
    ``~AA5S`` (I-7000 digital), ``~AA5PPSS`` with the current DO (I-7011 family, power-on
    value kept), ``~AA5`` / ``~AA5N`` (analog outputs)."""
    p = m.profile
    if p.digital == AIDIO and p.do:
        current = await m.ask("4", "~")  # !AAPPSS
        outputs = codec.hex_field((await m.ask("DI", "@"))[1:3], "DO")  # !AASOOII
        await m.ask(f"5{current[0:2]}{outputs:02X}", "~")
    elif p.do:
        await m.ask("5S", "~")
    if p.ao:
        for channel in _ao_channels(p):
            await m.ask("5" + channel, "~")
    log.info(
        "%s module %d (%s): current outputs latched as the safe values",
        m.link_name,
        m.address,
        p.model,
    )
