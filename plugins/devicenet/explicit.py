"""Explicit messaging: the Group 2 Only unconnected port (Allocate / Release only) and the
explicit connection (Get/Set_Attribute_Single and the objects' own services), fragmented
both ways.

Requests use body format 8/8 (``hdr svc class instance [attr] [data]``). A response longer
than 8 bytes goes out in acknowledged fragments of 6 bytes, each one waiting for the
master's ack (1 s, 2 repeats, then abandoned); fragmented requests are acknowledged fragment
by fragment. Errors are ``hdr 94 <general> <additional>`` (:class:`~.cip.CipError`).
"""

from __future__ import annotations

from collections.abc import Mapping

from . import cip
from .allocation import Allocation
from .cip import CipError
from .connection import EXPLICIT
from .connection_set import ConnectionSet
from .fragment import ACK, ACK_OK, ACK_TOO_MUCH, EXPLICIT_CHUNK, Reassembler, split
from .netaccess import NetworkAccess
from .objects import CipObject
from .slave_state import SlaveState

FRAGMENT_ACK_TIMEOUT_S = 1.0
FRAGMENT_RETRIES = 2
DEVICENET_CLASS = 0x03


class OutgoingFragments:
    """An explicit response longer than 8 bytes, sent one acknowledged fragment at a time."""

    def __init__(self, header: int, payload: bytes, now: float):
        self.header = header
        self.pieces = split(payload, EXPLICIT_CHUNK)
        self.index = 0
        self.retries = 0
        self.deadline = now + FRAGMENT_ACK_TIMEOUT_S

    def current(self) -> bytes:
        frag, data = self.pieces[self.index]
        return bytes([self.header | 0x80, frag]) + data


