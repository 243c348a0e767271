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
import logging
import ssl
from collections.abc import Callable
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from .config import BrokerSettings

log = logging.getLogger("fieldgate.sparkplug.link")


class LinkEvents:
    """What the link reports (called on the event loop)."""

    def __init__(
        self,
        connack: Callable[[int, bool, str], None],
        lost: Callable[[int, str], None],
        puback: Callable[[int, int], None],
        message: Callable[[int, str, bytes], None],
    ):
        self.connack = connack
        self.lost = lost
        self.puback = puback
        self.message = message


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
    ):
        self.loop = loop
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

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        self._post(self.events.connack, not reason.is_failure, str(reason))

    def _on_disconnect(
        self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any
    ) -> None:
        self._post(self.events.lost, str(reason))

    def _on_publish(self, client: Any, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        self._post(self.events.puback, mid)

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
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
        self.client.loop_start()

    def subscribe(self, topics: tuple[str, ...]) -> None:
        self.client.subscribe([(topic, 1) for topic in topics])

    def publish(self, topic: str, payload: bytes, qos: int, retain: bool) -> int | None:
        """The message id of a QoS 1 publish (its PUBACK is reported with it), else None."""
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        if info.rc != mqtt.MQTT_ERR_SUCCESS:
            log.debug("publish on %s not sent: %s", topic, mqtt.error_string(info.rc))
            return None
        return info.mid if qos else None

    async def close(self) -> None:
        """Send DISCONNECT after whatever is queued, stop the network thread."""
        self.closed = True
        await asyncio.to_thread(self._shutdown)

    def _shutdown(self) -> None:
        try:
            self.client.disconnect()
        except Exception:  # already gone
            pass
        self.client.loop_stop()
