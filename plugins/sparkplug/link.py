"""MQTT I/O for the session: one paho-mqtt client per connection, events handed to the loop.

A fresh client per CONNECT, because the will (NDEATH with this connection's ``bdSeq``) is
part of the CONNECT packet; paho's own reconnect is off (``reconnect_on_failure=False``),
so it never reconnects with a stale will. The blocking TCP/TLS connect runs in a worker
thread; the client's network thread (``loop_start``) reports CONNACK, PUBACK (by message
id), incoming messages and the end of the connection, each tagged with the connection's
generation so a late event of an old connection is ignored.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import ssl
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from .actions import Publish
from .config import BrokerSettings

log = logging.getLogger("fieldgate.sparkplug.link")

SYNC_FILTER = "$fieldgate/sync"
"""What a sync unsubscribes: a valid filter that no client of a Sparkplug broker uses."""

UNWRITTEN_QOS0 = 1
"""QoS 0 messages handed to paho and not yet written to the socket, at most."""


class LinkEvents:
    """What the link reports (called on the event loop, with the link's generation)."""

    def __init__(
        self,
        connack: Callable[[int, bool, str], None],
        lost: Callable[[int, str], None],
        puback: Callable[[int, int], None],
        message: Callable[[int, str, bytes], None],
        synced: Callable[[int, int], None],
    ):
        self.connack = connack
        self.lost = lost
        self.puback = puback  # (generation, token) of a QoS 1 DATA message
        self.message = message
        self.synced = synced  # (generation, sync token)


@dataclass
class LinkStats:
    """Counts kept across connections (one per front)."""

    published: Counter[str] = field(default_factory=Counter)  # handed to the client, by kind
    dropped: Counter[str] = field(default_factory=Counter)  # never handed, by reason


class Link:
    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        events: LinkEvents,
        generation: int,
        broker: BrokerSettings,
        password: str | None,
        client_id: str,
        keepalive_s: int,
        stats: LinkStats | None = None,
    ):
        self.loop = loop
        self.stats = stats or LinkStats()
        self._outbox: deque[Publish | int] = deque()  # a message, or a sync token
        self._unwritten = 0  # QoS 0 messages handed to paho, not yet written
        self._pending: dict[int, tuple[Publish, int]] = {}  # paho mid -> (message, its qos)
        self._syncs: dict[int, int] = {}  # paho mid of an UNSUBSCRIBE -> sync token
        self.events = events
        self.generation = generation
        self.broker = broker
        self.closed = False
        client = mqtt.Client(
            CallbackAPIVersion.VERSION2,
            client_id=client_id,
            protocol=mqtt.MQTTv311,
            clean_session=True,
            reconnect_on_failure=False,
        )
        client.max_inflight_messages_set(65535)  # the session paces what it sends
        client.max_queued_messages_set(0)
        if broker.username is not None:
            client.username_pw_set(broker.username, password)
        if broker.tls is not None:
            tls = broker.tls
            client.tls_set(
                ca_certs=tls.ca_file,
                certfile=tls.cert_file,
                keyfile=tls.key_file,
                cert_reqs=ssl.CERT_REQUIRED,
            )
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_publish = self._on_publish
        client.on_unsubscribe = self._on_unsubscribe
        client.on_message = self._on_message
        self.client = client
        self._keepalive = keepalive_s

    # -- paho callbacks (network thread) ------------------------------------------------
    def _post(self, fn: Callable[..., None], *args: Any) -> None:
        if self.closed:
            return
        try:
            self.loop.call_soon_threadsafe(fn, self.generation, *args)
        except RuntimeError:
            pass  # the loop is closed: the gateway has stopped

    def _call(self, fn: Callable[..., None], *args: Any) -> None:
        """Run ``fn`` on the loop (the link's own bookkeeping)."""
        if self.closed:
            return
        try:
            self.loop.call_soon_threadsafe(fn, *args)
        except RuntimeError:
            pass  # the loop is closed: the gateway has stopped

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        self._post(self.events.connack, not reason.is_failure, str(reason))

    def _on_disconnect(
        self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any
    ) -> None:
        self._post(self.events.lost, str(reason))

    def _on_publish(self, client: Any, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        self._call(self._done, mid)  # QoS 0: written to the socket; QoS 1: PUBACK received

    def _on_unsubscribe(
        self, client: Any, userdata: Any, mid: int, reasons: Any, props: Any
    ) -> None:
        self._call(self._unsubscribed, mid)

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        log.debug("received %s, %d bytes", msg.topic, len(msg.payload))
        self._post(self.events.message, msg.topic, bytes(msg.payload))

    # -- called on the event loop ---------------------------------------------------------
    async def open(self, will_topic: str, will_payload: bytes) -> None:
        """TCP/TLS connect and CONNECT (will: QoS 1, not retained); CONNACK comes as an event."""
        self.client.will_set(will_topic, will_payload, qos=1, retain=False)
        await asyncio.to_thread(
            self.client.connect, self.broker.host, self.broker.effective_port, self._keepalive
        )
        if self.closed:
            await asyncio.to_thread(self._shutdown)
            return
        sock = self.client.socket()
        if isinstance(sock, socket.socket):  # an SSLSocket is one too
            # no Nagle: a sync's UNSUBSCRIBE right behind its DDATA would otherwise wait for
            # the broker's delayed ACK of the DDATA (40 ms on Linux) before it is sent
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client.loop_start()

    def subscribe(self, topics: tuple[str, ...]) -> None:
        self.client.subscribe([(topic, 1) for topic in topics])

    def publish(self, message: Publish) -> None:
        """Queue a message; a QoS 1 DATA message's PUBACK is reported with its token."""
        self._outbox.append(message)
        self._pump()

    def sync(self, token: int) -> None:
        """Report ``token`` (events.synced) once the broker has read everything before it."""
        self._outbox.append(token)
        self._pump()

    def discard_data(self, reason: str = "rebirth") -> list[int]:
        """Drop the DATA messages not yet handed to the client; their tokens."""
        kept: deque[Publish | int] = deque()
        tokens: list[int] = []
        for item in self._outbox:
            if isinstance(item, Publish) and item.token is not None:
                tokens.append(item.token)
                log.debug("discarded %s seq=%s (%s)", item.topic, item.seq, reason)
            else:
                kept.append(item)
        self._outbox = kept
        if tokens:
            self.stats.dropped[reason] += len(tokens)
        return tokens

    @property
    def queued(self) -> int:
        """Items (messages, syncs) not yet handed to the client."""
        return len(self._outbox)

    @property
    def queued_data(self) -> int:
        return sum(1 for i in self._outbox if isinstance(i, Publish) and i.token is not None)

    # -- the outbox (event loop) ----------------------------------------------------------
    def _pump(self, *, force: bool = False) -> None:
        """Hand queued items to paho in order; a DATA message waits while a QoS 0 message
        handed before it is not yet written (the rest cannot be discarded: no need to wait)."""
        while self._outbox:
            item = self._outbox[0]
            if isinstance(item, int):
                self._outbox.popleft()
                self._hand_sync(item)
                continue
            if item.token is not None and self._unwritten >= UNWRITTEN_QOS0 and not force:
                return
            self._outbox.popleft()
            self._hand(item)

    def _hand(self, msg: Publish) -> None:
        info = self.client.publish(msg.topic, msg.payload, qos=msg.qos, retain=msg.retain)
        if info.rc != mqtt.MQTT_ERR_SUCCESS:
            self.stats.dropped["not_connected"] += 1
            log.debug("publish on %s not sent: %s", msg.topic, mqtt.error_string(info.rc))
            return  # the connection is gone; its loss reaches the session
        self.stats.published[msg.kind or "other"] += 1
        if log.isEnabledFor(logging.DEBUG):
            log.debug(
                "publish %s seq=%s qos=%d %d bytes", msg.topic, msg.seq, msg.qos, len(msg.payload)
            )
        self._pending[info.mid] = (msg, msg.qos)
        if msg.qos == 0:
            self._unwritten += 1

    def _hand_sync(self, token: int) -> None:
        rc, mid = self.client.unsubscribe(SYNC_FILTER)
        if rc == mqtt.MQTT_ERR_SUCCESS and mid is not None:
            self._syncs[mid] = token
            log.debug("sync %d sent", token)

    def _done(self, mid: int) -> None:
        entry = self._pending.pop(mid, None)
        if entry is None or self.closed:
            return
        msg, qos = entry
        if qos == 0:
            self._unwritten -= 1
            self._pump()
        elif msg.token is not None:
            self.events.puback(self.generation, msg.token)

    def _unsubscribed(self, mid: int) -> None:
        token = self._syncs.pop(mid, None)
        log.debug("sync %s done", token)
        if token is not None and not self.closed:
            self.events.synced(self.generation, token)

    async def close(self) -> None:
        """Hand what is queued but DATA (the NDEATH of an intentional disconnect) to the
        client, then send DISCONNECT after it and stop the network thread. Queued DATA is
        dropped: the session has put its samples back in the journal already."""
        self.closed = True
        self.discard_data("disconnect")
        self._pump(force=True)
        await asyncio.to_thread(self._shutdown)

    def _shutdown(self) -> None:
        try:
            self.client.disconnect()
        except Exception:  # already gone
            pass
        self.client.loop_stop()
