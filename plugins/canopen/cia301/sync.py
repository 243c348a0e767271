"""SYNC consumer and optional producer: 0x1005 COB-ID, 0x1006 period, 0x1019 counter.

* Consumer: a frame on the 0x1005 COB-ID (DLC 0, or DLC 1 carrying the counter when
  0x1019 > 1) calls ``node.sync(counter, now)``, which every service sees in
  ``on_sync`` (the PDO engine uses it). Only in pre-operational and operational.
* SYNC loss: with 0x1006 (communication cycle period, us) non-zero, a SYNC missing for
  1.5 periods after the first one raises EMCY 0x8100 (register 0x11, manufacturer
  byte 0x02, the NA-9161/Beckhoff "SYNC" bit). (CiA 301 does not fix the tolerance;
  1.5 periods is what CANopenNode uses.) The error ends (error-reset EMCY, 0x1001
  drops its bits; docs/canopen.md "Monitoring switched off") when

  - the next SYNC of the right length is consumed (as CANopenNode's CO_SYNC_process);
  - SYNC supervision is switched off: 0x1006 written 0, or 0x1005 bit 30 set with a
    period (the node produces SYNC itself and supervises nothing);
  - reset communication or reset node, after the boot-up. Error control gathers the
    errors every reset ends (:meth:`SyncService.reset_ends_errors`) into one EMCY.

  A new non-zero period or a new COB-ID keeps it: supervision restarts at the first
  SYNC, which ends it. NMT Stopped keeps it too (no SYNC is consumed there).
  With ``loss_is_error_event`` (the ``na9161`` style, seed-004 §4.8 "outputs go to the
  fault state, the adapter goes to PRE-OPERATIONAL") the loss is also an error event:
  error control reports it as master lost (outputs to their error values) and applies
  0x1029:1, until the loss ends.
* Producer (test benches): 0x1005 bit 30 set and 0x1006 non-zero sends SYNC every
  period, with a counter 1..0x1019 when 0x1019 > 1; the node consumes its own SYNC.
* 0x1019 may be written only while 0x1006 is 0 (else 0800 0022); values 1 and
  241..255 abort 0609 0030. 0x1005 with bit 29 (29-bit) aborts 0609 0030, and so does
  a new identifier while the producer bit stays set (clear bit 30 first, CiA 301).
"""

from __future__ import annotations

from typing import Any

from canopen.objectdictionary import datatypes as dt

from fieldgate.can.frame import Frame

from . import abort
from .abort import SdoAbort
from .cobid import check_cob_id
from .nmt import NmtState
from .service import COMMUNICATING, NodeHost, Service

SYNC_LOSS_CODE = 0x8100
SYNC_LOSS_REGISTER = 0x11  # generic + communication
SYNC_LOSS_ERROR = (SYNC_LOSS_CODE, b"\x02")  # (EMCY code, manufacturer bytes), as errctl's Error
PRODUCER_BIT = 1 << 30
LOSS_TOLERANCE = 1.5