class ExplicitServer:
    def __init__(
        self,
        slave: SlaveState,
        connections: ConnectionSet,
        network: NetworkAccess,
        allocation: Allocation,
        objects: Mapping[int, CipObject],
    ):
        self.slave = slave
        self.connections = connections
        self.network = network
        self.allocation = allocation
        self.objects = objects
        self.incoming = Reassembler(connections.explicit_size)
        self.outgoing: OutgoingFragments | None = None
        connections.hooks.append(self)

    # -- ConnectionHooks -------------------------------------------------------------------
    def opened(self, instance: int) -> None:
        pass

    def rate_set(self, instance: int, granted_ms: int) -> None:
        pass

    def stopped(self, instance: int) -> None:
        if instance == EXPLICIT and self.outgoing is not None:
            # a fragmented answer dies with its connection
            self.slave.counters["tx_fragments_dropped"] += 1
            self.outgoing = None

    def deadlines(self) -> list[float | None]:
        return [None if self.outgoing is None else self.outgoing.deadline]

    # -- the unconnected port ------------------------------------------------------------------
    def unconnected(self, data: bytes, now: float) -> None:
        slave = self.slave
        if len(data) < 2 or data[0] & 0x80 or data[1] & cip.RESPONSE:
            slave.counters["rx_malformed"] += 1
            return
        header, service = data[0] & 0x7F, data[1]
        try:
            if service not in (cip.ALLOCATE, cip.RELEASE):
                raise CipError(cip.RESOURCE_UNAVAILABLE, cip.INVALID_UNCONNECTED_REQUEST)
            if len(data) < 4:
                raise CipError(cip.NOT_ENOUGH_DATA)
            if data[2] != DEVICENET_CLASS or data[3] != 1:
                raise CipError(cip.OBJECT_DOES_NOT_EXIST)
            reply = bytes([header, service | cip.RESPONSE]) + self.allocation.handle(
                service, data[4:], now
            )
        except CipError as err:
            reply = self.error(header, err)
        slave.send_explicit(reply)

    def error(self, header: int, err: CipError) -> bytes:
        self.slave.counters["cip_errors"] += 1
        return bytes([header, cip.ERROR_RESPONSE | cip.RESPONSE, err.general, err.additional])

    # -- the explicit connection -----------------------------------------------------------------
    def request_frame(self, data: bytes, now: float) -> None:
        slave = self.slave
        connection = self.connections[EXPLICIT]
        if not connection.established:
            slave.counters["rx_explicit_without_connection"] += 1
            return
        if len(data) < 2:
            slave.counters["rx_malformed"] += 1
            return
        connection.kick(now)
        header = data[0] & 0x7F
        if not data[0] & 0x80:
            self.outgoing = None  # a new request abandons an unacknowledged response
            self._request(header, data[1:], now)
            return
        frag = data[1]
        if frag & 0xC0 == ACK:
            self._fragment_ack(frag, data[2:3], now)
            return
        outcome, payload = self.incoming.feed(frag, data[2:])
        if outcome == "dropped":
            slave.counters["rx_fragments_dropped"] += 1
            return
        status = ACK_TOO_MUCH if outcome == "overflow" else ACK_OK
        slave.send_explicit(bytes([header | 0x80, ACK | (frag & 0x3F), status]))
        if payload is not None:
            self.outgoing = None
            self._request(header, payload, now)

    def _request(self, header: int, body: bytes, now: float) -> None:
        if not body or body[0] & cip.RESPONSE:
            self.slave.counters["rx_malformed"] += 1
            return
        service = body[0]
        try:
            reply = self.serve(service, body[1:], now)
            if 1 + len(reply) > self.connections.explicit_size:  # attribute 7 of instance 1
                raise CipError(cip.REPLY_DATA_TOO_LARGE)
        except CipError as err:
            self._respond(header, self.error(header, err)[1:], now)
        else:
            self._respond(header, bytes([service | cip.RESPONSE]) + reply, now)
        self.network.restart_if_scheduled(header, now)

    def serve(self, service: int, path_and_data: bytes, now: float) -> bytes:
        """One request's response data (after the service byte), or CipError."""
        if len(path_and_data) < 2:
            raise CipError(cip.NOT_ENOUGH_DATA)
        class_id, instance, rest = path_and_data[0], path_and_data[1], path_and_data[2:]
        obj = self.objects.get(class_id)
        if obj is None:
            raise CipError(cip.OBJECT_DOES_NOT_EXIST)
        if service in (cip.GET_ATTRIBUTE_SINGLE, cip.SET_ATTRIBUTE_SINGLE):
            if not rest:
                raise CipError(cip.NOT_ENOUGH_DATA)
            attribute = obj.attribute(instance, rest[0])
            if service == cip.GET_ATTRIBUTE_SINGLE:
                if len(rest) > 1:
                    raise CipError(cip.TOO_MUCH_DATA)
                if attribute.get is None:
                    raise CipError(cip.ATTRIBUTE_NOT_GETTABLE)
                return attribute.get()
            if attribute.set is None:
                raise CipError(cip.ATTRIBUTE_NOT_SETTABLE)
            return attribute.set(rest[1:])
        return obj.service(service, instance, rest, now)

    def _respond(self, header: int, payload: bytes, now: float) -> None:
        if len(payload) <= 7:
            self.slave.send_explicit(bytes([header]) + payload)
            return
        self.outgoing = OutgoingFragments(header, payload, now)
        self.slave.counters["tx_fragmented_responses"] += 1
        self.slave.send_explicit(self.outgoing.current())

    def _fragment_ack(self, frag: int, status: bytes, now: float) -> None:
        slave, out = self.slave, self.outgoing
        if out is None or (frag & 0x3F) != out.pieces[out.index][0] & 0x3F:
            slave.counters["rx_unexpected_acks"] += 1
            return
        if status and status[0] != ACK_OK:
            slave.counters["tx_fragments_refused"] += 1
            self.outgoing = None
            return
        out.index += 1
        if out.index == len(out.pieces):
            self.outgoing = None
            return
        out.retries, out.deadline = 0, now + FRAGMENT_ACK_TIMEOUT_S
        slave.send_explicit(out.current())

    def tick(self, now: float) -> None:
        """Repeat an unacknowledged fragment, or abandon the response after the last repeat."""
        out = self.outgoing
        if out is None or now < out.deadline:
            return
        if out.retries >= FRAGMENT_RETRIES:
            self.slave.counters["tx_fragments_abandoned"] += 1
            self.outgoing = None
            return
        out.retries += 1
        out.deadline = now + FRAGMENT_ACK_TIMEOUT_S
        self.slave.send_explicit(out.current())
