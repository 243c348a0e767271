"""I/O messaging on the Predefined Master/Slave connections: poll, bit-strobe, change of
state and cyclic.

* Poll (instance 2): the master's G2/5 carries the outputs (I/O-fragmented above 8 bytes),
  the answer on G1/0xF the inputs; a zero-length poll is *idle* (outputs kept).
* Bit-strobe (instance 3): 8 bytes on the master's G2/0, answered on G1/0xE.
* Change of state / cyclic (instance 4): produced on G1/0xD every expected packet rate, and
  on an input change for change of state (no sooner than the production inhibit time);
  acknowledged with an empty G2/2 frame unless suppressed.
"""

from __future__ import annotations

from . import ids
from .allocation import BIT_COS
from .connection import COS_CYCLIC, POLL, STROBE
from .connection_set import ConnectionSet
from .fragment import Reassembler, io_frames
from .slave_state import SlaveState


class IoMessaging:
    def __init__(self, slave: SlaveState, connections: ConnectionSet):
        self.slave = slave
        self.connections = connections
        self.io_in = Reassembler(slave.assemblies.consumed_size)
        self.produce_at: float | None = None
        self.last_produced = float("-inf")
        connections.hooks.append(self)

    # -- ConnectionHooks ---------------------------------------------------------------------
    def opened(self, instance: int) -> None:
        self.io_in.reset()

    def rate_set(self, instance: int, granted_ms: int) -> None:
        if instance == COS_CYCLIC:
            self.produce_at = self.slave.now if granted_ms else None

    def stopped(self, instance: int) -> None:
        if instance == COS_CYCLIC:
            self.produce_at = None

    # -- receiving ---------------------------------------------------------------------------
    def send(self, message: int, payload: bytes) -> None:
        for data in io_frames(payload):
            self.slave.send(ids.group1_id(message, self.slave.mac_id), data)

    def poll(self, data: bytes, now: float) -> None:
        slave = self.slave
        c = self.connections[POLL]
        if not c.established:
            slave.counters["rx_poll_without_connection"] += 1
            return
        size = c.consumed_size
        if size > 8 and data:
            outcome, payload = self.io_in.feed(data[0], data[1:])
            if outcome == "dropped" or outcome == "overflow":
                slave.counters["rx_io_fragments_dropped"] += 1
                return
            if payload is None:
                return
            data = payload
        if len(data) not in (0, size):
            slave.counters["rx_poll_wrong_size"] += 1
            return
        c.kick(now)
        if data:  # zero-length poll = idle: outputs keep their values
            slave.assemblies.consume(data)
            slave.counters["rx_poll_outputs"] += 1
        else:
            slave.counters["rx_poll_idle"] += 1
        self.send(ids.G1_POLL_RESPONSE, slave.assemblies.produced())

    def strobe(self, data: bytes, now: float) -> None:
        slave = self.slave
        c = self.connections[STROBE]
        if not c.established:
            return
        if len(data) != 8:
            slave.counters["rx_strobe_wrong_size"] += 1
            return
        c.kick(now)
        slave.send(
            ids.group1_id(ids.G1_STROBE_RESPONSE, slave.mac_id), slave.assemblies.produced()[:8]
        )

    def cos_ack(self, now: float) -> None:
        c = self.connections[COS_CYCLIC]
        if c.established and c.acked:
            c.kick(now)
        else:
            self.slave.counters["rx_unexpected_acks"] += 1

    # -- producing ---------------------------------------------------------------------------
    @property
    def change_of_state(self) -> bool:
        return bool(self.slave.allocation_choice & BIT_COS)

    def due(self, now: float) -> bool:
        return self.produce_at is not None and now >= self.produce_at

    def produce(self, now: float) -> None:
        c = self.connections[COS_CYCLIC]
        if not c.established or not c.epr_ms:
            self.produce_at = None
            return
        self.send(ids.G1_COS_CYCLIC, self.slave.assemblies.produced())
        self.last_produced = now
        self.produce_at = now + c.epr_ms / 1000.0
        self.slave.counters["cos_cyclic_produced"] += 1

    def inputs_changed(self, now: float) -> None:
        """An input of this front changed: a change-of-state connection produces (inhibit time permitting)."""
        c = self.connections[COS_CYCLIC]
        if not self.slave.online or not self.change_of_state or not c.established or not c.epr_ms:
            return
        earliest = self.last_produced + c.inhibit_ms / 1000.0
        if now >= earliest:
            self.produce(now)
        elif self.produce_at is None or self.produce_at > earliest:
            self.produce_at = earliest
