"""The ``modbus`` back: module profiles for core's line scheduler.

Core's :class:`~fieldgate.polling.LineScheduler` decides *when* (writes ahead of reads,
poll periods, offline and re-probe, quality); this module decides *what goes on the
wire*: coalesced reads with per-point fallback, and write requests for changed outputs.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from itertools import groupby
from typing import Any

from fieldgate.image import ChannelSpec, ProcessImage, Quality, Value
from fieldgate.plugin import GatewayContext
from fieldgate.polling import NOTHING_DUE, PolledModule, SerialBack
from fieldgate.topology import ModuleConfig

from . import values as regvalues
from .client import ModbusExceptionError, ModbusLink, Transactions
from .codec import ExceptionCode, Function
from .config import ModbusBackConfig, ModbusModuleConfig, module_points
from .plan import ReadBlock, decode_block, plan_reads, plan_writes
from .points import Point, Table

log = logging.getLogger("fieldgate.modbus")

TABLE_NAMES = {
    Table.COILS: "coil",
    Table.DISCRETE_INPUTS: "discrete input",
    Table.HOLDING_REGISTERS: "holding register",
    Table.INPUT_REGISTERS: "input register",
}


class ModbusModule(PolledModule):
    """One Modbus slave: its read plan, its outputs, and the points it refused."""

    def __init__(
        self,
        config: ModbusModuleConfig,
        specs: list[ChannelSpec],
        link: Transactions,
        points: list[Point],
        *,
        retry_period: float = 5.0,
        clock: Callable[[], float],
        unit: int | None = None,
        image: ProcessImage | None = None,
    ):
        super().__init__(config, specs)
        self.link = link
        self.unit = config.address if unit is None else unit  # TCP: the device's own unit id
        self.clock = clock
        self.retry_period = retry_period
        self.reads = 0  # read transactions made, so a poll with nothing due can say so
        self.outputs_by_id = {p.channel: p for p in points if p.kind.is_output}
        inputs = [p for p in points if not p.kind.is_output]
        # A module with outputs only is read back, so that a dead module is noticed.
        self._readable = inputs or list(self.outputs_by_id.values())
        self._discard = not inputs
        self._limits = (config.max_read_registers, config.max_read_bits)
        self._gap = config.coalesce_gap
        self.bad: dict[str, float] = {}  # channel -> when to try it again
        self.last: dict[str, object] = {}
        self.allow_multiple_writes = True
        # Write spans (plan_writes): the image holds the values of the outputs between the
        # changed ones; without it (or with write_span off) only adjacent changes share a request.
        self.image = image if config.write_span else None
        self._write_limits = (config.max_write_bits, config.max_write_registers)
        self._fillable = {
            p.channel: p
            for p in self.outputs_by_id.values()
            if p.bit is None and p.write_fc not in (5, 6)
        }
        self.written: set[str] = set()  # outputs written since the last contact
        self.write_refused: set[str] = set()  # outputs whose last write was refused
        self._logged: set[tuple[object, ...]] = set()
        self.replan()

    def replan(self) -> None:
        points = [p for p in self._readable if p.channel not in self.bad]
        self.blocks: list[ReadBlock] = []
        for period in sorted({p.period or 0 for p in points}):
            same = [p for p in points if (p.period or 0) == period]
            self.blocks.extend(plan_reads(same, *self._limits, gap=self._gap))

    # -- reads ------------------------------------------------------------------------
    async def read_inputs(self) -> dict[str, object]:
        readings: dict[str, object] = {}
        now = self.clock()
        reads_before = self.reads
        for block in list(self.blocks):
            period = block.points[0].period
            if period and block.due > now:
                continue
            try:
                data = await self._read(block)
            except ModbusExceptionError as exc:
                readings.update(await self._fallback(block, exc))
            else:
                readings.update(decode_block(block, data))
            if period:
                block.due = now + period
        readings.update(await self._retry_bad(now))
        if self.reads == reads_before:
            return NOTHING_DUE
        if self._discard:
            return {}
        self.last.update({k: v for k, v in readings.items() if not isinstance(v, tuple)})
        return readings

    async def probe(self) -> None:
        """One read, due or not (an offline module must prove it answers); an exception is an answer."""
        points = {p.channel: p for p in self._readable}
        block = (
            self.blocks[0]
            if self.blocks
            else next((ReadBlock(p.table, p.address, p.width, [p]) for p in points.values()), None)
        )
        if block is None:
            return
        try:
            await self._read(block)
        except ModbusExceptionError:
            pass

    async def _read(self, block: ReadBlock) -> list[bool] | list[int]:
        self.reads += 1
        if block.table.is_bits:
            return await self.link.read_bits(self.unit, block.function, block.address, block.count)
        return await self.link.read_registers(self.unit, block.function, block.address, block.count)

    async def _fallback(self, block: ReadBlock, exc: ModbusExceptionError) -> dict[str, object]:
        """A coalesced read was refused: read its points one by one, drop the ones refused."""
        self._log_once(
            ("block", block.describe()),
            "module %d: %s answered exception %d; reading its points one by one",
            self.unit,
            block.describe(),
            exc.code,
        )
        readings: dict[str, object] = {}
        singles = (
            [ReadBlock(block.table, p.address, p.width, [p]) for p in block.points]
            if len(block.points) > 1
            else []
        )
        for single in singles:
            try:
                readings.update(decode_block(single, await self._read(single)))
            except ModbusExceptionError as point_exc:
                readings.update(self._refused(single.points[0], point_exc))
        if not singles:
            readings.update(self._refused(block.points[0], exc))
        self._gap = 0  # never coalesce across a refused address again
        self.replan()
        return readings

    def _refused(self, p: Point, exc: ModbusExceptionError) -> dict[str, object]:
        self.bad[p.channel] = self.clock() + self.retry_period
        self._log_once(
            ("point", p.channel),
            "module %d: %s (%s %d) refused with exception %d; quality config-error",
            self.unit,
            p.channel,
            p.table.value,
            p.address,
            exc.code,
        )
        return {p.channel: (self.last.get(p.channel, _zero(p)), Quality.CONFIG_ERROR)}

    async def _retry_bad(self, now: float) -> dict[str, object]:
        readings: dict[str, object] = {}
        if not self.bad:
            return readings
        points = {p.channel: p for p in self._readable}
        recovered = False
        for cid, due in list(self.bad.items()):
            p = points[cid]
            if due > now:
                readings[cid] = (self.last.get(cid, _zero(p)), Quality.CONFIG_ERROR)
                continue
            single = ReadBlock(p.table, p.address, p.width, [p])
            try:
                readings.update(decode_block(single, await self._read(single)))
            except ModbusExceptionError as exc:
                readings.update(self._refused(p, exc))
            else:
                del self.bad[cid]
                self._logged.discard(("point", cid))
                recovered = True
        if recovered:
            self.replan()
        return readings

    # -- writes -----------------------------------------------------------------------
    async def on_online(self) -> None:
        self.written.clear()  # the module may have been reset: what it holds is unknown

    async def send_outputs(self, values: dict[str, Any]) -> None:
        changes: list[tuple[Point, Value]] = [
            (self.outputs_by_id[cid], v) for cid, v in values.items() if cid in self.outputs_by_id
        ]
        whole = [(p, v) for p, v in changes if p.bit is None]
        held = self._held(values) if len(whole) > 1 else []
        for op in plan_writes(whole, self.allow_multiple_writes, held, *self._write_limits):
            if await self._write_request(op.function, op.address, op.values, op.points, op.filled):
                continue
            if op.filled:  # refused with held values in it: the changed outputs on their own
                self.write_refused |= op.filled
                mine = [(p, values[p.channel]) for p in op.points if p.channel not in op.filled]
                for alone in plan_writes(mine, self.allow_multiple_writes, (), *self._write_limits):
                    await self._write_request(
                        alone.function, alone.address, alone.values, alone.points
                    )
        in_registers = sorted(
            ((p, v) for p, v in changes if p.bit is not None), key=lambda pv: pv[0].address
        )
        for address, items in groupby(in_registers, key=lambda pv: pv[0].address):
            await self._write_bits_of_register(address, list(items))

    def _held(self, changed: dict[str, Any]) -> list[tuple[Point, Value]]:
        """The outputs a write span may fill in: whole coils and registers of this module
        whose value the gateway knows (written since the last contact, or set by a front or
        the config), none whose last write was refused; with the image's values (a changed
        output is in this batch, so the others hold what was last written)."""
        image = self.image
        if image is None or not self.allow_multiple_writes:
            return []
        held: list[tuple[Point, Value]] = []
        for cid, p in self._fillable.items():
            if cid in changed or cid in self.write_refused:
                continue
            channel = image[cid]
            if cid in self.written or channel.written_by or channel.spec.initial is not None:
                held.append((p, channel.value))
        return held

    async def _write_request(
        self,
        function: int,
        address: int,
        words: list[bool] | list[int],
        points: list[Point],
        filled: frozenset[str] = frozenset(),
    ) -> bool:
        """One write; False when the module refused it (logged once, its channels marked)."""
        try:
            await self.link.write(self.unit, function, address, words)
        except ModbusExceptionError as exc:
            multiple = function in (
                Function.WRITE_MULTIPLE_COILS,
                Function.WRITE_MULTIPLE_REGISTERS,
            )
            if (
                multiple
                and exc.code == ExceptionCode.ILLEGAL_FUNCTION
                and self.allow_multiple_writes
            ):
                self.allow_multiple_writes = False
                log.warning(
                    "module %d refuses FC%d; writing with single-write functions from now on",
                    self.unit,
                    function,
                )
                single = (
                    Function.WRITE_SINGLE_COIL
                    if function == Function.WRITE_MULTIPLE_COILS
                    else Function.WRITE_SINGLE_REGISTER
                )
                ok = True
                for at, word, owners in _singles(address, words, points, filled):
                    ok = await self._write_request(single, at, [word], owners) and ok
                return ok
            # The module will not take this value: keep the line going, count it, say it once.
            self.write_refused.update(p.channel for p in points)
            self._log_once(
                ("write", function, address),
                "module %d refused FC%d at %d with exception %d (%s)",
                self.unit,
                function,
                address,
                exc.code,
                ", ".join(p.channel for p in points),
            )
            return False
        channels = {p.channel for p in points}
        self.written |= channels
        self.write_refused -= channels
        return True

    async def _write_bits_of_register(self, address: int, items: list[tuple[Point, Value]]) -> None:
        """Digital outputs or special bytes inside a holding register: read, change them, write back."""
        (current,) = await self.link.read_registers(
            self.unit, Function.READ_HOLDING_REGISTERS, address, 1
        )
        for p, value in items:
            assert p.bit is not None  # (only such points come here)
            current = regvalues.set_field(current, p.bit, p.bits, p.raw_of(value))
        forced = (
            Function.WRITE_MULTIPLE_REGISTERS
            if any(p.write_fc == 16 for p, _ in items)
            else Function.WRITE_SINGLE_REGISTER
        )
        await self._write_request(forced, address, [current], [p for p, _ in items])

    def _log_once(self, key: tuple[object, ...], message: str, *args: object) -> None:
        if key in self._logged:
            log.debug(message, *args)
        else:
            self._logged.add(key)
            log.warning(message, *args)


def _singles(
    address: int, words: list[bool] | list[int], points: list[Point], filled: frozenset[str]
) -> list[tuple[int, bool | int, list[Point]]]:
    """A refused multiple write as single writes: (address, word, its points) for every
    coil or register of the changed outputs (held values in a span are not rewritten)."""
    if not filled:
        return [(address + i, word, points) for i, word in enumerate(words)]
    singles: list[tuple[int, bool | int, list[Point]]] = []
    offset = 0
    for p in points:  # a span holds whole coils and registers only
        if p.channel not in filled:
            singles.extend((p.address + i, words[offset + i], [p]) for i in range(p.width))
        offset += p.width
    return singles


def _zero(p: Point) -> bool | int:
    return False if p.kind.is_digital else 0


def describe_point(p: Point) -> str:
    """Where a point lives and how it is read: ``holding registers 10-13 (float64, CDAB) (FC3)``."""
    where = f"{TABLE_NAMES[p.table]} {p.address}"
    if p.width > 1:
        where = f"{TABLE_NAMES[p.table]}s {p.address}-{p.end - 1} ({p.dtype.value}, {p.order})"
    if p.bit is not None:
        where += f" bit {p.bit}" if p.bits == 1 else f" bits {p.bit}-{p.bit + p.bits - 1}"
    if p.engineering is not None:
        where += f" [{p.engineering.describe()}]"
    codes = f"FC{p.table.read_function}"
    if p.write_fc is not None:
        codes += f", written with FC{p.write_fc}"
    return f"{where} ({codes})"


class ModbusBack(SerialBack):
    """Modbus RTU master on one RS-485 line."""

    config: ModbusBackConfig

    async def open_link(self) -> ModbusLink:
        link = ModbusLink.from_config(self.config)
        await link.open()
        return link

    def unopened_link(self) -> ModbusLink:
        """The modules hold the link; it is opened when the port is there (:meth:`reopen_link`)."""
        return ModbusLink.from_config(self.config)

    async def close_link(self) -> None:
        self.link.close()

    def point_locations(self) -> dict[str, list[str]]:
        """The Modbus table and address of each point (status API); addresses as on the
        wire (0-based), the function codes that read and write it."""
        return {
            p.channel: [describe_point(p)]
            for module in self.config.modules
            for p in module_points(self.name, module)
        }

    async def reopen_link(self) -> None:
        await self.link.open()  # the same ModbusLink (the modules hold it), a new pymodbus client

    def make_module(self, config: ModuleConfig, specs: list[ChannelSpec]) -> ModbusModule:
        assert isinstance(config, ModbusModuleConfig)  # (the modules of a modbus back)
        points = module_points(self.name, config)
        module = ModbusModule(
            config,
            specs,
            self.link,
            points,
            retry_period=self.config.offline_probe_ms / 1000,
            clock=self.context.clock,
            image=self.context.image,
        )
        self.modules[config.address] = module
        return module

    def __init__(self, config: ModbusBackConfig, context: GatewayContext) -> None:
        super().__init__(config, context)
        self.modules: dict[int, ModbusModule] = {}  # the current run's modules, by address

    async def start(self) -> None:
        self.modules.clear()
        await super().start()

    def status(self) -> dict[str, Any]:
        status = super().status()
        if self.link is not None:
            status["modbus"] = {
                **self.link.stats.as_dict(),
                "echo": self.link.echo.describe(),
                "refused_points": sorted(cid for m in self.modules.values() for cid in m.bad),
                "single_writes_only": sorted(
                    a for a, m in self.modules.items() if not m.allow_multiple_writes
                ),
            }
        return status
