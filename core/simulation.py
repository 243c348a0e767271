"""Simulated modules for every back of a topology: ``fieldgate run FILE --simulate``.

``--simulate`` asks each back's plugin for its simulator (``registry.add_simulator``):

* a **serial back** (its config a :class:`~fieldgate.topology.SerialBackConfig`) gets one
  end of a :class:`~fieldgate.serial_link.PtyPair` as its ``port``; the simulator serves
  the other end, which the factory receives, so the back runs its real serial code;
* **any other back** (a file, a socket, a bus) gets ``port=None``: the factory points the
  back's config at what its simulator serves (a temporary file, a loopback port).

A back whose plugin offers no simulator stops ``--simulate`` before anything starts,
with one line naming every such back.
"""

from __future__ import annotations

import logging

from .plugin import PluginStartError, Registry, Simulator, one_line
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
        missing = [
            f"back {b.name} ({b.type})"
            for b in self.topology.backs
            if b.type not in self.registry.simulators
        ]
        if missing:
            raise PluginStartError(
                f"--simulate: no simulator for {', '.join(missing)}: "
                f"{'its plugin offers' if len(missing) == 1 else 'their plugins offer'} none"
            )
        for back in self.topology.backs:
            factory = self.registry.simulators[back.type]
            port = self._serial_end(back) if isinstance(back, SerialBackConfig) else None
            try:
                simulator = factory(back, port, self.animate)
                await simulator.start()
            except PluginStartError as exc:
                raise PluginStartError(
                    f"back {back.name} ({back.type}): simulator: {exc}"
                ) from None
            except Exception as exc:
                raise PluginStartError(
                    f"back {back.name} ({back.type}): simulator: {one_line(exc)}"
                ) from exc
            self.simulators[back.name] = simulator

    def _serial_end(self, back: SerialBackConfig) -> str:
        """Put one end of a new pty pair in the back's ``port``; return the simulator's end."""
        try:
            pair = PtyPair()
        except OSError as exc:  # no pseudo-terminals here (container without /dev/pts, limit)
            raise PluginStartError(
                f"back {back.name} ({back.type}): cannot open a pseudo-terminal for its"
                f" simulated modules: {exc.strerror or exc}"
            ) from None
        self._pairs.append(pair)
        back.port = pair.a
        if back.parity != "N":
            # a pseudo-terminal carries bytes, not bits, and Linux refuses even parity on one
            log.info(
                "back %s: simulated line runs without parity (configured %s)",
                back.name,
                back.parity,
            )
            back.parity = "N"
        return pair.b

    def simulator(self, back: str) -> Simulator:
        return self.simulators[back]

    async def stop(self) -> None:
        for simulator in self.simulators.values():
            await simulator.stop()
        self.simulators.clear()
        for pair in self._pairs:
            pair.close()
        self._pairs.clear()
