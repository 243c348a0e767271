"""Transmit PDOs (CiA 301 §7.2.2): when each TPDO goes out and with what data, sans-I/O.

Transmission types (seed-000 §2.7): 0 acyclic synchronous (on SYNC, only after an event),
1-240 every n-th SYNC (from the SYNC start value when SYNC counters are used), 252 sampled
at SYNC and sent on RTR, 253 sent on RTR, 254/255 on events and the event timer, held
back by the inhibit time (the latest data goes out when it ends).

Application events (:meth:`TpdoService.object_changed`, from process-image batches) are
coalesced: the TPDOs that map the changed objects are queued once and sent when the
engine call ends (:meth:`TpdoService.run_queued`), or at the next timer call when the
event came from outside one. Frames wait in :attr:`TpdoService.outbox`.
"""

from __future__ import annotations

from typing import Literal

from .mapping import Frame, Pdo, PdoCounters, PdoMapping, async_type


class TpdoService:
    """The TPDOs of one node: SYNC, events, inhibit time, event timer, remote requests."""

    def __init__(
        self,
        pdos: list[Pdo],
        mapping: PdoMapping,
        counters: PdoCounters,
        start_policy: Literal["async", "all", "none"] = "async",
    ):
        self.pdos = pdos
        self.mapping = mapping
        self.counters = counters
        self.start_policy = start_policy
        self.operational = False
        self.outbox: list[Frame] = []
        self._rtr: dict[int, Pdo] = {}
        self._timed: list[Pdo] = []
        self._on_sync: list[Pdo] = []  # valid, types 0-252: sampled (and maybe sent) at SYNC
        self._events: dict[tuple[int, int], list[Pdo]] = {}
        self._queued: dict[int, Pdo] = {}
        self._queued_at: float | None = None

    # -- life cycle -------------------------------------------------------------------
    def reindex(self) -> None:
        """Rebuild the look-up tables after a parameter or mapping change."""
        # Only these TPDOs ever have a deadline (event timer, or events held back by an inhibit time).
        self._timed = [
            p
            for p in self.pdos
            if p.valid and async_type(p.trans_type) and (p.event_timer or p.inhibit)
        ]
        self._rtr = {p.can_id: p for p in self.pdos if p.valid and p.rtr_allowed}
        self._on_sync = [p for p in self.pdos if p.valid and p.trans_type <= 252]
        self._events = {}
        for pdo in self.pdos:
            for slot in pdo.slots:
                if slot.entry is None:
                    continue
                bucket = self._events.setdefault((slot.index, slot.sub), [])
                if pdo not in bucket:
                    bucket.append(pdo)

    def start(self, now: float) -> None:
        """Entering Operational: timers armed, the start policy's TPDOs sent once."""
        self.operational = True
        for pdo in self.pdos:
            pdo.clear_runtime()
            self.arm_timer(pdo, now)
        for pdo in self.pdos:
            if pdo.valid and pdo.slots and self._sent_on_start(pdo):
                self.send(pdo, now)

    def stop(self) -> None:
        """Leaving Operational: nothing queued, nothing pending."""
        self.operational = False
        self.drop_queued()
        for pdo in self.pdos:
            pdo.clear_runtime()

    def drop_queued(self) -> None:
        self._queued, self._queued_at = {}, None

    def _sent_on_start(self, pdo: Pdo) -> bool:
        if self.start_policy == "all":
            return pdo.trans_type not in (252, 253)
        return self.start_policy == "async" and async_type(pdo.trans_type)

    # -- inputs -------------------------------------------------------------------------
    def listens_to(self, can_id: int) -> bool:
        return can_id in self._rtr

    def listen_ids(self) -> set[int]:
        return set(self._rtr)

    def on_rtr(self, can_id: int) -> bool:
        """A remote request: answers it (type 252 with the data sampled at the last SYNC).
        False when no TPDO that allows RTR has this COB-ID."""
        pdo = self._rtr.get(can_id)
        if pdo is None:
            return False
        data = (
            pdo.sample
            if pdo.trans_type == 252 and pdo.sample is not None
            else self.mapping.pack(pdo)
        )
        self.outbox.append((pdo.can_id, data))
        self.counters.rtr_answered += 1
        return True

    def on_sync(self, now: float, counter: int | None) -> None:
        for pdo in self._on_sync:
            self._sync_tpdo(pdo, now, counter)

    def object_changed(self, index: int, sub: int, now: float) -> bool:
        """Queue the TPDOs that map (index, sub); True when one was queued."""
        pdos = self._events.get((index, sub))
        if not pdos or not self.operational:
            return False
        if self._queued_at is None:
            self._queued_at = now
        for pdo in pdos:
            self._queued.setdefault(pdo.number, pdo)
        return True

    @property
    def queued(self) -> bool:
        return bool(self._queued)

    def run_queued(self, now: float) -> None:
        queued = self._queued
        self.drop_queued()
        for pdo in queued.values():
            self._event(pdo, now)

    def on_timer(self, now: float) -> None:
        self.run_queued(now)
        for pdo in self._timed:
            if pdo.pending and now >= pdo.next_allowed:
                self.send(pdo, now)
            elif pdo.timer_due is not None and now >= pdo.timer_due:
                pdo.timer_due = None
                self._event(pdo, now)

    def next_deadline(self) -> float | None:
        earliest = self._queued_at
        for p in self._timed:  # a plain loop: this runs several times per engine call
            if p.pending and (earliest is None or p.next_allowed < earliest):
                earliest = p.next_allowed
            if p.timer_due is not None and (earliest is None or p.timer_due < earliest):
                earliest = p.timer_due
        return earliest

    def take_frames(self) -> list[Frame]:
        frames, self.outbox = self.outbox, []
        return frames

    # -- behaviour ----------------------------------------------------------------------
    def send(self, pdo: Pdo, now: float, data: bytes | None = None) -> None:
        self.outbox.append((pdo.can_id, self.mapping.pack(pdo) if data is None else data))
        self.counters.tpdo_sent += 1
        pdo.pending = pdo.sync_event = False
        pdo.next_allowed = now + pdo.inhibit * 1e-4
        self.arm_timer(pdo, now)

    def arm_timer(self, pdo: Pdo, now: float) -> None:
        active = (
            pdo.transmit
            and self.operational
            and pdo.valid
            and pdo.event_timer
            and async_type(pdo.trans_type)
        )
        pdo.timer_due = now + pdo.event_timer / 1000 if active else None

    def _event(self, pdo: Pdo, now: float) -> None:
        if not self.operational or not pdo.valid:
            return
        if pdo.trans_type == 0:
            pdo.sync_event = True
        elif async_type(pdo.trans_type):
            if now >= pdo.next_allowed:
                self.send(pdo, now)
            else:
                pdo.pending = True

    def _sync_tpdo(self, pdo: Pdo, now: float, counter: int | None) -> None:
        pdo.sample = self.mapping.pack(pdo)
        t = pdo.trans_type
        if t == 0:
            if pdo.sync_event:
                self.send(pdo, now, pdo.sample)
        elif t <= 240:
            if pdo.waiting_start and counter is not None:
                if counter != pdo.sync_start:
                    return
                pdo.waiting_start = False
                pdo.sync_count = 0
                self.send(pdo, now, pdo.sample)
                return
            pdo.sync_count += 1
            if pdo.sync_count >= t:
                pdo.sync_count = 0
                self.send(pdo, now, pdo.sample)
