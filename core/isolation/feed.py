"""The fieldbus process's side of the mirror: what it sends every north-facing child.

:class:`GatewayFeed` subscribes once to the process image (every batch), module health,
master state, serial ports and the event hub, encodes each of them once into a frame
(:func:`fieldgate.isolation.wire.down`), and hands the frame to every child's
:class:`Outbox`. An outbox holds at most its byte budget: a child that reads slower than
the gateway changes loses what it has queued and is marked for a *resync*, a fresh
snapshot sent when it reads again. So a stuck or slow child costs the fieldbus process one
encoding per batch and a bounded queue, never an unbounded one, and never a wait.

Messages (tuples, pickled):

* ``("snap", channels, modules, masters, ports, events, counts)``: the whole state; channels
  as ``(id, value, quality, timestamp, written_by)``
* ``("chg", [(id, value, quality, timestamp, written_by), ...])``: one image batch
* ``("health", module_state, event)``, ``("master", front, ok, reason)``,
  ``("port", back, ok, text)``, ``("event", Event)``
* ``("ts", [(id, timestamp), ...])``: inputs read again with the same value and quality
  (no change, so no batch: the image only refreshed their time), every ``REFRESH_S``
* control (never dropped): ``("ping", seq, fieldbus_lag_s, sent)``, ``("ack", id, error)``,
  ``("gw", gateway_state)`` (to the HTTP child), ``("stop",)``
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable
from typing import Any

from ..events import Event
from ..health import ErrorKind, HealthEvent, ModuleHealth
from ..image import Change
from ..plugin import GatewayContext
from . import wire

log = logging.getLogger("fieldgate.isolation")

ModuleState = tuple[Any, ...]
REFRESH_S = 0.5  # how often a child learns the read times of points that did not change


def module_state(m: ModuleHealth) -> ModuleState:
    """Everything a child shows of a module's health, as plain data."""
    return (
        m.back,
        m.address,
        m.model,
        m.fail_threshold,
        m.online,
        m.consecutive_failures,
        m.error_counter,
        m.last_error,
        None if m.last_error_kind is None else str(m.last_error_kind),
        m.requests,
        {str(k): v for k, v in m.errors.items()},
        m.last_rtt,
        m.last_success,
        list(m.rtt_counts),
        m.rtt_sum,
    )


def apply_module_state(m: ModuleHealth, state: ModuleState) -> None:
    """Set a mirrored module's health to what the fieldbus process reported (no events)."""
    (
        _,
        _,
        m.model,
        m.fail_threshold,
        m.online,
        m.consecutive_failures,
        m.error_counter,
        m.last_error,
        kind,
        m.requests,
        errors,
        m.last_rtt,
        m.last_success,
        rtt_counts,
        m.rtt_sum,
    ) = state
    m.last_error_kind = None if kind is None else ErrorKind(kind)
    m.errors.clear()
    m.errors.update(errors)
    m.rtt_counts[:] = rtt_counts


class Outbox:
    """What one child has yet to receive: control frames (always kept) and data frames up to
    ``budget`` bytes; over it, the data frames are dropped and a snapshot is due."""

    def __init__(self, budget: int):
        self.budget = budget
        self.control: deque[bytes] = deque()
        self.data: deque[bytes] = deque()
        self.size = 0
        self.resync = True  # the first thing a child gets is a snapshot
        self.resyncs = 0  # times it fell behind
        self.frames = 0
        self.bytes = 0

    def put(self, frame: bytes) -> None:
        if self.resync:
            return  # the snapshot that comes next carries this change
        if self.size + len(frame) > self.budget:
            self.drop_for_snapshot()
            return
        self.data.append(frame)
        self.size += len(frame)

    def drop_for_snapshot(self) -> None:
        """The child is behind (over the budget, or it said so): what is queued goes, and
        the next thing it gets is a snapshot."""
        if self.resync:
            return
        self.data.clear()
        self.size = 0
        self.resync = True
        self.resyncs += 1

    def put_control(self, frame: bytes, latest_only: bool = False) -> None:
        """A frame that is never dropped for a resync; ``latest_only`` (a ping, the gateway's
        state for the HTTP child): it replaces an unsent one of its kind, so a child that does
        not read costs one of each, not one per second."""
        if latest_only:
            kind = frame[wire.HEADER.size]
            self.control = deque(f for f in self.control if f[wire.HEADER.size] != kind)
        self.control.append(frame)

    def take(self, snapshot: Callable[[], bytes], limit: int) -> list[bytes]:
        """Frames to write now, at most about ``limit`` bytes: control first, then a snapshot
        when one is due, then queued data."""
        out: list[bytes] = []
        size = 0
        while self.control:
            frame = self.control.popleft()
            out.append(frame)
            size += len(frame)
        if self.resync:
            frame = snapshot()
            self.resync = False
            out.append(frame)
            size += len(frame)
        while self.data and size < limit:
            frame = self.data.popleft()
            self.size -= len(frame)
            out.append(frame)
            size += len(frame)
        self.frames += len(out)
        self.bytes += size
        return out

    @property
    def pending(self) -> bool:
        return bool(self.control or self.data or self.resync)


