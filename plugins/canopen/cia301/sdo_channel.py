"""Additional SDO server channels: 0x1201-0x127F (CiA 301 §7.4.8, §7.5.2.35).

Each channel is its own :class:`SdoChannel`, a node service beside the default
server (0x1200): one transfer at a time per channel, its own state and timeout, its
COB-IDs from its own parameter object:

* sub 1 COB-ID client -> server, sub 2 COB-ID server -> client (U32, rw), default
  0x80000000: bit 31 set = "not valid". The channel serves requests only while both
  are valid. Bit 30 (dynamic allocation, CiA 302) is kept as written and changes
  nothing here; bit 29 (29-bit frames) and bits 11-28 abort 0609 0030.
* A valid COB-ID's CAN-ID cannot change: set bit 31 first (else 0609 0030). A valid
  COB-ID with a restricted CAN-ID (:mod:`.cobid`), or one that another SDO channel of
  this node already uses, aborts 0609 0030.
* sub 3 node-ID of the SDO client (U8, rw, 0..127; 0 = not set): informational.
* The parameters live in the communication area: 0x1010 sub 1/2 store them, reset
  communication reloads them (stored, else invalid).
* A change takes effect after the answer to the write that made it (a client that
  switches off its own channel gets its confirmation on the old COB-ID). A transfer
  open on a channel whose COB-IDs change ends without an abort frame (counted as
  ``ended_by_cob_id_change``).
"""

from __future__ import annotations

from typing import Any

from canopen.objectdictionary import datatypes as dt

from fieldgate.can.frame import Frame

from . import abort
from .abort import SdoAbort
from .cobid import check_cob_id
from .od import Dictionary
from .sdo import DEFAULT_TIMEOUT_S, MAX_BLOCK_SIZE, Phase, SdoServer
from .service import Taken

NOT_VALID = 1 << 31
FIRST_INDEX, LAST_INDEX = 0x1201, 0x127F
MAX_SERVERS = 1 + LAST_INDEX - FIRST_INDEX + 1  # 0x1200 plus 127 more


def channel_indices(servers: int) -> range:
    """The parameter objects of the extra channels for ``servers`` SDO servers in all (1..128)."""
    if not 1 <= servers <= MAX_SERVERS:
        raise ValueError(f"SDO servers must be 1..{MAX_SERVERS}")
    return range(FIRST_INDEX, FIRST_INDEX + servers - 1)


class SdoChannel(SdoServer):
    """An SDO server on the COB-IDs of one 0x1201-0x127F parameter object (see module doc)."""

    def __init__(
        self,
        parameter_index: int,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        block_size: int = MAX_BLOCK_SIZE,
        zero_extend: bool = False,
    ):
        if not FIRST_INDEX <= parameter_index <= LAST_INDEX:
            raise ValueError(
                f"SDO server parameter index must be 0x{FIRST_INDEX:04X}..0x{LAST_INDEX:04X}"
            )
        self.parameter_index = parameter_index
        self.name = f"sdo_{parameter_index:04X}"
        self._in_frame = False
        self._reload_pending = False
        super().__init__(timeout_s, block_size, zero_extend)

    def _add_parameter_object(self, od: Dictionary) -> None:
        index = self.parameter_index
        od.add_record(
            index,
            "SDO server parameter",
            [
                (1, "COB-ID client to server", dt.UNSIGNED32, "rw", NOT_VALID),
                (2, "COB-ID server to client", dt.UNSIGNED32, "rw", NOT_VALID),
                (3, "Node-ID of the SDO client", dt.UNSIGNED8, "rw", 0, {"maximum": 127}),
            ],
        )
        od.add_validator(index, self._check)
        od.on_write(index, self._written)

    def _cob_ids(self) -> tuple[int, int]:
        od, index = self.node.od, self.parameter_index
        return od.integer(index, 1), od.integer(index, 2)

    def _load_cob_ids(self) -> None:
        rx, tx = self._cob_ids()
        valid = not (rx | tx) & NOT_VALID
        self.rx_cob = rx & 0x7FF if valid else None  # None matches no frame
        self.tx_cob = tx & 0x7FF  # (used only for an answer: never while rx_cob is None)

    @property
    def valid(self) -> bool:
        return self.rx_cob is not None

    # -- frames: COB-ID changes take effect after the answer -------------------------------
    def on_frame(self, frame: Frame, now: float) -> Taken:
        if frame.can_id != self.rx_cob:
            return False
        self._in_frame = True
        try:
            return super().on_frame(frame, now)
        finally:
            self._in_frame = False
            if self._reload_pending:
                self._reload_pending = False
                self._reload()

    def _written(self, index: int, sub: int, value: int) -> None:
        if sub not in (1, 2):
            return
        if self._in_frame:
            self._reload_pending = True
        else:
            self._reload()

    def _reload(self) -> None:
        before = (self.rx_cob, self.tx_cob)
        self._load_cob_ids()
        if (self.rx_cob, self.tx_cob) != before and self.phase is not Phase.IDLE:
            self.counters["ended_by_cob_id_change"] += 1
            self._idle()

    # -- write checks ----------------------------------------------------------------------
    def _check(self, sub: int, value: int) -> None:
        if sub not in (1, 2):
            return
        valid = not value & NOT_VALID
        can_id = check_cob_id(value, "SDO", in_use=valid)
        if not valid:
            return
        old = self.node.od.integer(self.parameter_index, sub)
        if not old & NOT_VALID and (old & 0x7FF) != can_id:
            raise SdoAbort(
                abort.VALUE_RANGE,
                f"0x{self.parameter_index:04X}:{sub} is valid: set bit 31 before changing its CAN-ID",
            )
        if can_id in self._can_ids_in_use(except_sub=sub):
            raise SdoAbort(
                abort.VALUE_RANGE, f"CAN-ID 0x{can_id:03X} is already used by an SDO channel"
            )

    def _can_ids_in_use(self, except_sub: int) -> set[int]:
        """The valid CAN-IDs of every SDO channel of the node, but this channel's ``except_sub``."""
        used: set[int] = set()
        for service in self.node.services:
            if isinstance(service, SdoChannel):
                for sub, cob in enumerate(service._cob_ids(), start=1):
                    if not cob & NOT_VALID and not (service is self and sub == except_sub):
                        used.add(cob & 0x7FF)
            elif isinstance(service, SdoServer):
                used.update(c for c in (service.rx_cob, service.tx_cob) if c is not None)
        return used

    def status(self) -> dict[str, Any]:
        rx, tx = self._cob_ids()
        return {**super().status(), "cob_id_rx": rx, "cob_id_tx": tx, "valid": self.valid}
