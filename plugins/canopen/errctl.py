"""Error control (CiA 301 §7.2.8.3): node/life guarding, heartbeat producer and consumer.

* Node guarding: an RTR on 0x700+ID is answered ``[toggle<<7 | state]`` with DLC 1;
  the toggle is 0 in the first answer after boot-up / reset communication. While the
  heartbeat producer time 0x1017 is non-zero, CiA 301 says heartbeat replaces
  guarding: guard RTRs are then counted and not answered.
* Life guarding: with guard time 0x100C (ms) and life time factor 0x100D both
  non-zero, the node life time starts at the first guard RTR; when it passes with no
  further RTR, the master is lost: EMCY ``30 81 11 07 00 00 00 00`` (TV-20) and the
  node's master listeners are told (the front applies the outputs' error modes). The
  next guard RTR clears the error (error reset EMCY) and reports the master back.
* Heartbeat producer 0x1017 (ms): ``[state]`` on 0x700+ID in every state after the
  boot-up; a write restarts the period.
* Heartbeat consumer 0x1016:1..N (bits 23-16 node-ID, 15-0 time in ms): monitoring of
  a node starts at its first heartbeat; a timeout is a master-lost event with EMCY
  0x8130 (register 0x11, manufacturer bytes ``07 <node-ID>``); its next heartbeat
  clears it. Two entries with the same node-ID and non-zero times abort 0604 0043.
* 0x1029:1 (error behaviour, communication error): on a master-lost event an
  operational node goes to pre-operational (0, the CiA 301 default value), stays as
  it is (1) or stops (2). The front's default is 1 (the I-7232D keeps its state);
  the NA-9161 behaviour is 0.
* Bus-off (reported by the adapter via :meth:`bus_state`) is a master-lost event;
  the recovery sends EMCY 0x8140 (register 0x11, manufacturer byte 08, as the I-7232D),
  cleared when the master is heard again.
"""

from __future__ import annotations

from canopen.objectdictionary import datatypes as dt

from . import abort
from .abort import SdoAbort
from .frame import Frame, NmtState
from .service import ALL_STATES, Service

LIFE_GUARD_CODE = 0x8130
BUS_OFF_RECOVERED_CODE = 0x8140
COMM_REGISTER = 0x11  # generic + communication, as the I-7232D
ERROR_PRE_OPERATIONAL, ERROR_NO_CHANGE, ERROR_STOPPED = 0, 1, 2


