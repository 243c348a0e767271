"""I/O messaging on the Predefined Master/Slave connections: poll, bit-strobe, change of
state and cyclic, both ways. What each connection carries is its path (:mod:`.paths`).

* Poll (instance 2): the master's G2/5 carries the consumed assembly (I/O-fragmented above
  8 bytes), the answer on G1/0xF the produced one; a zero-length poll is *idle* (outputs
  kept).
* Bit-strobe (instance 3): 8 bytes on the master's G2/0, answered on G1/0xE with the first
  8 bytes of the produced assembly.
* Change of state / cyclic, slave to master (instance 4): produced on G1/0xD every
  expected packet rate, and for change of state when the produced data change (no sooner
  than the production inhibit time). Acknowledged with an empty G2/2 frame unless
  suppressed; an unacknowledged production is sent again after the Acknowledge Handler's
  timer, up to its retry limit (class 0x2B attributes 1 and 2).
* Change of state / cyclic, master to slave (instance 2 in its COS/cyclic role): the
  master's data on G2/5 is applied like a poll's outputs and acknowledged with an empty
  G1/0xF frame unless suppressed; its watchdog is the master's presence.
"""

from __future__ import annotations

from dataclasses import dataclass

from . import ids
from .allocation import BIT_COS
from .assembly import AnyAssembly
from .connection import COS_CYCLIC, COS_DATA_ROLE, POLL, STROBE, Connection
from .connection_set import ConnectionSet
from .fragment import Reassembler, io_frames
from .slave_state import SlaveState


@dataclass
class AwaitedAck:
    """A production of the acknowledged COS/cyclic connection that the master has not acked."""

    payload: bytes
    deadline: float
    retries: int = 0


