"""Error control (CiA 301 §7.2.8.3): the one service of guarding and heartbeat, and what
their errors mean for the node and its master.

The protocols are apart: node and life guarding in :mod:`.guarding`, the heartbeat
producer and consumer in :mod:`.heartbeat`. This service serves their objects (0x100C,
0x100D, 0x1016, 0x1017, 0x1029), takes their frames, runs their timers and owns what they
share:

* Life guarding timeout: the master is lost, EMCY ``30 81 11 07 00 00 00 00`` (TV-20). The
  next guard RTR clears the error (error reset EMCY) and ends the loss.
* Heartbeat consumer timeout: a master-lost event with EMCY 0x8130 (register 0x11,
  manufacturer bytes ``07 <node-ID>``); its next heartbeat clears it.
* 0x1029:1 (error behaviour, communication error): on a master-lost event an
  operational node goes to pre-operational (0, the CiA 301 default value), stays as
  it is (1) or stops (2). The front's default is 1 (the I-7232D keeps its state);
  the NA-9161 behaviour is 0.
* Bus-off (reported by the adapter via :meth:`bus_state`) is a master-lost event;
  the recovery sends EMCY 0x8140 (register 0x11, manufacturer byte 08, as the I-7232D),
  active until the master is heard again (guard RTR, monitored heartbeat).

A monitoring error ends when what it reports can no longer be true (docs/canopen.md,
"Monitoring switched off"): guarding switched off (0x100C or 0x100D written 0, or
0x1017 written non-zero) ends the life guarding error; a 0x1016 entry cleared or
moved to another node ends that node's heartbeat error; reset communication (and
reset node) ends all of them, the 0x8140 included, with one error-reset EMCY after
the boot-up. 0x8140 also ends as soon as nothing monitors the master (no guarding,
no 0x1016 entry): nothing could ever hear it.

Other services' errors that a reset ends (the SYNC loss) are gathered here after the
boot-up, from every service with a ``reset_ends_errors()`` method, so that one
error-reset EMCY reports everything the reset ended.

Master state: the master is lost while life guarding, a heartbeat consumer or bus-off
says so, or while it has not been heard since :meth:`ErrorControl.assume_master_lost`
(the front restarted while its master was lost; docs/canopen.md "After a front
restart"); ``node.master_state`` is told each change of that one fact (lost, then ok),
so the front's ``context.masters`` changes together with the monitoring errors in
0x1001/0x1003 (bus-off itself has no EMCY: it cannot be sent). The master is *heard*
by a guard RTR, a heartbeat of a monitored node, an NMT command (a state change this
service did not make) or a write to 0x100C/0x100D/0x1016/0x1017.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from canopen.objectdictionary import datatypes as dt

from fieldgate.can.frame import Frame

from .guarding import GUARD_TIME, LIFE_TIME_FACTOR, Guarding
from .heartbeat import CONSUMER_TIMES, PRODUCER_TIME, HeartbeatConsumer, HeartbeatProducer
from .nmt import NmtState
from .service import ALL_STATES, NodeHost, Service

LIFE_GUARD_CODE = 0x8130
BUS_OFF_RECOVERED_CODE = 0x8140
COMM_REGISTER = 0x11  # generic + communication, as the I-7232D
ERROR_PRE_OPERATIONAL, ERROR_NO_CHANGE, ERROR_STOPPED = 0, 1, 2
ERROR_BEHAVIOUR = 0x1029

Error = tuple[int, bytes]  # (EMCY code, manufacturer bytes): one error of node.emcy
LIFE_GUARDING_ERROR: Error = (LIFE_GUARD_CODE, b"\x07")
BUS_OFF_RECOVERED_ERROR: Error = (BUS_OFF_RECOVERED_CODE, b"\x08")


def heartbeat_error(producer: int) -> Error:
    return (LIFE_GUARD_CODE, bytes([0x07, producer]))


class ErrorControl(Service):
    name = "error_control"
    active_states = ALL_STATES

    def __init__(
        self,
        guard_time_ms: int = 0,
        life_time_factor: int = 0,
        heartbeat_ms: int | None = 0,
        consumers: int = 1,
        error_behaviour: int = ERROR_NO_CHANGE,
        consumer_defaults: Iterable[int] = (),
    ):
        super().__init__()
        self.defaults = (guard_time_ms, life_time_factor, heartbeat_ms)
        self.error_behaviour = error_behaviour
        self.consumer = HeartbeatConsumer(consumers, consumer_defaults)
        self.producer_served = heartbeat_ms is not None  # 0x1017 (an I-7232D: guarding only)
        # what the master monitoring says now (each an active EMCY error, bus-off aside)
        self.sync_lost = False  # SYNC loss reported as an error event (the NA-9161's)
        self.guard_lost = False
        self.heartbeat_lost: set[int] = set()
        self.bus_off = False
        self.bus_off_recovered = False  # EMCY 0x8140 active: the master not heard since
        self.unheard = False  # lost until heard (assume_master_lost); no EMCY: nothing detected
        self._own_state_change = False  # 0x1029 at work: a state change not the master's
        self.master_lost = False  # as last told to node.master_state

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        od = node.od
        self.guarding = Guarding(od)
        self.heartbeat = HeartbeatProducer(od, self.producer_served)
        guard, factor, heartbeat = self.defaults
        od.add_variable(GUARD_TIME, "Guard time", dt.UNSIGNED16, "rw", guard, maximum=32767)
        od.add_variable(LIFE_TIME_FACTOR, "Life time factor", dt.UNSIGNED8, "rw", factor)
        if heartbeat is not None:
            od.add_variable(
                PRODUCER_TIME, "Producer heartbeat time", dt.UNSIGNED16, "rw", heartbeat
            )
        od.add_array(
            ERROR_BEHAVIOUR,
            "Error behaviour",
            [
                (
                    1,
                    "Communication error",
                    dt.UNSIGNED8,
                    "rw",
                    self.error_behaviour,
                    {"maximum": ERROR_STOPPED},
                )
            ],
        )
        self.consumer.add_objects(od)
        if self.consumer.entries:
            od.on_write(CONSUMER_TIMES, lambda *_: self._consumers_written(node.now))
        if heartbeat is not None:
            od.on_write(PRODUCER_TIME, lambda *_: self._heartbeat_time_written(node.now))
        od.on_write(GUARD_TIME, lambda *_: self._guarding_written(node.now))
        od.on_write(LIFE_TIME_FACTOR, lambda *_: self._guarding_written(node.now))

    # -- life cycle ---------------------------------------------------------------------
    def on_reset_communication(self, now: float) -> None:
        self.guarding.reset()
        self.heartbeat.due = None
        self.consumer.reset()

    def on_nmt_state(self, old: NmtState, new: NmtState, now: float) -> None:
        if not self._own_state_change:
            self.unheard = False  # an NMT command, or a reset (NMT, LSS): the master is there
        if old is NmtState.INITIALISING and new is not NmtState.INITIALISING:
            self._restart_heartbeat(now)
            # after a reset (the boot-up is out, EMCY may be sent): the monitoring restarted,
            # so none of its errors holds any more, nor do the other services' (SYNC loss)
            self._end(
                now,
                "reset communication",
                guard=True,
                producers=self.heartbeat_lost,
                bus_off_recovered=True,
                others=self._ended_elsewhere(),
            )
        elif new is NmtState.INITIALISING:
            self.heartbeat.due = None
        else:
            self._report_master(f"NMT {new.label}")

    def _ended_elsewhere(self) -> list[Error]:
        """The errors other services give up at a reset (``reset_ends_errors()``)."""
        ended: list[Error] = []
        for service in self.node.services:
            hook = getattr(service, "reset_ends_errors", None)
            if service is not self and hook is not None:
                ended += hook()
        return ended

    def assume_master_lost(self, reason: str) -> None:
        """Count the master as lost until it is heard (see the module docstring)."""
        self.unheard = True
        self._report_master(reason)

    def _heard(self, reason: str) -> None:
        if self.unheard:
            self.unheard = False
            self._report_master(reason)

    @property
    def cob_id(self) -> int:
        return 0x700 + self.node.node_id

    # -- frames -------------------------------------------------------------------------
    def listen_ids(self) -> set[int]:
        """Guarding RTRs on 0x700 + node-ID, the heartbeats of the 0x1016 producers."""
        if not self.node.configured:
            return set()
        return {self.cob_id, *(0x700 + p for p in self.consumer.watched if 1 <= p <= 127)}

    def on_frame(self, frame: Frame, now: float) -> bool:
        if not self.node.configured:
            return False
        if frame.can_id == self.cob_id:
            if not frame.rtr:
                self.counters["foreign_frames_on_own_id"] += 1
                return True
            self._heard("guard request")
            self._guard_request(now)
            return True
        producer = frame.can_id - 0x700
        if 1 <= producer <= 0x7F and not frame.rtr and producer in self.consumer.watched:
            self._heard(f"heartbeat of node {producer}")
            self._heartbeat_from(producer, frame.data, now)
            return True
        return False

    def producer_time_ms(self) -> int:
        """0x1017 now; 0 when the node has no heartbeat producer."""
        return self.heartbeat.period_ms()

    def _guard_request(self, now: float) -> None:
        if self.producer_time_ms():
            self.counters["guard_rtr_ignored_heartbeat_on"] += 1
            return
        self.counters["guard_requests"] += 1
        self.node.send(Frame(self.cob_id, self.guarding.answer(int(self.node.state))))
        self.guarding.rearm(now, started=True)
        if self.guard_lost or self.bus_off_recovered:
            self._end(now, "life guarding resumed", guard=True, bus_off_recovered=True)

    def guarding_enabled(self) -> bool:
        """Life guarding configured: guard time and life time factor set, heartbeat producer off."""
        return self.guarding.life_time_s() > 0 and not self.producer_time_ms()

    def monitoring(self) -> bool:
        """Whether anything here can hear the master: life guarding or a heartbeat consumer entry."""
        return bool(self.consumer.times) or self.guarding_enabled()

    def _heartbeat_from(self, producer: int, data: bytes, now: float) -> None:
        if len(data) < 1:
            self.counters["heartbeat_malformed"] += 1
            return
        self.counters["heartbeats_consumed"] += 1
        self.consumer.heard(producer, data[0], now)
        if producer in self.heartbeat_lost or self.bus_off_recovered:
            self._end(
                now,
                f"heartbeat of node {producer} back",
                producers=(producer,),
                bus_off_recovered=True,
            )

    # -- timers -------------------------------------------------------------------------
    def deadline(self) -> float | None:
        earliest = self.guarding.life_deadline  # (a plain comparison: asked on every engine call)
        due = self.heartbeat.due
        if due is not None and (earliest is None or due < earliest):
            earliest = due
        if self.consumer.watched:
            due = self.consumer.deadline()
            if due is not None and (earliest is None or due < earliest):
                earliest = due
        return earliest

    def poll(self, now: float) -> None:
        if self.heartbeat.take_due(now):
            self.node.send(Frame(self.cob_id, bytes([int(self.node.state)])))
            self.counters["heartbeats_sent"] += 1
        if self.guarding.expired(now):
            self.guard_lost = True
            self.counters["life_guarding_events"] += 1
            self._master_lost(LIFE_GUARDING_ERROR, "life guarding timeout", now)
        for producer in self.consumer.timed_out(now):
            self.heartbeat_lost.add(producer)
            self.counters["heartbeat_consumer_timeouts"] += 1
            self._master_lost(
                heartbeat_error(producer), f"heartbeat of node {producer} timed out", now
            )

    def _restart_heartbeat(self, now: float) -> None:
        running = self.node.state is not NmtState.INITIALISING and self.node.configured
        self.heartbeat.restart(now, running)

    # -- writes to the monitoring objects -------------------------------------------------
    def _heartbeat_time_written(self, now: float) -> None:
        self._restart_heartbeat(now)
        self._guarding_written(now)  # heartbeat on is guarding off, and back

    def _guarding_written(self, now: float) -> None:
        self._heard("monitoring configured")
        if self.guarding_enabled():
            self.guarding.rearm(now)
            return
        self.guarding.stop()
        self._end(
            now, "life guarding switched off", guard=True, bus_off_recovered=not self.monitoring()
        )

    def _consumers_written(self, now: float) -> None:
        self._heard("monitoring configured")
        self.consumer.rewritten()
        dropped = sorted(p for p in self.heartbeat_lost if p not in self.consumer.times)
        reason = "heartbeat consumer for node " + ", ".join(map(str, dropped)) + " switched off"
        self._end(now, reason, producers=dropped, bus_off_recovered=not self.monitoring())

    # -- master lost / back -----------------------------------------------------------------
    def bus_state(self, bus_off: bool, now: float) -> None:
        """The adapter reports the CAN controller's bus-off state."""
        if bus_off and not self.bus_off:
            self.bus_off = True
            self._event_began("bus_off", "CAN bus-off", now)
        elif not bus_off and self.bus_off:
            self.bus_off = False
            if self.node.emcy is not None:
                self.node.emcy.raise_error(
                    BUS_OFF_RECOVERED_CODE, COMM_REGISTER, BUS_OFF_RECOVERED_ERROR[1], now
                )
                self.bus_off_recovered = True
            # with nothing to hear the master by, the recovery EMCY is an event: reset at once
            self._end(now, "recovered from bus-off", bus_off_recovered=not self.monitoring())

    def sync_state(self, lost: bool, now: float) -> None:
        """SYNC loss as an error event (the NA-9161: outputs to their error values, 0x1029);
        the SYNC service raises and clears its own EMCY. Called only when the style says so."""
        if lost and not self.sync_lost:
            self.sync_lost = True
            self._event_began("sync_error_events", "SYNC lost", now)
        elif not lost and self.sync_lost:
            self.sync_lost = False
            self._report_master("SYNC back")

    def _event_began(self, counter: str, reason: str, now: float) -> None:
        """A master-lost event this service raises no EMCY for (bus-off, SYNC loss): counted,
        reported, and 0x1029 applies."""
        self.counters[counter] += 1
        self._report_master(reason)
        self._apply_error_behaviour(now)

    def _master_lost(self, error: Error, reason: str, now: float) -> None:
        if self.node.emcy is not None:
            self.node.emcy.raise_error(error[0], COMM_REGISTER, error[1], now)
        self._report_master(reason)
        self._apply_error_behaviour(now)

    def _apply_error_behaviour(self, now: float) -> None:
        behaviour = self.node.od.integer(ERROR_BEHAVIOUR, 1)
        self._own_state_change = True
        try:
            if behaviour == ERROR_PRE_OPERATIONAL and self.node.state is NmtState.OPERATIONAL:
                self.node.set_state(NmtState.PRE_OPERATIONAL, now)
            elif behaviour == ERROR_STOPPED:
                self.node.set_state(NmtState.STOPPED, now)
        finally:
            self._own_state_change = False

    def _end(
        self,
        now: float,
        reason: str,
        guard: bool = False,
        producers: Iterable[int] = (),
        bus_off_recovered: bool = False,
        others: Iterable[Error] = (),
    ) -> None:
        """Monitoring errors that no longer hold (master heard, monitoring off, reset): one EMCY."""
        ended: list[Error] = list(others)
        if guard and self.guard_lost:
            self.guard_lost = False
            ended.append(LIFE_GUARDING_ERROR)
        for producer in sorted(producers):
            if producer in self.heartbeat_lost:
                self.heartbeat_lost.discard(producer)
                ended.append(heartbeat_error(producer))
        if bus_off_recovered and self.bus_off_recovered:
            self.bus_off_recovered = False
            ended.append(BUS_OFF_RECOVERED_ERROR)
        if ended and self.node.emcy is not None:
            self.node.emcy.clear_errors(ended, now)
        self._report_master(reason)

    def _report_master(self, reason: str) -> None:
        """Tell the node's master listeners when "master lost" changes, and only then."""
        lost = (
            self.guard_lost
            or bool(self.heartbeat_lost)
            or self.bus_off
            or self.unheard
            or self.sync_lost
        )
        if lost != self.master_lost:
            self.master_lost = lost
            self.node.master_state(not lost, reason)

    def status(self) -> dict[str, Any]:
        guarding = (
            "lost"
            if self.guard_lost
            else (
                "active"
                if self.guarding.life_deadline
                else ("armed" if self.guarding_enabled() else "off")
            )
        )
        return {
            **self.counters,
            "guarding": guarding,
            "heartbeat_lost": sorted(self.heartbeat_lost),
            "bus_off": self.bus_off,
            "bus_off_recovered": self.bus_off_recovered,
            "sync_error_event": self.sync_lost,
            "master_unheard": self.unheard,
            "master": "lost" if self.master_lost else "ok",
        }
