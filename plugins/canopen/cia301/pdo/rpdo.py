"""Receive PDOs (CiA 301 §7.2.2): RPDO data to the mapped objects, sans-I/O.

RPDOs of transmission types 0-240 are latched and applied at the next SYNC, 254/255 at
once. An RPDO shorter than its mapping is ignored and reported through
``length_error(True)`` (EMCY 0x8210); the next good one reports ``length_error(False)``.
Longer RPDOs use their first bytes. A mapped entry that refuses its value (its setter
aborts) is counted in ``rpdo_write_refused`` and the other entries are still written.

One RPDO's entries, and at a SYNC the entries of every RPDO latched for it, are written
inside one ``directory.batch()``: the CiA 401 objects turn them into one process-image
batch (:meth:`fieldgate.image.ProcessImage.write_outputs`), so subscribers (the back's
write-on-change, a loopback, Sparkplug) hear of a message once, not once per bit.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from ..entries import Abort
from .mapping import Pdo, PdoCounters, PdoMapping, sync_type

log = logging.getLogger("fieldgate.canopen.pdo")


def _number(pdo: Pdo) -> int:
    return pdo.number


class RpdoService:
    """The RPDOs of one node: reception, length check, latching, application."""

    def __init__(
        self,
        pdos: list[Pdo],
        mapping: PdoMapping,
        counters: PdoCounters,
        length_error: Callable[[bool], None] | None = None,
    ):
        self.pdos = pdos
        self.mapping = mapping
        self.counters = counters
        self.length_error = length_error
        self.length_error_active = False
        self._rx: dict[int, Pdo] = {}
        self._latched: list[Pdo] = []  # RPDOs that latched data since the last SYNC

    def reindex(self) -> None:
        self._rx = {p.can_id: p for p in self.pdos if p.valid}

    def reset(self) -> None:
        self.length_error_active = False
        self._latched = []

    def listens_to(self, can_id: int) -> bool:
        return can_id in self._rx

    def listen_ids(self) -> set[int]:
        return set(self._rx)

    def on_frame(self, can_id: int, data: bytes) -> bool:
        """An RPDO's data; False when no valid RPDO has this COB-ID."""
        pdo = self._rx.get(can_id)
        if pdo is None:
            return False
        self._receive(pdo, bytes(data))
        return True

    def on_sync(self) -> None:
        """Apply what synchronous RPDOs latched since the last SYNC, in RPDO order, as one
        batch."""
        latched, self._latched = self._latched, []
        if not latched:
            return
        if len(latched) > 1:
            latched.sort(key=_number)
        with self.mapping.directory.batch():
            for pdo in latched:
                data, pdo.latched = pdo.latched, None
                if data is not None:  # (None: dropped by a reset or an NMT state change since)
                    self._apply(pdo, data)

    def _receive(self, pdo: Pdo, data: bytes) -> None:
        self.counters.rpdo_received += 1
        if len(data) < pdo.length:
            self.counters.rpdo_too_short += 1
            if not self.length_error_active:
                self.length_error_active = True
                if self.length_error is not None:
                    self.length_error(True)
            return
        if self.length_error_active:
            self.length_error_active = False
            if self.length_error is not None:
                self.length_error(False)
        payload = data[: pdo.length]
        if sync_type(pdo.trans_type):
            if pdo.latched is None:
                self._latched.append(pdo)
            pdo.latched = payload
        else:
            self._apply(pdo, payload)

    def _apply(self, pdo: Pdo, payload: bytes) -> None:
        with self.mapping.directory.batch():
            for slot, entry, value in self.mapping.unpack(pdo, payload):
                try:
                    entry.store(value)
                except Abort as exc:
                    self.counters.rpdo_write_refused += 1
                    log.debug(
                        "RPDO%d: 0x%04X:%d refused: %s", pdo.number, slot.index, slot.sub, exc
                    )