class GatewayFeed:
    """The gateway's changes, encoded once, for every child's :class:`Outbox`."""

    def __init__(self, context: GatewayContext):
        self.context = context
        self.outboxes: list[tuple[Outbox, Callable[[], None]]] = []  # (outbox, wake its writer)
        self.batches = 0
        self._cancels: list[Callable[[], None]] = []
        self._subscribed = False
        self._sent_times: dict[str, float | None] = {}
        self._refresher: asyncio.TimerHandle | None = None

    def attach(self, outbox: Outbox, wake: Callable[[], None]) -> Callable[[], None]:
        """Feed ``outbox`` from now on (its first frame is a snapshot); returns the detach call."""
        if not self._subscribed:
            self._subscribe()
        entry = (outbox, wake)
        self.outboxes.append(entry)

        def detach() -> None:
            if entry in self.outboxes:
                self.outboxes.remove(entry)

        return detach

    def _subscribe(self) -> None:
        ctx = self.context
        self._subscribed = True
        sub = ctx.image.subscribe_batch(self._on_batch)
        self._cancels.append(sub.cancel)
        ctx.health.subscribe(self._on_health)
        ctx.health.subscribe_ports(self._on_port)
        ctx.masters.subscribe(self._on_master)
        self._cancels.append(ctx.events.subscribe(self._on_event))
        self._sent_times = {c.id: c.timestamp for c in ctx.image}
        try:
            self._refresher = asyncio.get_running_loop().call_later(REFRESH_S, self._tick)
        except RuntimeError:  # no loop (a test drives it): refresh() by hand
            self._refresher = None

    def close(self) -> None:
        for cancel in self._cancels:
            cancel()
        self._cancels.clear()
        self.outboxes.clear()
        if self._refresher is not None:
            self._refresher.cancel()
            self._refresher = None
        self._subscribed = False

    def _tick(self) -> None:
        self._refresher = asyncio.get_running_loop().call_later(REFRESH_S, self._tick)
        self.refresh()

    def refresh(self) -> None:
        """The read times that moved without a change: one frame for every child."""
        sent = self._sent_times
        moved = [(c.id, c.timestamp) for c in self.context.image if sent.get(c.id) != c.timestamp]
        if moved:
            sent.update(moved)
            self._send(("ts", moved))

    # -- what changed ---------------------------------------------------------------------
    def _send(self, message: tuple[Any, ...]) -> None:
        if not self.outboxes:
            return
        frame = wire.down(message)
        for outbox, wake in self.outboxes:
            outbox.put(frame)
            wake()

    def _on_batch(self, changes: list[Change]) -> None:
        self.batches += 1
        sent = self._sent_times
        for c in changes:
            sent[c.id] = c.timestamp
        self._send(
            (
                "chg",
                [
                    (
                        c.id,
                        c.value,
                        c.quality.value,
                        c.timestamp,
                        c.channel.written_by if c.channel.is_output else "",
                    )
                    for c in changes
                ],
            )
        )

    def _on_health(self, health: ModuleHealth, event: HealthEvent) -> None:
        self._send(("health", module_state(health), event.value))

    def _on_port(self, back: str, ok: bool, text: str) -> None:
        self._send(("port", back, ok, text))

    def _on_master(self, front: str, ok: bool, reason: str) -> None:
        self._send(("master", front, ok, reason))

    def _on_event(self, event: Event) -> None:
        self._send(("event", event))

    # -- the whole state ------------------------------------------------------------------
    def snapshot(self) -> bytes:
        return wire.down(self.snapshot_message())

    def snapshot_message(self) -> tuple[Any, ...]:
        ctx = self.context
        channels = [(c.id, c.value, c.quality.value, c.timestamp, c.written_by) for c in ctx.image]
        modules = [module_state(m) for m in ctx.health.modules()]
        masters = {f.name: ctx.masters.is_ok(f.name) for f in ctx.topology.fronts}
        return (
            "snap",
            channels,
            modules,
            masters,
            dict(ctx.health.ports_lost),
            ctx.events.recent(),
            dict(ctx.events.counts),
        )