class ErrorControl(Service):
    name = "error_control"
    active_states = ALL_STATES

    def __init__(self, guard_time_ms: int = 0, life_time_factor: int = 0, heartbeat_ms: int = 0, consumers: int = 1, error_behaviour: int = ERROR_NO_CHANGE):
        super().__init__()
        self.defaults = (guard_time_ms, life_time_factor, heartbeat_ms)
        self.error_behaviour = error_behaviour
        self.consumers = consumers
        self.toggle = 0
        self.life_deadline: float | None = None
        self.guard_lost = False
        self.heartbeat_due: float | None = None
        self.watched: dict[int, float | None] = {}  # producer node-ID -> deadline (None: not yet heard)
        self.heartbeat_lost: set[int] = set()
        self.bus_off = False

    def attach(self, node) -> None:
        super().attach(node)
        od = node.od
        guard, factor, heartbeat = self.defaults
        od.add_variable(0x100C, "Guard time", dt.UNSIGNED16, "rw", guard, maximum=32767)
        od.add_variable(0x100D, "Life time factor", dt.UNSIGNED8, "rw", factor)
        od.add_variable(0x1017, "Producer heartbeat time", dt.UNSIGNED16, "rw", heartbeat)
        od.add_array(0x1029, "Error behaviour", [(1, "Communication error", dt.UNSIGNED8, "rw", self.error_behaviour, {"maximum": ERROR_STOPPED})])
        if self.consumers:
            od.add_array(0x1016, "Consumer heartbeat time", [(i, f"Consumer heartbeat time {i}", dt.UNSIGNED32, "rw", 0, {"maximum": 0x00FFFFFF}) for i in range(1, self.consumers + 1)])
            od.add_validator(0x1016, self._check_consumer)
            od.on_write(0x1016, lambda *_: self._configure_consumers())
        od.on_write(0x1017, lambda *_: self._restart_heartbeat(node.now))
        od.on_write(0x100C, lambda *_: self._rearm_life_guarding(node.now))
        od.on_write(0x100D, lambda *_: self._rearm_life_guarding(node.now))

    # -- life cycle ---------------------------------------------------------------------
    def on_reset_communication(self, now: float) -> None:
        self.toggle = 0
        self.life_deadline = None
        self._configure_consumers()
        self.heartbeat_due = None

    def on_nmt_state(self, old: NmtState, new: NmtState, now: float) -> None:
        if old is NmtState.INITIALISING and new is not NmtState.INITIALISING:
            self._restart_heartbeat(now)
        elif new is NmtState.INITIALISING:
            self.heartbeat_due = None

    @property
    def cob_id(self) -> int:
        return 0x700 + self.node.node_id

    # -- frames -------------------------------------------------------------------------
    def on_frame(self, frame: Frame, now: float) -> bool:
        if not self.node.configured:
            return False
        if frame.can_id == self.cob_id:
            if not frame.rtr:
                self.counters["foreign_frames_on_own_id"] += 1
                return True
            self._guard_request(now)
            return True
        if 0x701 <= frame.can_id <= 0x77F and not frame.rtr and frame.can_id - 0x700 in self.watched:
            self._heartbeat_from(frame.can_id - 0x700, frame.data, now)
            return True
        return False

    def _guard_request(self, now: float) -> None:
        if self.node.od.get(0x1017):
            self.counters["guard_rtr_ignored_heartbeat_on"] += 1
            return
        self.counters["guard_requests"] += 1
        self.node.send(Frame(self.cob_id, bytes([(self.toggle << 7) | int(self.node.state)])))
        self.toggle ^= 1
        self._rearm_life_guarding(now, started=True)
        if self.guard_lost:
            self.guard_lost = False
            self._master_seen(LIFE_GUARD_CODE, bytes([0x07]), "life guarding resumed")

    def _life_time_s(self) -> float:
        return self.node.od.get(0x100C) * self.node.od.get(0x100D) / 1000.0

    def _rearm_life_guarding(self, now: float, started: bool = False) -> None:
        if not started and self.life_deadline is None:
            return  # not started yet: the first guard RTR starts it
        life = self._life_time_s()
        self.life_deadline = now + life if life > 0 else None

    def _heartbeat_from(self, producer: int, data: bytes, now: float) -> None:
        if len(data) < 1:
            self.counters["heartbeat_malformed"] += 1
            return
        self.counters["heartbeats_consumed"] += 1
        period = self._consumer_times().get(producer, 0)
        if data[0] == 0x00:  # boot-up: monitoring restarts at its next heartbeat
            self.watched[producer] = None
        else:
            self.watched[producer] = now + period / 1000.0
        if producer in self.heartbeat_lost:
            self.heartbeat_lost.discard(producer)
            self._master_seen(LIFE_GUARD_CODE, bytes([0x07, producer]), f"heartbeat of node {producer} back")

    # -- timers -------------------------------------------------------------------------
    def deadline(self) -> float | None:
        earliest = None
        for t in (self.life_deadline, self.heartbeat_due):
            if t is not None and (earliest is None or t < earliest):
                earliest = t
        for t in self.watched.values() if self.watched else ():
            if t is not None and (earliest is None or t < earliest):
                earliest = t
        return earliest

    def poll(self, now: float) -> None:
        if self.heartbeat_due is not None and now >= self.heartbeat_due:
            self.node.send(Frame(self.cob_id, bytes([int(self.node.state)])))
            self.counters["heartbeats_sent"] += 1
            period = self.node.od.get(0x1017) / 1000.0
            self.heartbeat_due = (self.heartbeat_due + period) if self.heartbeat_due + period > now else now + period
        if self.life_deadline is not None and now >= self.life_deadline:
            self.life_deadline = None
            self.guard_lost = True
            self.counters["life_guarding_events"] += 1
            self._master_lost(LIFE_GUARD_CODE, bytes([0x07]), "life guarding timeout", now)
        for producer, due in list(self.watched.items()):
            if due is not None and now >= due:
                self.watched[producer] = None
                self.heartbeat_lost.add(producer)
                self.counters["heartbeat_consumer_timeouts"] += 1
                self._master_lost(LIFE_GUARD_CODE, bytes([0x07, producer]), f"heartbeat of node {producer} timed out", now)

    def _restart_heartbeat(self, now: float) -> None:
        period = self.node.od.get(0x1017)
        if period and self.node.state is not NmtState.INITIALISING and self.node.configured:
            self.heartbeat_due = now + period / 1000.0
        else:
            self.heartbeat_due = None

    # -- heartbeat consumer objects -----------------------------------------------------------
    def _consumer_times(self) -> dict[int, int]:
        times = {}
        for sub in range(1, self.consumers + 1):
            entry = self.node.od.get(0x1016, sub)
            producer, period = (entry >> 16) & 0xFF, entry & 0xFFFF
            if 1 <= producer <= 127 and period:
                times[producer] = period
        return times

    def _configure_consumers(self) -> None:
        times = self._consumer_times() if self.consumers else {}
        self.watched = {p: self.watched.get(p) if p in self.watched else None for p in times}
        self.heartbeat_lost &= set(times)

    def _check_consumer(self, sub: int, value: int) -> None:
        producer, period = (value >> 16) & 0xFF, value & 0xFFFF
        if not period or sub == 0:
            return
        for other in range(1, self.consumers + 1):
            entry = self.node.od.get(0x1016, other)
            if other != sub and (entry >> 16) & 0xFF == producer and entry & 0xFFFF:
                raise SdoAbort(abort.INCOMPATIBLE_PARAMETER, f"node {producer} is already monitored at sub {other}")

    # -- master lost / back -----------------------------------------------------------------
    def bus_state(self, bus_off: bool, now: float) -> None:
        """The adapter reports the CAN controller's bus-off state."""
        if bus_off and not self.bus_off:
            self.bus_off = True
            self.counters["bus_off"] += 1
            self._master_lost_without_emcy("CAN bus-off", now)
        elif not bus_off and self.bus_off:
            self.bus_off = False
            if self.node.emcy is not None:
                self.node.emcy.raise_error(BUS_OFF_RECOVERED_CODE, COMM_REGISTER, bytes([0x08]), now)
            self.node.master_state(True, "recovered from bus-off")

    def _master_lost(self, code: int, manufacturer: bytes, reason: str, now: float) -> None:
        if self.node.emcy is not None:
            self.node.emcy.raise_error(code, COMM_REGISTER, manufacturer, now)
        self._master_lost_without_emcy(reason, now)

    def _master_lost_without_emcy(self, reason: str, now: float) -> None:
        self.node.master_state(False, reason)
        behaviour = self.node.od.get(0x1029, 1)
        if behaviour == ERROR_PRE_OPERATIONAL and self.node.state is NmtState.OPERATIONAL:
            self.node.set_state(NmtState.PRE_OPERATIONAL, now)
        elif behaviour == ERROR_STOPPED:
            self.node.set_state(NmtState.STOPPED, now)

    def _master_seen(self, code: int, manufacturer: bytes, reason: str) -> None:
        if self.node.emcy is not None:
            self.node.emcy.clear_error(code, manufacturer)
            if self.node.emcy.is_active(BUS_OFF_RECOVERED_CODE):
                self.node.emcy.clear_error(BUS_OFF_RECOVERED_CODE)
        self.node.master_state(True, reason)

    def status(self) -> dict:
        return {**self.counters, "guarding": "lost" if self.guard_lost else ("active" if self.life_deadline else "idle"),
                "heartbeat_lost": sorted(self.heartbeat_lost), "bus_off": self.bus_off}
