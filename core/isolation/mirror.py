"""A north-facing child's copy of the gateway: the context its front runs against.

:class:`MirrorContext` is a :class:`~fieldgate.plugin.GatewayContext` whose image, module
health, master state and events follow what the fieldbus process sends
(:mod:`.feed`), through :meth:`MirrorContext.apply`; the front subscribes to them exactly
as it would in the fieldbus process. What the front writes for its clients goes back with
:meth:`set_outputs` and returns once the fieldbus process has applied it.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import Callable, Mapping
from typing import Any, NoReturn

from ..events import EventHub
from ..health import HealthEvent, HealthRegistry, ModuleHealth
from ..image import ProcessImage, Value
from ..masters import MasterMonitor
from ..plugin import GatewayContext
from ..topology.loader import Topology
from .feed import apply_module_state

SendUp = Callable[[dict[str, Any]], None]


class WriteRefused(ValueError):
    """The fieldbus process refused a client's write; the message is its one-line reason."""


class MirrorImage(ProcessImage):
    """The child's image: changed only by the mirror. A front that writes it directly would
    make its copy differ from the fieldbus process's: it gets a clear error instead."""

    def write_outputs(self, values: Mapping[str, Value], origin: str = "front") -> NoReturn:
        raise RuntimeError(
            "a north-facing front writes outputs with `await context.set_outputs(...)` "
            "(it runs in a child process: docs/plugins.md)"
        )


class MirrorContext(GatewayContext):
    def __init__(self, topology: Topology, send_up: SendUp, locations: dict[str, list[str]]):
        image = MirrorImage()
        for spec in topology.channel_specs:
            image.add(spec)
        super().__init__(topology, image, HealthRegistry(), MasterMonitor(image), EventHub())
        self._send_up = send_up
        self._locations = locations
        self._ids = itertools.count(1)
        self._waiting: dict[int, asyncio.Future[None]] = {}
        self.fieldbus_lag = 0.0  # how late the fieldbus process's loop was, by its last ping
        self.last_ping = time.monotonic()
        self.snapshots = 0

    # -- what the front asks of the fieldbus side -------------------------------------------
    async def set_outputs(self, values: Mapping[str, Value], origin: str) -> None:
        for cid, value in values.items():  # the fieldbus process checks again; a clear error early
            channel = self.image[cid]
            if not channel.kind.is_output:
                raise ValueError(f"{cid} is an input; only outputs can be written")
            channel.check(value)
        request = next(self._ids)
        done: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiting[request] = done
        try:
            self._send_up({"t": "write", "id": request, "values": dict(values)})
            await done
        finally:
            self._waiting.pop(request, None)

    def point_locations(self) -> dict[str, list[str]]:
        return self._locations

    def fail_writes(self, reason: str) -> None:
        """The channel to the fieldbus process is gone: every write waiting fails with a
        ConnectionError (a refusal is a ValueError or KeyError)."""
        for done in self._waiting.values():
            if not done.done():
                done.set_exception(ConnectionError(reason))

    # -- what the fieldbus process sends --------------------------------------------------------
    def apply(self, message: tuple[Any, ...]) -> None:
        kind = message[0]
        if kind == "chg":
            self.image.mirror(message[1])
        elif kind == "ts":
            self.image.refresh_times(message[1])
        elif kind == "ack":
            done = self._waiting.get(message[1])
            if done is not None and not done.done():
                if message[2] is None:
                    done.set_result(None)
                else:
                    done.set_exception(WriteRefused(message[2]))
        elif kind == "health":
            self._module(message[1]).announce(HealthEvent(message[2]))
        elif kind == "master":
            self.masters.mirror(message[1], message[2], message[3])
        elif kind == "port":
            self.health.port_state(message[1], message[2], message[3])
        elif kind == "event":
            self.events.mirror(message[1])
        elif kind == "snap":
            self._snapshot(*message[1:])

    def _module(self, state: tuple[Any, ...]) -> ModuleHealth:
        try:
            module = self.health.get(state[0], state[1])
        except KeyError:
            module = self.health.add(ModuleHealth(state[0], state[1]))
        apply_module_state(module, state)
        return module

    def _snapshot(
        self,
        channels: list[Any],
        modules: list[tuple[Any, ...]],
        masters: dict[str, bool],
        ports: dict[str, str],
        events: list[Any],
        counts: dict[str, int],
    ) -> None:
        """The whole state (at start, and after the child fell behind): listeners hear what
        differs from what the child had."""
        self.snapshots += 1
        self.image.mirror(channels)
        for state in modules:
            before = self._known_online(state)
            module = self._module(state)
            if before is not None and before != module.online:
                module.announce(HealthEvent.ONLINE if module.online else HealthEvent.OFFLINE)
        for front, ok in masters.items():
            self.masters.register(front)
            self.masters.mirror(front, ok, "as the fieldbus process reports")
        for back in set(self.health.ports_lost) - set(ports):
            self.health.port_state(back, True)
        for back, text in ports.items():
            self.health.port_state(back, False, text)
        known = {e.seq for e in self.events.recent()}
        for event in events:
            if event.seq not in known:
                self.events.mirror(event)
        self.events.counts.clear()
        self.events.counts.update(counts)

    def _known_online(self, state: tuple[Any, ...]) -> bool | None:
        try:
            return self.health.get(state[0], state[1]).online
        except KeyError:
            return None
