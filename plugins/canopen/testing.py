"""The ``canopen_master`` fixture (pytest plugin, entry point ``pytest11``): canopen's own
master, a ``RemoteNode`` whose object dictionary is the EDS ``fieldgate eds`` writes for a
canopen front, on the front's bus (python-can's ``virtual`` one in tests).

For tests that drive a gateway as a PLC would: read and write objects over SDO, map and
exchange PDOs, NMT. Tests of the protocol itself keep their own frame-level decoders.

::

    def test_the_plc_sees_the_inputs(fieldgate_thread, canopen_master):
        gateway = fieldgate_thread("plant.yaml", {"fronts.can.interface": "virtual"})
        master = canopen_master("plant.yaml", overrides={"fronts.can.interface": "virtual"})
        master.wait_answering()
        assert master.node.sdo.upload(0x1000, 0) == (0x000F0191).to_bytes(4, "little")
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:  # loaded by every pytest run where fieldgate is installed: imports stay lazy
    import canopen

    from fieldgate.plugin import Registry


@dataclass
class CanopenMaster:
    network: canopen.Network
    node: canopen.RemoteNode
    eds: Path  # the EDS its object dictionary came from

    def wait_answering(self, timeout: float = 10.0) -> None:
        """Until the node answers an SDO upload of 0x1000 (a gateway takes a moment to start)."""
        import canopen

        deadline = time.monotonic() + timeout
        while True:
            try:
                self.node.sdo.upload(0x1000, 0)
                return
            except canopen.SdoCommunicationError:
                if time.monotonic() > deadline:
                    raise AssertionError(
                        f"node {self.node.id} does not answer SDO within {timeout} s"
                    ) from None

    def close(self) -> None:
        self.network.disconnect()


@pytest.fixture
def canopen_master(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[Callable[..., CanopenMaster]]:
    """``master(topology, front=None, overrides=None, interface=None, channel=None)``: canopen's
    master for a canopen front of the topology, on the front's interface and channel (or the
    ones given); disconnected when the test ends."""
    made: list[CanopenMaster] = []

    def make(
        topology: str | Path | dict[str, Any],
        front: str | None = None,
        *,
        overrides: dict[str, Any] | None = None,
        interface: str | None = None,
        channel: str | None = None,
        registry: Registry | None = None,
    ) -> CanopenMaster:
        import canopen

        from .eds import eds_text, front_node

        component, od = front_node(topology, front, registry, overrides)
        config = component.config
        eds = tmp_path_factory.mktemp("canopen-master") / f"{config.name}.eds"
        eds.write_text(eds_text(component, od, eds.name))
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.05
        network.connect(interface=interface or config.interface, channel=channel or config.channel)
        node = network.add_node(canopen.RemoteNode(config.node_id, str(eds)))
        node.sdo.RESPONSE_TIMEOUT = 1.0
        made.append(CanopenMaster(network, node, eds))
        return made[-1]

    yield make
    for master in made:
        master.close()
