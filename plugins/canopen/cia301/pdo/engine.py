"""PDO engine (CiA 301 §7.2.2), sans-I/O: the PDO services of one node, composed.

Feed it what happens and it returns the frames to send, as ``(can_id, data)`` tuples:

* :meth:`PdoEngine.on_frame` ``(can_id, data, now, rtr=False)`` -- an RPDO, or a remote
  request for a TPDO;
* :meth:`PdoEngine.on_sync` ``(now, counter=None)`` -- a SYNC (``counter`` is the SYNC
  counter byte when 0x1019 is used);
* :meth:`PdoEngine.set_operational` ``(flag, now)`` -- NMT state changes; PDOs live only
  in Operational;
* :meth:`PdoEngine.on_timer` ``(now)`` -- when :meth:`PdoEngine.next_deadline` is due
  (event timers, transmissions held back by the inhibit time);
* :meth:`PdoEngine.object_changed` ``(index, sub, now)`` -- an application event on a
  mapped object (the CiA 401 profile calls it from process-image subscriptions). Frames
  it produces outside one of the calls above wait in the outbox; ``wakeup`` is called so
  the adapter can :meth:`PdoEngine.take_frames` and re-read the deadline.

The work is done by one service per concern, each in its own module:

* :mod:`.rpdo` -- :class:`~.rpdo.RpdoService`: reception, length check, latching until
  SYNC, writing the mapped entries (one ``directory.batch()`` per RPDO, or per SYNC);
* :mod:`.tpdo` -- :class:`~.tpdo.TpdoService`: SYNC, events, inhibit time, event timer,
  remote requests;
* :mod:`.pdo_mapping` -- the :class:`~.pdo_mapping.Pdo` record, mapping rules, packing
  and unpacking, the mapping parameter objects (0x1600-, 0x1A00-);
* :mod:`.pdo_comm` -- the communication parameter objects (0x1400-, 0x1800-) and the
  records 0x1010 stores.

The engine owns what they share: the NMT state, the counters, the time of the current
call and the end-of-call step that sends the TPDOs events queued during the call (one
RPDO writing 8 DO bits that loop back to DI gives one TPDO).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, Literal

from ..entries import Directory, ObjectDef
from .comm import PdoCommParameters
from .defaults import PdoDefault
from .mapping import (
    COB_NO_RTR,
    MAX_BITS,
    MAX_ENTRIES,
    Frame,
    Pdo,
    PdoCounters,
    PdoMapping,
    dummy_types,
)
from .rpdo import RpdoService
from .tpdo import TpdoService

log = logging.getLogger("fieldgate.canopen.pdo")

MAX_PDOS = 512

__all__ = [
    "COB_NO_RTR",
    "MAX_BITS",
    "MAX_ENTRIES",
    "MAX_PDOS",
    "Frame",
    "Pdo",
    "PdoCounters",
    "PdoEngine",
    "dummy_types",
]


class PdoEngine:
    def __init__(
        self,
        directory: Directory,
        tpdo_defaults: list[PdoDefault],
        rpdo_defaults: list[PdoDefault],
        node_id: int,
        *,
        start_policy: Literal["async", "all", "none"] = "async",
        rpdo_timing: bool = False,
        clock: Callable[[], float] = time.monotonic,
        length_error: Callable[[bool], None] | None = None,
        wakeup: Callable[[], None] | None = None,
        exists: Callable[[int, int], bool] | None = None,
        granularity: int = 8,
    ):
        if not 1 <= len(tpdo_defaults) <= MAX_PDOS or not 1 <= len(rpdo_defaults) <= MAX_PDOS:
            raise ValueError(f"1 to {MAX_PDOS} PDOs per direction")
        self.mapping = PdoMapping(directory, granularity, exists)
        self.directory = directory
        self.granularity = granularity
        self.node_id = node_id
        self.clock = clock
        self.wakeup = wakeup
        self.tpdos = [Pdo(n + 1, True, d) for n, d in enumerate(tpdo_defaults)]
        self.rpdos = [Pdo(n + 1, False, d) for n, d in enumerate(rpdo_defaults)]
        self.operational = False
        self.counters = PdoCounters()
        self.tpdo = TpdoService(self.tpdos, self.mapping, self.counters, start_policy)
        self.rpdo = RpdoService(self.rpdos, self.mapping, self.counters, length_error)
        self.comm = PdoCommParameters(
            self.tpdos + self.rpdos,
            lambda: self.node_id,
            lambda pdo: self.tpdo.arm_timer(pdo, self.clock()),
            self._reindex,
            rpdo_timing=rpdo_timing,
        )
        self._depth = 0
        self._now = 0.0
        self.reset()

    @property
    def length_error_active(self) -> bool:
        return self.rpdo.length_error_active

    # -- life cycle ---------------------------------------------------------------
    def reset(self, node_id: int | None = None) -> None:
        """Reset communication: every parameter back to its default (for ``node_id``)."""
        if node_id is not None:
            self.node_id = node_id
        for pdo in self.tpdos + self.rpdos:
            d = pdo.default
            pdo.cob_id = d.cob_id(self.node_id)
            pdo.trans_type, pdo.inhibit, pdo.event_timer, pdo.sync_start = (
                d.trans_type,
                d.inhibit,
                d.event_timer,
                0,
            )
            pdo.map_entries = (list(d.entries) + [0] * MAX_ENTRIES)[:MAX_ENTRIES]
            pdo.map_count = len(d.entries)
            pdo.slots = self.mapping.compile(pdo, pdo.map_entries[: pdo.map_count])
            pdo.sample = None
            pdo.clear_runtime()
        self.operational = self.tpdo.operational = False
        self.rpdo.reset()
        self.tpdo.drop_queued()
        self._reindex()

    def set_operational(self, operational: bool, now: float) -> list[Frame]:
        with self._call(now):
            if operational and not self.operational:
                self.operational = True
                for pdo in self.rpdos:
                    pdo.clear_runtime()
                self.tpdo.start(now)
            elif not operational and self.operational:
                self.operational = False
                self.tpdo.stop()
                for pdo in self.rpdos:
                    pdo.clear_runtime()
        return self.take_frames()

    # -- inputs ---------------------------------------------------------------------
    def on_frame(self, can_id: int, data: bytes, now: float, rtr: bool = False) -> list[Frame]:
        with self._call(now):
            if self.operational:
                handled = self.tpdo.on_rtr(can_id) if rtr else self.rpdo.on_frame(can_id, data)
                if not handled:
                    self.counters.frames_ignored += 1
        return self.take_frames()

    def on_sync(self, now: float, counter: int | None = None) -> list[Frame]:
        with self._call(now):
            if self.operational:
                self.tpdo.on_sync(now, counter)
                self.rpdo.on_sync()
        return self.take_frames()

    def object_changed(self, index: int, sub: int, now: float) -> None:
        """An application event on (index, sub): queues the TPDOs that map it.

        Events are coalesced: inside an engine call they are handled when the call
        ends (one RPDO writing 8 DO bits that loop back gives one TPDO), outside they
        wait for the next :meth:`on_timer`, so a back updating several channels in one go
        also gives one TPDO. An event from outside is due at once on the engine's own
        clock: ``now`` comes from the caller's (the process image's), which may be ahead
        of the time the adapter runs the engine on (uvloop's loop time lags the monotonic
        clock by up to a millisecond), and must not hold the TPDO back until then.
        """
        if self._depth == 0:
            now = min(now, self.clock())
        if (
            self.tpdo.object_changed(index, sub, now)
            and self._depth == 0
            and self.wakeup is not None
        ):
            self.wakeup()

    def on_timer(self, now: float) -> list[Frame]:
        with self._call(now):
            if self.operational:
                self.tpdo.on_timer(now)
        return self.take_frames()

    def next_deadline(self) -> float | None:
        return self.tpdo.next_deadline() if self.operational else None

    def take_frames(self) -> list[Frame]:
        return self.tpdo.take_frames()

    def listen_ids(self) -> set[int]:
        """CAN identifiers the engine wants: valid RPDOs and RTR-enabled valid TPDOs."""
        return self.rpdo.listen_ids() | self.tpdo.listen_ids()

    def listens_to(self, can_id: int) -> bool:
        """``can_id in listen_ids()`` without building the set (once per received frame)."""
        return self.rpdo.listens_to(can_id) or self.tpdo.listens_to(can_id)

    # -- one engine call ------------------------------------------------------------
    class _CallGuard:
        def __init__(self, engine: PdoEngine):
            self.engine = engine

        def __enter__(self) -> None:
            self.engine._depth += 1

        def __exit__(self, *exc: object) -> bool:
            engine = self.engine
            if exc[0] is None and engine._depth == 1 and engine.tpdo.queued and engine.operational:
                try:
                    engine.tpdo.run_queued(engine._now)
                except Exception:
                    log.exception("PDO engine error (dropped)")
            engine._depth -= 1
            if exc[0] is not None and not isinstance(exc[1], (KeyboardInterrupt, SystemExit)):
                log.exception("PDO engine error (dropped)", exc_info=exc)  # type: ignore[arg-type]
                return True
            return False

    def _call(self, now: float) -> PdoEngine._CallGuard:
        if self._depth == 0:
            self._now = now
        return PdoEngine._CallGuard(self)

    def _reindex(self) -> None:
        self.tpdo.reindex()
        self.rpdo.reindex()

    # -- parameter objects and persistence ---------------------------------------------
    def objects(self) -> list[ObjectDef]:
        """The parameter objects of every PDO, bound to this engine."""
        result = []
        for pdo in self.rpdos + self.tpdos:
            result += [self.comm.comm_object(pdo), self.mapping.map_object(pdo, self._remapped)]
        return result

    def _remapped(self, pdo: Pdo) -> None:
        self._reindex()

    def parameters(self, keep_node_id: bool = False) -> list[list[Any]]:
        """The parameters of every PDO that differs from its default (``keep_node_id``: and of
        every PDO whose COB-ID counts from the node-ID), as plain data."""
        return self.comm.records(keep_node_id)

    def load_parameters(self, records: list[Any]) -> int:
        """Apply stored records (after a reset); a record that no longer fits is skipped. Returns how many applied."""
        return self.comm.load_records(records, self.mapping.compile)

    def status(self) -> dict[str, Any]:
        return {
            "operational": self.operational,
            "tpdo_valid": sum(p.valid for p in self.tpdos),
            "rpdo_valid": sum(p.valid for p in self.rpdos),
            "length_error": self.length_error_active,
            **self.counters.__dict__,
        }
