"""Simulated modules for every back of a topology, on pseudo-terminal pairs.

``fieldgate run FILE --simulate`` (the demo) and tests use it: each back's port is
replaced by one end of a :class:`~fieldgate.serial_link.PtyPair`, and the back's
plugin simulator serves the other end, so the back runs its real serial code.
"""

from __future__ import annotations

import logging
from typing import cast

from .plugin import PluginStartError, Registry, Simulator
from .serial_link import PtyPair
from .topology import SerialBackConfig, Topology

log = logging.getLogger("fieldgate.simulation")


class SimulationBench:
    def __init__(self, topology: Topology, registry: Registry, animate: bool = False):
        self.topology = topology
        self.registry = registry
        self.animate = animate
        self.simulators: dict[str, Simulator] = {}
        self._pairs: list[PtyPair] = []

    async def start(self) -> None:
        for back in self.topology.backs:
            factory = self.registry.simulators.get(back.type)
            if factory is None:
                raise PluginStartError(
                    f"back {back.name} ({back.type}): its plugin offers no simulator"
                )
            if not hasattr(back, "port"):
                raise PluginStartError(
                    f"back {back.name} ({back.type}): not a serial back, cannot simulate it"
                )
            try:
                pair = PtyPair()
            except OSError as exc:  # no pseudo-terminals here (container without /dev/pts, limit)
                raise PluginStartError(
                    f"back {back.name} ({back.type}): cannot open a pseudo-terminal for its"
                    f" simulated modules: {exc.strerror or exc}"
                ) from None
            self._pairs.append(pair)
            back.port = pair.a
            serial = cast(SerialBackConfig, back)  # (a serial back: it has a port)
            if getattr(serial, "parity", "N") != "N":
                # a pseudo-terminal carries bytes, not bits, and Linux refuses even parity on one
                log.info(
                    "back %s: simulated line runs without parity (configured %s)",
                    back.name,
                    serial.parity,
                )
                serial.parity = "N"
            simulator = factory(back, pair.b, self.animate)
            await simulator.start()
            self.simulators[back.name] = simulator

    def simulator(self, back: str) -> Simulator:
        return self.simulators[back]

    async def stop(self) -> None:
        for simulator in self.simulators.values():
            await simulator.stop()
        self.simulators.clear()
        for pair in self._pairs:
            pair.close()
        self._pairs.clear()