class IoMessaging:
    def __init__(self, slave: SlaveState, connections: ConnectionSet):
        self.slave = slave
        self.connections = connections
        self.io_in = Reassembler(slave.assemblies.largest)
        self.produce_at: float | None = None
        self.last_produced = float("-inf")
        self.last_data: bytes | None = None
        self.awaited: AwaitedAck | None = None
        connections.hooks.append(self)

    # -- ConnectionHooks ---------------------------------------------------------------------
    def opened(self, instance: int) -> None:
        if instance == POLL:
            self.io_in.reset()
        if instance == COS_CYCLIC:
            self.last_data, self.awaited = None, None

    def rate_set(self, instance: int, granted_ms: int) -> None:
        if instance == COS_CYCLIC:
            self.produce_at = self.slave.now if granted_ms else None

    def stopped(self, instance: int) -> None:
        if instance == COS_CYCLIC:
            self.produce_at, self.awaited = None, None

    def deadlines(self) -> list[float | None]:
        return [self.produce_at, None if self.awaited is None else self.awaited.deadline]

    # -- receiving ---------------------------------------------------------------------------
    def send(self, message: int, payload: bytes) -> None:
        for data in io_frames(payload):
            self.slave.send(ids.group1_id(message, self.slave.mac_id), data)

    def _reassemble(self, c: Connection, data: bytes) -> bytes | None:
        """A whole consumed message (I/O fragments put together), or None (more to come / dropped)."""
        if c.consumed_size <= 8 or not data:
            return data
        outcome, payload = self.io_in.feed(data[0], data[1:])
        if outcome == "dropped" or outcome == "overflow":
            self.slave.counters["rx_io_fragments_dropped"] += 1
        return payload

    def _consume(self, consumes: AnyAssembly | None, data: bytes, counter: str) -> None:
        if data and consumes is not None:  # zero length = idle: outputs keep their values
            self.slave.assemblies.consume(consumes, data)
            self.slave.counters[f"{counter}_outputs"] += 1
        else:
            self.slave.counters[f"{counter}_idle"] += 1

    def master_data(self, data: bytes, now: float) -> None:
        """Group 2 message 5: a poll, or the master's COS/cyclic data (instance 2's role)."""
        slave = self.slave
        c = self.connections[POLL]
        if not c.established:
            slave.counters["rx_poll_without_connection"] += 1
            return
        whole = self._reassemble(c, data)
        if whole is None:
            return
        if len(whole) not in (0, c.consumed_size):
            slave.counters["rx_poll_wrong_size"] += 1
            return
        c.kick(now)
        if c.role == COS_DATA_ROLE:
            self._consume(c.consumes, whole, "rx_cos_cyclic")
            if c.acked:
                self.send(ids.G1_POLL_RESPONSE, b"")  # the acknowledge: an empty message
            return
        self._consume(c.consumes, whole, "rx_poll")
        self.send(ids.G1_POLL_RESPONSE, c.produces.data() if c.produces else b"")

    def strobe(self, data: bytes, now: float) -> None:
        slave = self.slave
        c = self.connections[STROBE]
        if not c.established:
            return
        if len(data) != 8:
            slave.counters["rx_strobe_wrong_size"] += 1
            return
        c.kick(now)
        produced = c.produces.data()[: c.produced_size] if c.produces else b""
        slave.send(ids.group1_id(ids.G1_STROBE_RESPONSE, slave.mac_id), produced)

    def cos_ack(self, now: float) -> None:
        c = self.connections[COS_CYCLIC]
        if c.established and c.acked:
            c.kick(now)
            self.awaited = None
        else:
            self.slave.counters["rx_unexpected_acks"] += 1

    # -- producing ---------------------------------------------------------------------------
    @property
    def change_of_state(self) -> bool:
        return bool(self.slave.allocation_choice & BIT_COS)

    def due(self, now: float) -> bool:
        return (self.produce_at is not None and now >= self.produce_at) or (
            self.awaited is not None and now >= self.awaited.deadline
        )

    def tick(self, now: float) -> None:
        if self.produce_at is not None and now >= self.produce_at:
            self.produce(now)
        elif self.awaited is not None and now >= self.awaited.deadline:
            self._repeat(now)

    def produce(self, now: float) -> None:
        slave = self.slave
        c = self.connections[COS_CYCLIC]
        if not c.established or not c.epr_ms:
            self.produce_at = None
            return
        payload = c.produces.data() if c.produces else b""
        self.send(ids.G1_COS_CYCLIC, payload)
        self.last_produced, self.last_data = now, payload
        self.produce_at = now + c.epr_ms / 1000.0
        slave.counters["cos_cyclic_produced"] += 1
        if c.acked:
            if self.awaited is not None:
                slave.counters["cos_cyclic_unacknowledged"] += 1
            self.awaited = AwaitedAck(payload, now + slave.ack_timer_ms / 1000.0)

    def _repeat(self, now: float) -> None:
        """The Acknowledge Handler's timer ran out: send again, or give up at the retry limit."""
        slave, awaited = self.slave, self.awaited
        assert awaited is not None
        if awaited.retries >= slave.ack_retry_limit:
            slave.counters["cos_cyclic_ack_failures"] += 1
            self.awaited = None
            return
        awaited.retries += 1
        awaited.deadline = now + slave.ack_timer_ms / 1000.0
        slave.counters["cos_cyclic_retries"] += 1
        self.send(ids.G1_COS_CYCLIC, awaited.payload)

    def inputs_changed(self, now: float) -> None:
        """An input of this front changed: a change-of-state connection produces if its data
        changed (inhibit time permitting)."""
        c = self.connections[COS_CYCLIC]
        if not self.slave.online or not self.change_of_state or not c.established or not c.epr_ms:
            return
        if c.produces is None or c.produces.data() == self.last_data:
            return  # not an input of this connection's path
        earliest = self.last_produced + c.inhibit_ms / 1000.0
        if now >= earliest:
            self.produce(now)
        elif self.produce_at is None or self.produce_at > earliest:
            self.produce_at = earliest