class SyncService(Service):
    name = "sync"
    active_states = COMMUNICATING

    def __init__(self, cob_id: int = 0x80, loss_is_error_event: bool = False):
        super().__init__()
        self.default_cob_id = cob_id
        # SYNC loss is also an error event (the NA-9161, seed-004 §4.8): error control
        # reports it like a master loss (outputs to their error values, 0x1029)
        self.loss_is_error_event = loss_is_error_event
        self.loss_deadline: float | None = None
        self.produce_due: float | None = None
        self.counter = 0
        self.lost = False

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        od = node.od
        od.add_variable(0x1005, "COB-ID SYNC message", dt.UNSIGNED32, "rw", self.default_cob_id)
        od.add_variable(0x1006, "Communication cycle period", dt.UNSIGNED32, "rw", 0)
        od.add_variable(0x1019, "Synchronous counter overflow value", dt.UNSIGNED8, "rw", 0)
        od.add_validator(0x1005, self._check_cob_id)
        od.add_validator(0x1019, self._check_overflow)
        for index in (0x1005, 0x1006):
            od.on_write(index, lambda *_: self._configure(node.now))

    @property
    def cob_id(self) -> int:
        return self.node.od.integer(0x1005) & 0x7FF

    def _period_s(self) -> float:
        return self.node.od.integer(0x1006) / 1e6

    def _producer(self) -> bool:
        return (
            bool(self.node.od.integer(0x1005) & PRODUCER_BIT) and self.node.od.integer(0x1006) > 0
        )

    def supervising(self) -> bool:
        """SYNC loss is watched: a communication cycle period, and the SYNC comes from elsewhere."""
        return self.node.od.integer(0x1006) > 0 and not self._producer()

    def _configure(self, now: float) -> None:
        self.loss_deadline = None  # supervision (re)starts at the first SYNC
        self.counter = 0
        if self._producer() and self.node.state in COMMUNICATING:
            self.produce_due = (
                self.produce_due if self.produce_due is not None else now + self._period_s()
            )
        else:
            self.produce_due = None
        if not self.supervising():
            self._end_loss(now)

    def on_reset_communication(self, now: float) -> None:
        self.produce_due = None  # the loss error ends after the boot-up (on_nmt_state)

    def on_nmt_state(self, old: NmtState, new: NmtState, now: float) -> None:
        if old is NmtState.INITIALISING and new is not NmtState.INITIALISING:
            self._end_loss(now)  # unless error control already ended it with its own (one EMCY)
        if new in COMMUNICATING:
            self._configure(now)
        else:
            self.produce_due = None
            self.loss_deadline = None

    def reset_ends_errors(self) -> list[tuple[int, bytes]]:
        """Called by error control after a reset's boot-up: the errors the reset ends, now forgotten
        here; error control clears them with its own in one error-reset EMCY."""
        if not self.lost:
            return []
        self.lost = False
        self._error_event(False, self.node.now)
        return [SYNC_LOSS_ERROR]

    def _end_loss(self, now: float) -> None:
        if self.lost:
            self.lost = False
            if self.node.emcy is not None:
                self.node.emcy.clear_errors([SYNC_LOSS_ERROR], now)
            self._error_event(False, now)

    def _error_event(self, lost: bool, now: float) -> None:
        if not self.loss_is_error_event:
            return
        try:
            errctl = self.node.service("error_control")
        except KeyError:
            return
        errctl.sync_state(lost, now)

    # -- consumer --------------------------------------------------------------------------
    def listen_ids(self) -> tuple[int, ...]:
        return (self.cob_id,)

    def on_frame(self, frame: Frame, now: float) -> bool:
        if frame.can_id != self.cob_id or frame.rtr:
            return False
        overflow = self.node.od.integer(0x1019)
        if overflow > 1 and len(frame.data) != 1 or overflow <= 1 and len(frame.data) != 0:
            self.counters["bad_length"] += 1
            return True
        self._consume(frame.data[0] if frame.data else None, now)
        return True

    def _consume(self, counter: int | None, now: float) -> None:
        self.counters["received"] += 1
        period = self._period_s()
        self.loss_deadline = (
            now + LOSS_TOLERANCE * period if period and not self._producer() else None
        )
        self._end_loss(now)
        self.node.sync(counter, now)

    # -- timers ------------------------------------------------------------------------------
    def deadline(self) -> float | None:
        loss, produce = self.loss_deadline, self.produce_due
        if loss is None or produce is None:
            return produce if loss is None else loss
        return min(loss, produce)

    def poll(self, now: float) -> None:
        if self.produce_due is not None and now >= self.produce_due:
            period = self._period_s()
            self.produce_due = max(self.produce_due + period, now)
            overflow = self.node.od.integer(0x1019)
            if overflow > 1:
                self.counter = self.counter % overflow + 1
                data = bytes([self.counter])
            else:
                data = b""
            self.node.send(Frame(self.cob_id, data))
            self.counters["produced"] += 1
            self.node.sync(data[0] if data else None, now)
        if self.loss_deadline is not None and now >= self.loss_deadline:
            self.loss_deadline = None
            if not self.lost:
                self.lost = True
                self.counters["sync_loss"] += 1
                if self.node.emcy is not None:
                    self.node.emcy.raise_error(
                        SYNC_LOSS_CODE, SYNC_LOSS_REGISTER, SYNC_LOSS_ERROR[1], now
                    )
                self._error_event(True, now)

    # -- validators --------------------------------------------------------------------------
    def _check_cob_id(self, sub: int, value: int) -> None:
        check_cob_id(value, "SYNC")  # SYNC is always consumed: bit 31 does not free the identifier
        old = self.node.od.integer(0x1005)
        if old & value & PRODUCER_BIT and (old & 0x7FF) != (value & 0x7FF):
            raise SdoAbort(abort.VALUE_RANGE, "clear bit 30 before changing the SYNC COB-ID")

    def _check_overflow(self, sub: int, value: int) -> None:
        if self.node.od.integer(0x1006):
            raise SdoAbort(abort.DEVICE_STATE, "0x1019 can change only while 0x1006 is 0")
        if value == 1 or value > 240:
            raise SdoAbort(abort.VALUE_RANGE, "0x1019 must be 0 or 2..240")

    def status(self) -> dict[str, Any]:
        return {**self.counters, "sync_lost": self.lost, "producer": bool(self.produce_due)}
