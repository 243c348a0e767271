"""What the HTTP server reads of the gateway it serves (:class:`fieldgate.runtime.Gateway` is one).

The server depends on this interface, not on the runtime module: the runtime starts the
server, so an import the other way would close a cycle.
"""

from __future__ import annotations

from typing import Any, Protocol

from ..health import HealthRegistry
from ..image import ProcessImage
from ..masters import MasterMonitor
from ..plugin import Component, GatewayContext
from ..topology.loader import Topology


class GatewayView(Protocol):
    topology: Topology
    context: GatewayContext
    image: ProcessImage
    health: HealthRegistry
    masters: MasterMonitor
    backs: list[Component]
    fronts: list[Component]
    down: dict[str, str]  # components waiting for a restart, with the cause
    running: bool

    def restarts(self, name: str) -> int: ...

    def status(self) -> dict[str, Any]: ...
