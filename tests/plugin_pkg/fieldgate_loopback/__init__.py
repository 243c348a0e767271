"""Test plugin: a loopback back and a memory front, used by fieldgate's tests.

A third-party package (fieldgate-loopback, installed in the test environment only).

* back ``loopback``: each module's DO n is wired to its DI n, AO n to AI n (SO byte n to
  SI byte n: a special module's raw block), like the
  demo bench of the I-7232D manual (M-7055D outputs wired to M-7052D inputs), in software.
* front ``memory``: a front without a bus; it records the channels it serves and can
  be told its master is lost.
* front ``probe``: a north-facing front (it runs in a child process) serving a line protocol
  on TCP, to test the process layout: ``get ID``, ``set ID VALUE`` (through
  ``context.set_outputs``), ``batches``, and misbehaviour on request: ``hang S`` (blocks its
  event loop), ``eat MB`` (holds memory), ``crash`` (its run() fails), ``exit CODE``.

``fail_start`` and ``fail_after_s`` inject start-up and run-time failures, so the
gateway's supervision can be tested; ``stall_after_s`` blocks the whole event loop for
``stall_s`` once (a runaway callback), so the systemd watchdog can be tested: the stall's
begin and end are sent to ``$NOTIFY_SOCKET`` as ``X-FIELDGATE-TEST=stall-begin|stall-end``.
"""

from __future__ import annotations

import asyncio
import os
import time

from pydantic import Field

from fieldgate import Back, ChannelSpec, Front, Kind, PluginStartError, Source, channel_id, hookimpl
from fieldgate.topology import BackConfig, FrontConfig, ModuleConfig

__version__ = "1.0.0"


class LoopbackModule(ModuleConfig):
    digital: int = Field(
        0, ge=0, le=64, description="number of DO channels, each looped back to a DI"
    )
    analog: int = Field(
        0, ge=0, le=32, description="number of AO channels, each looped back to an AI"
    )
    special: int = Field(
        0, ge=0, le=64, description="number of SO bytes, each looped back to an SI byte"
    )


class LoopbackConfig(BackConfig):
    type: str = "loopback"
    modules: list[LoopbackModule] = Field(min_length=1)
    fail_start: str | None = Field(None, description="test hook: start() fails with this cause")
    fail_after_s: float | None = Field(
        None, gt=0, description="test hook: run() fails after this long"
    )
    stall_after_s: float | None = Field(
        None, gt=0, description="test hook: block the event loop once, after this long"
    )
    stall_s: float = Field(1.0, gt=0, description="test hook: how long the loop is blocked")

    def channel_specs(self) -> list[ChannelSpec]:
        specs = []
        for m in self.modules:
            for kinds, count in (
                ((Kind.DI, Kind.DO), m.digital),
                ((Kind.AI, Kind.AO), m.analog),
                ((Kind.SI, Kind.SO), m.special),
            ):
                for i in range(count):
                    for kind in kinds:
                        err, shut = m.output_modes(kind, i) if kind.is_output else (None, None)
                        extra = {"error_mode": err, "shutdown_mode": shut} if kind.is_output else {}
                        specs.append(
                            ChannelSpec(
                                channel_id(self.name, m.address, kind, i),
                                kind,
                                Source(self.name, m.address, i),
                                **extra,
                            )
                        )
        return specs


TWIN_KIND = {Kind.DO: Kind.DI, Kind.AO: Kind.AI, Kind.SO: Kind.SI}


class LoopbackBack(Back):
    def __init__(self, config: LoopbackConfig, context):
        super().__init__(config, context)
        self._sub = None
        self._twin: dict[str, str] = {}
        self.starts = 0

    async def start(self) -> None:
        self.starts += 1
        if self.config.fail_start:
            raise PluginStartError(self.config.fail_start)
        image = self.context.image
        outputs = [c for c in image.channels(back=self.name) if c.kind.is_output]
        self._twin = {
            c.id: channel_id(self.name, c.source.module, TWIN_KIND[c.kind], c.source.index)
            for c in outputs
        }
        self._sub = image.subscribe_batch(self._echo, ids=self._twin)
        image.update_inputs({self._twin[c.id]: c.value for c in outputs})

    def _echo(self, changes) -> None:
        """One batch of outputs (an RPDO's bits) comes back as one batch of inputs."""
        self.context.image.update_inputs({self._twin[c.id]: c.value for c in changes})

    async def run(self) -> None:
        if self.config.fail_after_s is not None:
            await asyncio.sleep(self.config.fail_after_s)
            raise RuntimeError("injected run-time failure")
        if self.config.stall_after_s is not None:
            await asyncio.sleep(self.config.stall_after_s)
            self._stall()
        await asyncio.Event().wait()

    def _stall(self) -> None:
        from fieldgate.systemd import Notifier

        notifier = Notifier.from_environment()
        if notifier is not None:
            notifier.send("X-FIELDGATE-TEST=stall-begin")
        time.sleep(self.config.stall_s)  # blocks the loop: nothing else runs meanwhile
        if notifier is not None:
            notifier.send("X-FIELDGATE-TEST=stall-end")
            notifier.close()

    async def stop(self) -> None:
        if self._sub is not None:
            self._sub.cancel()
            self._sub = None

    def status(self) -> dict:
        return {"starts": self.starts}


