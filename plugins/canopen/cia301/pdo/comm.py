"""PDO communication parameters (CiA 301 §7.4.8: 0x1400-, 0x1800-) and their 0x1010 records.

Write rules of CiA 301: a COB-ID changes only while the PDO is invalid (bit 31), is an
11-bit identifier outside the restricted ranges (:mod:`.cobid`) and no other valid PDO's;
reserved transmission types are refused (0609 0030: 241-251, and 252/253 for RPDOs); a
TPDO's inhibit time and SYNC start value change only while it is invalid. RPDOs have
sub 3/5 (inhibit time, event timer) only with ``rpdo_timing`` (the NA-9161 lists them).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from ..abort import VALUE_RANGE
from ..cobid import check_cob_id
from ..entries import UNSIGNED8, UNSIGNED16, UNSIGNED32, Abort, Entry, ObjectDef, count_entry
from .defaults import COB_INVALID
from .mapping import MAX_ENTRIES, Pdo, Slot

log = logging.getLogger("fieldgate.canopen.pdo")


class PdoCommParameters:
    """The communication parameter objects of every PDO (``pdos``: RPDOs and TPDOs).

    After a write, ``rearm(pdo)`` restarts its event timer and ``reindex()`` rebuilds the
    services' look-up tables; ``node_id()`` gives the node-ID the defaults count from.
    """

    def __init__(
        self,
        pdos: list[Pdo],
        node_id: Callable[[], int],
        rearm: Callable[[Pdo], None],
        reindex: Callable[[], None],
        *,
        rpdo_timing: bool = False,
    ):
        self.pdos = pdos
        self.node_id = node_id
        self.rearm = rearm
        self.reindex = reindex
        self.rpdo_timing = rpdo_timing

    # -- write rules ----------------------------------------------------------------------
    def _set_cob_id(self, pdo: Pdo, value: int) -> None:
        new_valid = not value & COB_INVALID
        can_id = check_cob_id(value, "PDO", in_use=new_valid)
        if pdo.valid and new_valid and value != pdo.cob_id:
            raise Abort(VALUE_RANGE, "the COB-ID of a valid PDO cannot change; set bit 31 first")
        if new_valid:
            clash = [p for p in self.pdos if p is not pdo and p.valid and p.can_id == can_id]
            if clash:
                raise Abort(VALUE_RANGE, f"COB-ID 0x{can_id:03X} is used by another PDO")
        was_valid = pdo.valid
        pdo.cob_id = value
        if was_valid != new_valid:
            pdo.clear_runtime()
            self.rearm(pdo)
        self.reindex()

    def _set_trans_type(self, pdo: Pdo, value: int) -> None:
        allowed = value <= 240 or value >= (252 if pdo.transmit else 254)
        if not allowed:
            raise Abort(
                VALUE_RANGE,
                f"transmission type {value} is not supported for a {'T' if pdo.transmit else 'R'}PDO",
            )
        pdo.trans_type = value
        pdo.clear_runtime()
        self.rearm(pdo)
        self.reindex()

    def _set_while_invalid(self, pdo: Pdo, attr: str, value: int) -> None:
        if pdo.valid and pdo.transmit:
            raise Abort(
                VALUE_RANGE, f"{attr.replace('_', ' ')} can change only while the PDO is invalid"
            )
        setattr(pdo, attr, value)
        pdo.clear_runtime()
        self.reindex()

    def _set_event_timer(self, pdo: Pdo, value: int) -> None:
        pdo.event_timer = value
        self.rearm(pdo)
        self.reindex()

    # -- objects ----------------------------------------------------------------------------
    def _cob_default(self, pdo: Pdo) -> tuple[int, str | None]:
        d = pdo.default
        if d.cob_base is None:
            return COB_INVALID, None
        if d.absolute:  # the topology's own CAN-ID: the same for every node-ID
            return d.cob_id(self.node_id()), None
        return d.cob_id(
            self.node_id()
        ), f"$NODEID+0x{d.cob_base | d.flags | (0 if d.valid else COB_INVALID):X}"

    def comm_object(self, pdo: Pdo) -> ObjectDef:
        """0x1400+n / 0x1800+n of ``pdo``."""
        cob, expr = self._cob_default(pdo)
        d = pdo.default
        kind = "Transmit" if pdo.transmit else "Receive"
        entries = [
            Entry(
                1,
                "COB-ID",
                UNSIGNED32,
                "rw",
                lambda: pdo.cob_id,
                lambda v: self._set_cob_id(pdo, v),
                default=cob,
                default_expr=expr,
            ),
            Entry(
                2,
                "Transmission type",
                UNSIGNED8,
                "rw",
                lambda: pdo.trans_type,
                lambda v: self._set_trans_type(pdo, v),
                default=d.trans_type,
            ),
        ]
        if pdo.transmit or self.rpdo_timing:
            entries += [
                Entry(
                    3,
                    "Inhibit time",
                    UNSIGNED16,
                    "rw",
                    lambda: pdo.inhibit,
                    lambda v: self._set_while_invalid(pdo, "inhibit", v),
                    default=d.inhibit,
                ),
                Entry(
                    5,
                    "Event timer",
                    UNSIGNED16,
                    "rw",
                    lambda: pdo.event_timer,
                    lambda v: self._set_event_timer(pdo, v),
                    default=d.event_timer,
                ),
            ]
        if pdo.transmit:
            entries.append(
                Entry(
                    6,
                    "SYNC start value",
                    UNSIGNED8,
                    "rw",
                    lambda: pdo.sync_start,
                    lambda v: self._set_while_invalid(pdo, "sync_start", v),
                    default=0,
                    high=240,
                )
            )
        highest = entries[-1].sub
        return ObjectDef(
            pdo.comm_index,
            f"{kind} PDO {pdo.number} communication parameter",
            "record",
            [count_entry(highest)] + entries,
        )

    # -- persistence (0x1010 store) ------------------------------------------------------
    def records(self, keep_node_id: bool = False) -> list[list[Any]]:
        """The parameters of every PDO that differs from its default, as plain data;
        ``keep_node_id``: also every PDO whose default COB-ID counts from the node-ID, so the
        stored COB-ID stays when the node-ID changes (the NA-9161, [AMBIG-24])."""
        records = []
        for pdo in self.pdos:
            record = [
                pdo.transmit,
                pdo.number,
                pdo.cob_id,
                pdo.trans_type,
                pdo.inhibit,
                pdo.event_timer,
                pdo.sync_start,
                pdo.map_count,
                list(pdo.map_entries),
            ]
            d = pdo.default
            default = [
                pdo.transmit,
                pdo.number,
                d.cob_id(self.node_id()),
                d.trans_type,
                d.inhibit,
                d.event_timer,
                0,
                len(d.entries),
                (list(d.entries) + [0] * MAX_ENTRIES)[:MAX_ENTRIES],
            ]
            relative = d.cob_base is not None and not d.absolute
            if record != default or (keep_node_id and relative):
                records.append(record)
        return records

    def load_records(
        self, records: list[Any], compile: Callable[[Pdo, list[int]], list[Slot]]
    ) -> int:
        """Apply stored records (after a reset); a record that no longer fits is skipped.
        Returns how many applied."""
        applied = 0
        by_key = {(p.transmit, p.number): p for p in self.pdos}
        for record in records:
            try:
                (
                    transmit,
                    number,
                    cob_id,
                    trans_type,
                    inhibit,
                    event_timer,
                    sync_start,
                    count,
                    entries,
                ) = record
                pdo = by_key[(bool(transmit), int(number))]
                entries = [int(e) for e in entries][:MAX_ENTRIES]
                slots = compile(pdo, entries[:count])
            except (Abort, KeyError, TypeError, ValueError):
                log.warning(
                    "stored PDO parameters %r do not fit this device; defaults kept", record
                )
                continue
            pdo.cob_id, pdo.trans_type, pdo.inhibit, pdo.event_timer, pdo.sync_start = (
                int(cob_id),
                int(trans_type),
                int(inhibit),
                int(event_timer),
                int(sync_start),
            )
            pdo.map_entries = entries + [0] * (MAX_ENTRIES - len(entries))
            pdo.map_count, pdo.slots, pdo.sample = int(count), slots, None
            pdo.clear_runtime()
            applied += 1
        self.reindex()
        return applied
