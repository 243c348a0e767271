"""A DCON module as the line scheduler polls it: reads, writes, configuration, watchdog state."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from fieldgate.health import ErrorKind
from fieldgate.image import ChannelSpec, Kind, ProcessImage, Quality
from fieldgate.polling import CommError, PolledModule

from . import codec, output_values
from .config import DconModuleConfig
from .formats import DataFormat, raw_to_text, split_values, text_to_raw
from .link import DconLink
from .profiles import AIDIO, AO_SINGLE, DIO, find_profile
from .tables import TABLES, TypeRange

log = logging.getLogger("fieldgate.dcon")

WATCHDOG_TIMEOUT_BIT = 0x04  # ~AA0 status: host watchdog timeout occurred
RESET_CHECK_EVERY = 10  # polls between two $AA5 reset-status reads of a module with outputs


class DconModule(PolledModule):
    config: DconModuleConfig

    def __init__(
        self,
        config: DconModuleConfig,
        specs: list[ChannelSpec],
        image: ProcessImage,
        link: DconLink | None,
        watch_status: bool = False,
    ):
        super().__init__(config, specs)
        self.image = image
        self._link = link  # None while the port is missing at start (the back sets it)
        self.profile = config.profile
        self.by_kind: dict[Kind, list[str]] = {
            k: [s.id for s in sorted(specs, key=lambda s: s.source.index) if s.kind is k]
            for k in Kind
        }
        self.range: TypeRange | None = None
        self.data_format: DataFormat | None = None
        self.config_reply: codec.ModuleConfigReply | None = None  # the last $AA2
        self.config_error = ""
        self.warnings: list[str] = []
        self.name = ""
        self.firmware = ""
        self.in_watchdog = False
        self.watchdog_events = 0
        self.safe_values_latched = 0
        self.latch_after_write = False  # set by the back: safe_value current, host OK stopped
        self.last_clear = ""  # how the last clear went (status)
        self.watch_status = (
            watch_status  # poll ~AA0 with the inputs (set while host OK is suspended)
        )
        self._outputs_configured = False
        self.polls = 0
        self.resets = 0
        self._seen_online = False
        # set by the back: rewrite the outputs
        self.on_reset: Callable[[DconModule], None] = lambda module: None
        wd = config.watchdog
        self.watchdog_enabled = bool(wd and wd.enabled)
        self.watchdog_timeout_ms = wd.timeout_ms if wd else 0

    # -- helpers ----------------------------------------------------------------
    @property
    def link(self) -> DconLink:
        if self._link is None:
            raise CommError(ErrorKind.IO, "the port is not open")
        return self._link

    @link.setter
    def link(self, link: DconLink) -> None:
        self._link = link

    async def ask(self, body: str, lead: str = "$") -> str:
        return codec.addressed(
            await self.link.transact(codec.command(lead, self.address, body)), self.address
        )

    async def command(self, text: str) -> None:
        """A command whose answer is an acknowledgement only (an output write, a setting)."""
        codec.write_ack(await self.link.transact(text))

    async def read_config(self) -> codec.ModuleConfigReply:
        """``$AA2``: adopt the module's type code and data format; note mismatches with the topology."""
        reply = codec.parse_config(
            await self.link.transact(codec.command("$", self.address, "2")), self.address
        )
        self._adopt(reply)
        self.config_reply = reply
        return reply

    def _adopt(self, reply: codec.ModuleConfigReply) -> None:
        cfg, p = self.config, self.profile
        warnings, error = [], ""
        if cfg.type_code is not None and reply.type_code != cfg.type_code:
            warnings.append(
                f"type code 0x{reply.type_code:02X}, topology says 0x{cfg.type_code:02X}"
            )
        key = p.ai_table or p.ao_table
        if key:
            self.range = TABLES[key].get(reply.type_code)
            if self.range is None:
                error = f"type code 0x{reply.type_code:02X} is not a {p.model} range"
        fmt = DataFormat(reply.data_format)
        if key and cfg.data_format not in ("auto", fmt.label):
            warnings.append(f"data format {fmt.label}, topology says {cfg.data_format}")
        if (
            self.range is not None
            and fmt is DataFormat.OHMS
            and self.range.sensor not in ("pt385", "pt3916", "pt1000")
        ):
            error = f"ohms format of {self.range.describe()} is not supported; set the module to hex format"
        self.data_format = fmt if key else None
        if warnings != self.warnings:
            for w in warnings:
                log.warning(
                    "%s module %d (%s): %s; using the module's setting",
                    self.link_name,
                    self.address,
                    p.model,
                    w,
                )
        self.warnings, self.config_error = warnings, error

    @property
    def link_name(self) -> str:
        return self.specs[0].source.back if self.specs else "dcon"

    # -- inputs ---------------------------------------------------------------------
    async def read_inputs(self) -> dict[str, Any]:
        p = self.profile
        readings: dict[str, Any] = {}
        if (p.ai or p.ao) and self.data_format is None:
            await self.read_config()
        if p.digital == DIO:
            do_bits, di_bits = p.decode_dio(
                codec.data(await self.link.transact(codec.command("@", self.address)), self.address)
            )
            readings.update(self._bits(Kind.DI, di_bits))
        elif p.digital == AIDIO:
            body = await self.ask("DI", "@")  # !AASOOII
            if len(body) != 5:
                raise CommError(ErrorKind.GARBAGE, f"@AADI reply should carry SOOII, got {body!r}")
            readings.update(self._bits(Kind.DI, codec.hex_field(body[3:5], "DI")))
        if p.ai:
            readings.update(await self._read_analog())
        if (self.watch_status and self.watchdog_enabled) or not (p.di or p.do or p.ai):
            await (
                self.read_status()
            )  # analog-output modules have nothing else to read: status keeps them polled
        self.polls += 1
        if (p.do or p.ao) and self.polls % RESET_CHECK_EVERY == 0:
            await self.check_reset()
        return readings

    async def check_reset(self) -> bool:
        """``$AA5``: a module reset (power glitch) between two polls is back at its power-on
        values without ever looking offline; its outputs are written again."""
        if await self.ask("5") != "1":
            return False
        self.resets += 1
        log.warning(
            "%s module %d (%s) was reset: writing its outputs again",
            self.link_name,
            self.address,
            self.profile.model,
        )
        self.on_reset(self)
        return True

    def _bits(self, kind: Kind, bits: int) -> dict[str, bool]:
        return {cid: bool(bits >> i & 1) for i, cid in enumerate(self.by_kind[kind])}

    async def _read_analog(self) -> dict[str, Any]:
        ids = self.by_kind[Kind.AI]
        if self.config_error:
            await self.read_config()  # keeps the module polled, and sees it when it is set right
        if self.config_error:
            return {cid: (self.image.value(cid), Quality.CONFIG_ERROR) for cid in ids}
        assert self.range is not None and self.data_format is not None
        data = codec.data(await self.link.transact(codec.command("#", self.address)), self.address)
        try:
            values = split_values(data, self.data_format, len(ids))
            return {
                cid: text_to_raw(text, self.data_format, self.range)
                for cid, text in zip(ids, values, strict=False)
            }
        except CommError:
            # data that do not fit the format learnt from $AA2: that reply may have been a
            # distorted one (no checksum); the next poll reads $AA2 again before the data
            self.data_format = None
            raise

    async def probe(self) -> None:
        await self.read_config()

    # -- outputs --------------------------------------------------------------------
    async def send_outputs(self, values: dict[str, Any]) -> None:
        if not values:
            return
        if self.in_watchdog:
            return  # the module ignores writes until ~AA1; they are re-sent after clear_watchdog()
        p = self.profile
        try:
            if p.do and any(cid in values for cid in self.by_kind[Kind.DO]):
                await self._write_digital()
            for index, cid in enumerate(self.by_kind[Kind.AO]):
                if cid in values:
                    await self.write_analog(index, int(values[cid]))
            if self.latch_after_write and not self.in_watchdog:
                await self.latch_safe_value()  # safe_value: current while the host OK is off
        except CommError as exc:
            if exc.kind is ErrorKind.WATCHDOG:
                self.enter_watchdog("an output write was answered '!'")
            raise

    def _do_bits(self) -> int:
        return sum(1 << i for i, cid in enumerate(self.by_kind[Kind.DO]) if self.image.value(cid))

    async def _write_digital(self) -> None:
        p, bits = self.profile, self._do_bits()
        if p.digital == AIDIO:
            await self.ask(f"DO{bits:02X}", "@")
            if self.watchdog_enabled and await self.read_status() & WATCHDOG_TIMEOUT_BIT:
                # this family answers !AA even when it ignores the write
                raise CommError(
                    ErrorKind.WATCHDOG, "output write ignored: module in host-watchdog timeout"
                )
            return
        await self.command(codec.command("@", self.address, p.encode_do(bits)))

    async def write_analog(self, index: int, raw: int) -> None:
        if self.range is None or self.data_format is None:
            await self.read_config()
        if self.config_error or self.range is None or self.data_format is None:
            raise CommError(ErrorKind.EXCEPTION, self.config_error or "no type code")
        p = self.profile
        text = raw_to_text(
            raw,
            self.data_format,
            self.range,
            hex_width=p.ao_hex_width,
            signed_text=p.ao_signed_text,
            round_up=True,
        )
        body = text if p.ao_style == AO_SINGLE else f"{index}{text}"
        await self.command(codec.command("#", self.address, body))

    def output_quality(self) -> Quality:
        return Quality.WATCHDOG if self.in_watchdog else Quality.GOOD

    # -- host watchdog ----------------------------------------------------------------
    def enter_watchdog(self, why: str) -> None:
        if not self.in_watchdog:
            self.in_watchdog = True
            self.watchdog_events += 1
            log.warning(
                "%s module %d (%s) is in host-watchdog timeout (%s): outputs at their safe values until cleared",
                self.link_name,
                self.address,
                self.profile.model,
                why,
            )
        self.image.set_quality(self.outputs, Quality.WATCHDOG)

    async def read_status(self) -> int:
        """``~AA0``: bit 2 = host-watchdog timeout occurred (kept until ``~AA1``)."""
        body = await self.ask("0", "~")
        status = codec.hex_field(body[:2], "module status")
        if status & WATCHDOG_TIMEOUT_BIT:
            self.enter_watchdog("module status says so")
        return status

    async def send_clear(self) -> None:
        """``~AA1``: reset the host-watchdog timeout flag (the sequence around it is core's:
        ``fieldgate.host_watchdog.clear_timeout``)."""
        await self.ask("1", "~")

    async def timeout_flag(self) -> bool:
        """``~AA0``: whether the host-watchdog timeout flag is set."""
        body = await self.ask("0", "~")
        return bool(codec.hex_field(body[:2], "module status") & WATCHDOG_TIMEOUT_BIT)

    def watchdog_cleared(self, outcome: str) -> None:
        """The clear was confirmed: outputs answer again (their values are being rewritten)."""
        if self.in_watchdog:
            log.info(
                "%s module %d: host-watchdog timeout %s", self.link_name, self.address, outcome
            )
        self.in_watchdog = False
        self.last_clear = outcome
        self.image.set_quality(self.outputs, Quality.GOOD)

    async def configure_watchdog(self) -> None:
        await self.ask(
            codec.watchdog_setup(
                self.address, self.watchdog_enabled, self.watchdog_timeout_ms or 100
            )[3:],
            "~",
        )

    # -- coming online --------------------------------------------------------------------
    async def on_online(self) -> None:
        if not self.name:
            self.name = await self.ask("M")
            self.firmware = await self.ask("F")
            found = find_profile(self.name)
            if found is not None and found is not self.profile:
                self.warnings.append(
                    f"module answers $AAM as {self.name!r}, topology says {self.profile.model}"
                )
                log.warning(
                    "%s module %d: $AAM says %r, topology says %s",
                    self.link_name,
                    self.address,
                    self.name,
                    self.profile.model,
                )
        if await self.ask("5") == "1":
            log.info(
                "%s module %d (%s) was reset or powered up",
                self.link_name,
                self.address,
                self.profile.model,
            )
            if self._seen_online:
                self.resets += 1  # the scheduler rewrites the outputs after on_online
        self._seen_online = True
        await self.read_config()
        if (
            self.config.watchdog is not None or self.watchdog_enabled
        ):  # from the topology or set at run time
            await self.configure_watchdog()
        if self.profile.do or self.profile.ao:
            await self.read_status()
            if not self._outputs_configured and not self.in_watchdog:
                await output_values.store_configured(self)
                self._outputs_configured = True

    # -- safe values -------------------------------------------------------------------
    @property
    def has_outputs(self) -> bool:
        return bool(self.profile.do or self.profile.ao)

    async def latch_safe_value(self) -> None:
        """The module's current outputs become its safe values (:mod:`.output_values`)."""
        await output_values.latch_current(self)
        self.safe_values_latched += 1

    def point_locations(self) -> dict[str, list[str]]:
        """The DCON command that reads or writes each of its points (status API)."""
        out: dict[str, list[str]] = {}
        aa, p = f"{self.address:02X}", self.profile
        read_di, write_do = (
            (f"@{aa}DI reply", f"@{aa}DO(data)")
            if p.digital == AIDIO
            else (f"@{aa} reply", f"@{aa}(data)")
        )
        for i, cid in enumerate(self.by_kind[Kind.DI]):
            out[cid] = [f"{read_di} bit {i}"]
        for i, cid in enumerate(self.by_kind[Kind.DO]):
            out[cid] = [f"{write_do} bit {i}"]
        for i, cid in enumerate(self.by_kind[Kind.AI]):
            out[cid] = [f"#{aa} reply, value {i + 1}"]
        for i, cid in enumerate(self.by_kind[Kind.AO]):
            out[cid] = [f"#{aa}(data)" if p.ao_style == AO_SINGLE else f"#{aa}{i}(data)"]
        return out

    def status(self) -> dict[str, Any]:
        return {
            "address": self.address,
            "model": self.profile.model,
            "name": self.name,
            "firmware": self.firmware,
            "type_code": None if self.range is None else f"0x{self.range.code:02X}",
            "range": None if self.range is None else self.range.label,
            "data_format": None if self.data_format is None else self.data_format.label,
            "watchdog": {
                "enabled": self.watchdog_enabled,
                "timeout_ms": self.watchdog_timeout_ms,
                "timed_out": self.in_watchdog,
                "events": self.watchdog_events,
                "last_clear": self.last_clear,
            },
            "resets_seen": self.resets,
            "safe_values_latched": self.safe_values_latched,
            "warnings": list(self.warnings),
            "config_error": self.config_error,
        }