class MemoryFrontConfig(FrontConfig):
    type: str = "memory"
    fail_start: str | None = Field(None, description="test hook: start() fails with this cause")


class MemoryFront(Front):
    def __init__(self, config: MemoryFrontConfig, context):
        super().__init__(config, context)
        self.channels: list[str] = []
        self.stopped = False

    async def start(self) -> None:
        if self.config.fail_start:
            raise PluginStartError(self.config.fail_start)
        self.channels = [c.id for c in self.context.front_channels(self.config)]

    async def run(self) -> None:
        await asyncio.Event().wait()

    async def stop(self) -> None:
        self.stopped = True

    def lose_master(self, reason: str = "heartbeat timeout") -> list[str]:
        outputs = [c for c in self.channels if self.context.image[c].kind.is_output]
        return self.context.masters.lost(self.name, reason, outputs)


class ProbeFrontConfig(FrontConfig):
    type: str = "probe"
    listen: str = Field("127.0.0.1:0", description="HOST:PORT of the line server")
    writable: list[str] = Field(default_factory=list, description="outputs it may write")
    fail_start: str | None = Field(None, description="test hook: start() fails with this cause")
    start_s: float = Field(0.0, ge=0, description="test hook: start() takes this long")
    thread_s: float = Field(
        0.0,
        ge=0,
        description="test hook: start() leaves a worker thread blocked this long (a library's "
        "blocking call, e.g. paho's connect to a broker that does not answer)",
    )

    def written_outputs(self) -> list[str] | None:
        return self.writable


class ProbeFront(Front):
    def __init__(self, config: ProbeFrontConfig, context):
        super().__init__(config, context)
        self.server: asyncio.AbstractServer | None = None
        self.batches = 0
        self.changes = 0
        self.port = 0
        self._crash = asyncio.Event()
        self._held: list[bytearray] = []
        self._blocked: asyncio.Future[None] | None = None

    async def start(self) -> None:
        if self.config.fail_start:
            raise PluginStartError(self.config.fail_start)
        await asyncio.sleep(self.config.start_s)  # a server that takes long (certificates, ...)
        if self.config.thread_s:
            self._blocked = asyncio.ensure_future(
                asyncio.to_thread(time.sleep, self.config.thread_s)
            )
        host, port = self.config.listen.rsplit(":", 1)
        self.context.image.subscribe_batch(self._changed)
        self.server = await asyncio.start_server(self._serve, host, int(port))
        self.port = self.server.sockets[0].getsockname()[1]

    def _changed(self, changes) -> None:
        self.batches += 1
        self.changes += len(changes)

    async def _serve(self, reader, writer) -> None:
        while line := await reader.readline():
            words = line.decode().split()
            answer = await self._answer(words)
            writer.write((answer + "\n").encode())
            await writer.drain()
        writer.close()

    async def _answer(self, words: list[str]) -> str:
        match words:
            case ["get", cid]:
                ch = self.context.image[cid]
                return f"{cid} {ch.value} {ch.quality}"
            case ["set", cid, value]:
                try:
                    await self.context.set_outputs({cid: int(value)}, origin=self.name)
                except (KeyError, ValueError) as exc:
                    return f"refused: {exc}"
                return "ok"
            case ["batches"]:
                return str(self.batches)
            case ["hang", seconds]:
                time.sleep(float(seconds))  # blocks this child's loop
                return "woke"
            case ["eat", megabytes]:
                self._held.append(bytearray(int(megabytes) * 2**20))
                for block in self._held:  # touch every page: resident, not just reserved
                    block[::4096] = b"x" * len(block[::4096])
                return "ate"
            case ["crash"]:
                self._crash.set()
                return "crashing"
            case ["exit", code]:
                os._exit(int(code))
        return "?"

    async def run(self) -> None:
        await self._crash.wait()
        raise RuntimeError("probe told to crash")

    async def stop(self) -> None:
        if self.server is not None:
            self.server.close()
            self.server = None

    def status(self) -> dict:
        return {"state": "listening", "port": self.port, "batches": self.batches}

    def metrics(self) -> list:
        return [("probe_batches_total", "counter", "image batches the probe saw", self.batches, {})]

    def point_locations(self) -> dict[str, list[str]]:
        return {"lb/m1/ao0": ["probe line 1"]}


@hookimpl
def fieldgate_register(registry) -> None:
    registry.add_back(
        "loopback", LoopbackConfig, LoopbackBack, "outputs looped back to inputs (test plugin)"
    )
    registry.add_front(
        "memory", MemoryFrontConfig, MemoryFront, "a front without a bus (test plugin)"
    )
    registry.add_front(
        "probe",
        ProbeFrontConfig,
        ProbeFront,
        "a north-facing line server (test plugin)",
        north=True,
    )
