"""The ``jsonfile`` back: reads the inputs file every ``poll_ms``, writes the outputs file
when a front changes an output; module health and quality as core's serial backs keep them."""

import asyncio
import json
from typing import Any

from fieldgate import (
    Back,
    ErrorKind,
    GatewayContext,
    Kind,
    ModuleHealth,
    PluginStartError,
    Quality,
    channel_id,
)
from fieldgate.image import Subscription, integer_range
from fieldgate.metric_samples import Sample, counter
from fieldgate.persist import write_atomic

from .config import FileModule, JsonFileConfig


class JsonFileBack(Back):
    config: JsonFileConfig

    def __init__(self, config: JsonFileConfig, context: GatewayContext):
        super().__init__(config, context)
        base = context.topology.base_dir  # relative paths are next to the topology file
        self.path = base / config.path
        self.outputs_path = base / config.outputs_path
        self.health = {
            m.address: context.health.add(
                ModuleHealth(self.name, m.address, m.model or "", config.fail_threshold)
            )
            for m in config.modules
        }
        self.reads = self.bad_reads = self.writes = 0
        self._changed = asyncio.Event()
        self._subscription: Subscription | None = None

    # -- life cycle: start, run until cancelled, stop ---------------------------------------
    async def start(self) -> None:
        if not self.path.parent.is_dir():
            raise PluginStartError(f"no folder {self.path.parent} (for {self.path.name})")
        image = self.context.image
        outputs = [c.id for c in image.channels(back=self.name) if c.kind.is_output]
        self._subscription = image.subscribe(lambda change: self._changed.set(), ids=outputs)
        self._changed.set()  # what fronts or initial values set before we started

    async def run(self) -> None:
        while True:
            try:  # in a thread: a slow disk never delays the fronts' answers
                text = await asyncio.to_thread(self.path.read_text, encoding="utf-8")
            except OSError as exc:
                self._failed_all(ErrorKind.IO, f"{self.path}: {exc.strerror or exc}")
            else:
                self._apply(text)
            if self._changed.is_set():
                self._changed.clear()
                await self.flush_outputs()
            try:
                await asyncio.wait_for(self._changed.wait(), self.config.poll_ms / 1000)
            except TimeoutError:
                pass

    async def flush_outputs(self) -> None:
        """Write the outputs file (core calls it at shutdown, after the shutdown values)."""
        data = json.dumps({"modules": self._outputs()}, indent=1).encode()
        await asyncio.to_thread(write_atomic, self.outputs_path, data)  # never half a file
        self.writes += 1

    async def stop(self) -> None:
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None

    # -- inputs ---------------------------------------------------------------------------------
    def _apply(self, text: str) -> None:
        self.reads += 1
        try:
            modules = json.loads(text)["modules"]
            if not isinstance(modules, dict):
                raise TypeError("'modules' is not an object")
        except (ValueError, KeyError, TypeError) as exc:
            self._failed_all(ErrorKind.GARBAGE, f"{self.path.name}: not readable: {exc}")
            return
        for m in self.config.modules:
            has_inputs = m.di or m.ai  # a module of outputs only needs no entry
            entry = modules.get(str(m.address), None if has_inputs else {})
            if not isinstance(entry, dict):
                self._failed(m, ErrorKind.TIMEOUT, f"module {m.address} not in {self.path.name}")
                continue
            readings: dict[str, Any] = {}
            for kind in (Kind.DI, Kind.AI):
                values, count = entry.get(kind.value, []), getattr(m, kind.value)
                if not isinstance(values, list) or len(values) < count:
                    self._failed(m, ErrorKind.GARBAGE, f"module {m.address}: {kind.value} short")
                    break
                for i in range(count):
                    readings[channel_id(self.name, m.address, kind, i)] = values[i]
            else:
                if self.health[m.address].record_success(now=self.context.clock()):
                    outputs = self._module_channels(m, outputs=True)  # back online
                    self.context.image.set_quality(outputs, Quality.GOOD)
                try:  # the module's inputs in one batch: one call for each batch subscriber
                    self.context.image.update_inputs(readings)
                except ValueError:  # a value that does not fit its channel: one by one
                    for cid, value in readings.items():
                        self._update(cid, value)

    def _update(self, cid: str, value: Any) -> None:
        image = self.context.image
        try:
            image.update_input(cid, value)  # checked against the channel's data type
        except ValueError:
            if image[cid].kind is Kind.AI and type(value) is int:  # outside int16
                low, high = integer_range(image[cid].spec.data_type)
                quality = Quality.OVER_RANGE if value > high else Quality.UNDER_RANGE
                image.update_input(cid, min(max(value, low), high), quality)
            else:  # a value of the wrong type: the file does not match the declaration
                image.set_quality([cid], Quality.CONFIG_ERROR)

    def _failed(self, m: FileModule, kind: ErrorKind, text: str) -> None:
        image, health = self.context.image, self.health[m.address]
        if health.record_failure(kind, text):  # this failure took the module offline
            image.set_quality(self._module_channels(m), Quality.COMM_FAULT)
        elif health.online:  # the last good values, no longer fresh
            fresh = self._module_channels(m, outputs=False)
            image.set_quality([c for c in fresh if image[c].quality is Quality.GOOD], Quality.STALE)

    def _failed_all(self, kind: ErrorKind, text: str) -> None:
        self.bad_reads += 1
        for m in self.config.modules:
            self._failed(m, kind, text)

    def _module_channels(self, m: FileModule, outputs: bool | None = None) -> list[str]:
        channels = self.context.image.channels(back=self.name, module=m.address)
        return [c.id for c in channels if outputs is None or c.kind.is_output == outputs]

    # -- outputs --------------------------------------------------------------------------------
    def _outputs(self) -> dict[str, dict[str, list[Any]]]:
        """Every module's outputs; null for one that no front (nor an initial value) has set:
        the gateway never drives an output to a value it invented."""
        out: dict[str, dict[str, list[Any]]] = {}
        for c in self.context.image.channels(back=self.name):
            if c.kind.is_output:
                value = c.value if c.written_by or c.spec.initial is not None else None
                out.setdefault(str(c.source.module), {}).setdefault(c.kind.value, []).append(value)
        return out

    # -- what people watching the gateway see ----------------------------------------------------
    def status(self) -> dict[str, Any]:
        return {
            "path": str(self.path),
            "outputs_path": str(self.outputs_path),
            "reads": self.reads,
            "bad_reads": self.bad_reads,
            "writes": self.writes,
        }

    def metrics(self) -> list[Sample]:
        return [
            counter("jsonfile_reads_total", "inputs file reads", self.reads),
            counter(
                "jsonfile_bad_reads_total", "inputs file missing or unreadable", self.bad_reads
            ),
            counter("jsonfile_writes_total", "outputs file writes", self.writes),
        ]

    def point_locations(self) -> dict[str, list[str]]:
        return {
            c.id: [
                f"{(self.outputs_path if c.kind.is_output else self.path).name}: "
                f"modules.{c.source.module}.{c.kind.value}[{c.source.index}]"
            ]
            for c in self.context.image.channels(back=self.name)
        }
