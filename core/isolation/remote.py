"""The whole gateway for the HTTP child: what the fieldbus process reports each second, and
the mirror that serves it to :class:`fieldgate.http.service.HttpService` as a
:class:`~fieldgate.http.view.GatewayView`.

The image, module health transitions, master state and events reach the HTTP child as they
happen (:mod:`.feed`); everything else the status API and /metrics show (each component's
``status()``, ``metrics()``, point locations, line statistics, module counters, restarts,
the children's processes) comes in :func:`gateway_state`, sent once a second: /readyz and
/metrics may be up to a second behind the fieldbus process, never more.
"""

from __future__ import annotations

import time
from collections import Counter
from types import SimpleNamespace
from typing import Any

from ..health import LineStats, ModuleHealth
from ..plugin import Component, GatewayContext
from .feed import apply_module_state, module_state
from .mirror import MirrorContext

PERIOD_S = 1.0
FIELDBUS_SILENT_S = 2.0  # /healthz: the fieldbus process has not pinged for this long


def gateway_state(gateway: Any, children: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The fieldbus process's side: plain data about every component, once a second."""
    components = []
    for comp in gateway.backs + gateway.fronts:
        components.append(
            {
                "name": comp.name,
                "kind": comp.kind,
                "started": bool(getattr(comp, "started", False)),
                "restarts": gateway.restarts(comp.name),
                "metrics": _call(comp, "metrics", []),
                "locations": _call(comp, "point_locations", {}),
                "line": _line(comp),
            }
        )
    return {
        "running": gateway.running,
        "down": dict(gateway.down),
        "status": gateway.status(),
        "components": components,
        "modules": [module_state(m) for m in gateway.health.modules()],
        "children": children,
    }


def _call(comp: Any, name: str, default: Any) -> Any:
    method = getattr(comp, name, None)
    if method is None or not getattr(comp, "started", False):
        return default
    try:
        return list(method()) if isinstance(default, list) else method()
    except Exception:  # the HTTP side logs what it cannot show; never the fieldbus side's problem
        return default


def _line(comp: Any) -> tuple[Any, ...] | None:
    scheduler = getattr(comp, "scheduler", None)
    stats = getattr(scheduler, "stats", None)
    if not isinstance(stats, LineStats):
        return None
    return (
        stats.cycles,
        stats.last_cycle_time,
        stats.requests,
        dict(stats.errors),
        stats.writes,
        stats.port_losses,
        scheduler.pending_writes,  # type: ignore[union-attr]
    )


class RemoteComponent(Component):
    """A front or back of the fieldbus process as the HTTP child sees it."""

    def __init__(self, config: Any, context: MirrorContext, kind: str):
        self.kind = kind
        super().__init__(config, context)
        self.started = False
        self.scheduler: Any = None
        self._status: dict[str, Any] = {}
        self._metrics: list[Any] = []
        self._locations: dict[str, list[str]] = {}

    async def start(self) -> None:  # pragma: no cover  (never started here)
        raise NotImplementedError

    async def run(self) -> None:  # pragma: no cover
        raise NotImplementedError

    async def stop(self) -> None:  # pragma: no cover
        raise NotImplementedError

    def status(self) -> dict[str, Any]:
        return self._status

    def metrics(self) -> list[Any]:
        return [tuple(s) if isinstance(s, list) else s for s in self._metrics]

    def point_locations(self) -> dict[str, list[str]]:
        return self._locations

    def update(self, entry: dict[str, Any], status: dict[str, Any]) -> None:
        self.started = entry["started"]
        self._metrics = entry["metrics"]
        self._locations = entry["locations"]
        self._status = status
        line = entry["line"]
        if line is None:
            self.scheduler = None
            return
        stats = LineStats(self.name)
        (cycles, stats.last_cycle_time, stats.requests, errors, stats.writes, ports, pending) = line
        stats.cycles, stats.port_losses = cycles, ports
        stats.errors = Counter(errors)
        self.scheduler = SimpleNamespace(stats=stats, pending_writes=pending)


class MirrorGateway:
    """A :class:`~fieldgate.http.view.GatewayView` of the fieldbus process, in the HTTP child."""

    def __init__(self, context: MirrorContext):
        self.topology = context.topology
        self.context: GatewayContext = context
        self.mirror = context
        self.image = context.image
        self.health = context.health
        self.masters = context.masters
        self.backs: list[Component] = [
            RemoteComponent(c, context, "back") for c in self.topology.backs
        ]
        self.fronts: list[Component] = [
            RemoteComponent(c, context, "front") for c in self.topology.fronts
        ]
        self.down: dict[str, str] = {}
        self.running = False
        self.children: dict[str, dict[str, Any]] = {}
        self._restarts: dict[str, int] = {}
        self._status: dict[str, Any] = {"gateway": self.topology.gateway.name, "running": False}
        self.updated = 0.0

    def restarts(self, name: str) -> int:
        return self._restarts.get(name, 0)

    def status(self) -> dict[str, Any]:
        return dict(self._status)

    def update(self, state: dict[str, Any]) -> None:
        self.updated = time.monotonic()
        self.running = state["running"]
        self.down = state["down"]
        self._status = state["status"]
        self.children = state["children"]
        statuses = {
            **self._status.get("fronts", {}),
            **self._status.get("backs", {}),
        }
        by_name = {c.name: c for c in self.backs + self.fronts}
        for entry in state["components"]:
            comp = by_name.get(entry["name"])
            if isinstance(comp, RemoteComponent):
                comp.update(entry, statuses.get(entry["name"], {}))
                self._restarts[entry["name"]] = entry["restarts"]
        for mstate in state["modules"]:
            try:
                module = self.health.get(mstate[0], mstate[1])
            except KeyError:
                module = self.health.add(ModuleHealth(mstate[0], mstate[1]))
            apply_module_state(module, mstate)

    def fieldbus_health(self) -> tuple[bool, str]:
        """For /healthz: is the fieldbus process answering, and how late is its event loop?"""
        lag = self.mirror.fieldbus_lag
        silent = time.monotonic() - self.mirror.last_ping
        if silent > FIELDBUS_SILENT_S:
            return False, f"the fieldbus process has not been heard from for {silent:.1f} s"
        if lag > 1.0:
            return False, f"the fieldbus process's event loop is {lag * 1000:.0f} ms late"
        return True, f"fieldbus event loop {lag * 1000:.1f} ms late"
