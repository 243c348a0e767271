"""Server-Sent Events: point changes (merged, rate-limited per client) and gateway events.

Memory stays bounded whatever a client does:

* point changes are not queued: each client keeps the *set* of changed point ids (at most
  every point once) and sends their current values at most ``rate_hz`` times a second;
* gateway events go to a queue of ``queue_size`` per client; when it is full the event is
  dropped and counted (``fieldgate_sse_dropped_total``), and the client gets a ``dropped``
  count with the next batch;
* a client that does not read for ``WRITE_TIMEOUT`` seconds is disconnected (counted).

With no client connected the image has no subscription at all: the event stream costs a
poller or CAN engine nothing until someone watches.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections import deque
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from ..events import Event
from ..image import Change
from .explain import compact
from .server import WRITE_TIMEOUT, Stream, StreamWriter

if TYPE_CHECKING:
    from .view import GatewayView

log = logging.getLogger("fieldgate.http.sse")

KEEPALIVE_S = 15.0
QUEUE_SIZE = 256
RETRY_MS = 2000


def _frame(event: str, data: Any, event_id: int | None = None) -> bytes:
    head = f"id: {event_id}\n" if event_id is not None else ""
    return f"{head}event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


class SseClient:
    def __init__(self, ids: frozenset[str] | None, rate_hz: float, queue_size: int):
        self.ids = ids  # points this client follows (None: all)
        self.interval = 1.0 / rate_hz
        self.queue_size = queue_size
        self.events: deque[Event] = deque()
        self.dirty: dict[str, None] = {}  # changed point ids, in order, each once
        self.dropped = 0  # events not delivered since the last batch
        self.wake = asyncio.Event()

    def mark(self, channel_id: str) -> None:
        if self.ids is None or channel_id in self.ids:
            self.dirty[channel_id] = None
            if not self.wake.is_set():
                self.wake.set()

    def push(self, event: Event) -> bool:
        if len(self.events) >= self.queue_size:
            self.dropped += 1
            return False
        self.events.append(event)
        self.wake.set()
        return True


class EventStreams:
    """Every open event stream of one gateway."""

    def __init__(
        self,
        gateway: GatewayView,
        *,
        max_clients: int,
        rate_hz: float,
        queue_size: int = QUEUE_SIZE,
    ):
        self.gateway = gateway
        self.max_clients = max_clients
        self.rate_hz = rate_hz
        self.queue_size = queue_size
        self.clients: set[SseClient] = set()
        self.dropped_events = 0
        self.closed_slow = 0
        self.batches = 0
        self._subscription: Any = None
        self._unsubscribe_events: Any = None

    @property
    def full(self) -> bool:
        return len(self.clients) >= self.max_clients

    def open(self, ids: Iterable[str] | None, rate_hz: float | None = None) -> Stream | None:
        """A new client's stream, its slot taken now (check and take in one step: clients
        connecting at the same moment cannot all pass the limit); None when full."""
        if self.full:
            return None
        rate = min(self.rate_hz, rate_hz) if rate_hz else self.rate_hz
        client = SseClient(frozenset(ids) if ids is not None else None, rate, self.queue_size)
        self._add(client)

        async def body(writer: StreamWriter) -> None:
            await self._serve(client, writer)

        return Stream(body, release=lambda: self._remove(client))

    # -- fan-out (on the event loop, inside the write or publish that caused it) ----------
    def _add(self, client: SseClient) -> None:
        self.clients.add(client)
        if self._subscription is None:
            self._subscription = self.gateway.image.subscribe_batch(self._changed)
            self._unsubscribe_events = self.gateway.context.events.subscribe(self._event)

    def _remove(self, client: SseClient) -> None:
        self.clients.discard(client)
        if not self.clients and self._subscription is not None:
            self._subscription.cancel()
            self._unsubscribe_events()
            self._subscription = self._unsubscribe_events = None

    def _changed(self, changes: list[Change]) -> None:
        for client in self.clients:
            for change in changes:
                client.mark(change.id)

    def _event(self, event: Event) -> None:
        for client in self.clients:
            if not client.push(event):
                self.dropped_events += 1

    def close_all(self) -> None:
        for client in list(self.clients):
            client.wake.set()

    # -- one client ----------------------------------------------------------------------
    async def _serve(self, client: SseClient, writer: StreamWriter) -> None:
        loop = asyncio.get_running_loop()
        next_batch = loop.time()
        writer.write(
            f"retry: {RETRY_MS}\n\n".encode() + _frame("hello", {"rate_hz": 1 / client.interval})
        )
        await self._drain(writer)
        while True:
            try:
                async with asyncio.timeout(KEEPALIVE_S):
                    await client.wake.wait()
            except TimeoutError:
                writer.write(b": keepalive\n\n")
                if not await self._drain(writer):
                    return
                continue
            client.wake.clear()
            while client.events:
                event = client.events.popleft()
                writer.write(_frame("event", event.as_dict(), event.seq))
            if client.dirty:
                delay = next_batch - loop.time()
                if delay > 0:
                    await asyncio.sleep(delay)  # changes meanwhile merge into this batch
                now = self.gateway.image.clock()
                image = self.gateway.image
                batch = [compact(image[cid], now) for cid in client.dirty]
                client.dirty.clear()
                payload: dict[str, Any] = {"points": batch}
                if client.dropped:
                    payload["dropped_events"] = client.dropped
                    client.dropped = 0
                writer.write(_frame("points", payload))
                self.batches += 1
                next_batch = loop.time() + client.interval
            if not await self._drain(writer):
                return

    async def _drain(self, writer: StreamWriter) -> bool:
        try:
            async with asyncio.timeout(WRITE_TIMEOUT):
                await writer.drain()
        except TimeoutError:
            self.closed_slow += 1
            log.info("event stream client too slow for %.0f s: disconnected", WRITE_TIMEOUT)
            return False
        return True
