"""What a child serves: a north-facing front, or the HTTP status server."""

from __future__ import annotations

from typing import Any, Protocol

from ..plugin import Component
from .mirror import MirrorContext


class Part(Protocol):
    async def start(self) -> None: ...

    async def run(self) -> None: ...

    async def stop(self) -> None: ...

    def report(self) -> dict[str, Any]:
        """``{"status": ..., "metrics": [...], "locations": {...}}`` as JSON values."""
        ...

    def gateway_state(self, state: dict[str, Any]) -> None:
        """The fieldbus process's periodic report of the whole gateway (HTTP only)."""
        ...


class FrontPart:
    """A plugin's front, built by its own factory against the mirror: unchanged code."""

    def __init__(self, init: dict[str, Any], context: MirrorContext):
        self.front: Component = init["factory"](init["config"], context)

    async def start(self) -> None:
        await self.front.start()

    async def run(self) -> None:
        await self.front.run()

    async def stop(self) -> None:
        await self.front.stop()

    def report(self) -> dict[str, Any]:
        from ..http.explain import json_safe

        front = self.front
        metrics = getattr(front, "metrics", None)
        locations = getattr(front, "point_locations", None)
        return {
            "status": json_safe(front.status()),
            "metrics": json_safe(list(metrics())) if metrics is not None else [],
            "locations": json_safe(locations()) if locations is not None else {},
        }

    def gateway_state(self, state: dict[str, Any]) -> None:
        return None


class HttpPart:
    """The read-only HTTP status server on a mirror of the gateway."""

    def __init__(self, init: dict[str, Any], context: MirrorContext):
        from ..http.service import HttpService
        from .remote import MirrorGateway

        self.gateway = MirrorGateway(context)
        settings = init["topology"].gateway.http
        if "listen" in init:  # a restart: where the first one listened
            settings = settings.model_copy(update={"listen": init["listen"]})
        self.service = HttpService(self.gateway, settings)

    async def start(self) -> None:
        await self.service.start()

    async def run(self) -> None:
        import asyncio

        await asyncio.Event().wait()

    async def stop(self) -> None:
        await self.service.stop()

    def report(self) -> dict[str, Any]:
        return {"status": self.service.stats(), "metrics": [], "locations": {}}

    def gateway_state(self, state: dict[str, Any]) -> None:
        self.gateway.update(state)


def make_part(init: dict[str, Any], context: MirrorContext) -> Part:
    if init["role"] == "http":
        return HttpPart(init, context)
    return FrontPart(init, context)
