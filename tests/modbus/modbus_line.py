"""A real Modbus RTU line on a pty pair for the tests, driven step by step (see conftest)."""

from __future__ import annotations

from fieldgate import ModuleHealth, ProcessImage
from fieldgate.plugins.modbus.back import ModbusModule
from fieldgate.plugins.modbus.client import ModbusLink
from fieldgate.plugins.modbus.config import ModbusBackConfig
from fieldgate.plugins.modbus.simulator import ModbusSimulator
from fieldgate.polling import LineScheduler
from fieldgate.serial_link import PtyPair

PERIOD = 0.125
PROBE = 5.0

I7232D_MODULES = [
    {"address": 1, "model": "M-7052D"},
    {"address": 3, "model": "M-7055D", "counts": {"di": 0}},
    {"address": 4, "model": "M-7024", "counts": {"ao": 1}},
    {"address": 5, "model": "M-7017R", "counts": {"ai": 1}},
]


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


class Line:
    """Back-end modules + scheduler on one end of a pty pair, the simulator on the other."""

    def __init__(self, modules: list[dict], *, timeout_ms: int = 150, **back):
        self.config = ModbusBackConfig(
            name="rs485",
            port="unused",
            baudrate=115200,
            timeout_ms=timeout_ms,
            modules=modules,
            **back,
        )
        self.clock = Clock()
        self.image = ProcessImage(self.clock)
        for spec in self.config.channel_specs():
            self.image.add(spec)
        self.pair = PtyPair()
        self.sim = ModbusSimulator(self.config, self.pair.b)
        self.link = ModbusLink(
            self.pair.a, baudrate=115200, timeout=timeout_ms / 1000, inter_frame=0
        )
        points = self.config.points()
        self.modules = [
            ModbusModule(
                m,
                [c.spec for c in self.image.channels(module=m.address)],
                self.link,
                points[m.address],
                retry_period=PROBE,
                clock=self.clock,
                image=self.image,
            )
            for m in self.config.modules
        ]
        self.health = {
            m.address: ModuleHealth("rs485", m.address, m.model or "", self.config.fail_threshold)
            for m in self.config.modules
        }
        self.scheduler = LineScheduler(
            "rs485",
            self.modules,
            self.image,
            self.health,
            poll_period=PERIOD,
            offline_probe_period=PROBE,
            retries=self.config.retries,
            clock=self.clock,
        )

    def module(self, address: int) -> ModbusModule:
        return next(m for m in self.modules if m.unit == address)

    async def start(self) -> Line:
        await self.sim.start()
        await self.link.open()
        self.scheduler.attach()
        return self

    async def close(self) -> None:
        self.scheduler.detach()
        self.link.close()
        await self.sim.stop()
        self.pair.close()

    async def run_due(self, limit: int = 50) -> int:
        """Do every transaction due now; returns how many steps did work."""
        done = 0
        for _ in range(limit):
            if await self.scheduler.step() is not None:
                return done
            done += 1
        raise AssertionError("the scheduler never ran out of due work")

    async def cycle(self) -> None:
        """Advance the clock one poll period and do what is due."""
        self.clock.t += PERIOD
        await self.run_due()

    def requests(self) -> list[tuple]:
        """(unit, function, address, count) of every request the simulator saw, then forget them."""
        out = [(r.unit, r.function, r.address, r.count) for r in self.sim.requests]
        self.sim.requests.clear()
        return out
