"""SDO server (CiA 301 §7.2.4): expedited, segmented and block transfers, both ways.

One transfer at a time, as CiA 301 defines for one SDO channel. Every answer is
computed from the object dictionary in the same call (no back-end waits). This class
serves the default channel 0x1200; each further channel (0x1201-0x127F, the front's
``sdo_servers`` option) is its own instance of the subclass in :mod:`.sdo_channel`.

Choices where CiA 301 leaves one (see docs/canopen.md):

* Frames with a DLC other than 8 and RTR frames on the request COB-ID are counted and
  dropped (CiA 301 SDO frames always carry 8 bytes).
* A new initiate request (download, upload, block) while a transfer is open ends the
  open transfer without an abort frame and is served (the client evidently gave up
  on it). During a block download sub-block every frame is a segment, so there it is
  read as a segment.
* Block transfers use CRC-16-CCITT (polynomial 0x1021, initial value 0) when the
  client asks for it (cc = 1); the server answers sc = cc, so a client without CRC
  gets exactly the I-7232D's frames.
* Block upload with a protocol switch threshold (pst > 0) and a value of at most pst
  bytes is answered as a normal upload (expedited or segmented initiate response).
* Block download end with an ``n`` that does not match the object's size is refused
  with 0607 0012 / 0607 0013 like any other wrong length (the I-7232D's TV-05 ``D5``
  for a 1-byte object is therefore aborted).
* Server-side timeout (default 1 s): an open transfer with no client frame for that
  long is aborted with 0504 0000.
* An access the dictionary defers (:class:`~.abort.Deferred`: a hook of an EDS device at
  work, :mod:`..device.hooks`) holds its answer: the server keeps the request and its
  state as they were before it, answers nothing, and replays the request when
  :meth:`SdoServer.resolve` gets its ticket (the hook's outcome is then ready), or aborts
  with the Deferred's code at its timeout. Any other frame from the client meanwhile ends
  the wait (the client gave up) and is served as usual.
"""

from __future__ import annotations

import logging
import struct
from collections import Counter
from typing import Any

from canopen.objectdictionary import datatypes as dt
from canopen.objectdictionary.datatypes import UNSIGNED_TYPES

from fieldgate.can.frame import Frame

from . import abort
from .abort import Deferred, SdoAbort
from .nmt import NmtState
from .od import Dictionary, size_of
from .sdo_transfer import MAX_BLOCK_SIZE, Phase, SdoTransfer, crc16
from .service import QUIET, NodeHost, Taken

__all__ = ["MAX_BLOCK_SIZE", "Phase", "SdoServer", "crc16"]

EXPEDITED_UPLOAD = struct.Struct("<BHB4s")  # command, index, sub-index, data zero-padded to 4 bytes

log = logging.getLogger("fieldgate.canopen.sdo")

DEFAULT_TIMEOUT_S = 1.0


_TRANSFER_STATE = frozenset(
    {
        "phase",
        "index",
        "subindex",
        "data",
        "pos",
        "toggle",
        "size",
        "crc",
        "blksize",
        "seqno",
        "block_start",
    }
)


class SdoServer(SdoTransfer):
    name = "sdo"

    rx_cob: int | None  # the request COB-ID; None (a channel that is not valid): no frame

    def __init__(
        self,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        block_size: int = MAX_BLOCK_SIZE,
        zero_extend: bool = False,
    ):
        super().__init__()
        if not 1 <= block_size <= MAX_BLOCK_SIZE:
            raise ValueError("SDO block size must be 1..127")
        self.timeout_s = timeout_s
        self.block_size = block_size
        self.zero_extend = (
            zero_extend  # accept short expedited writes to unsigned objects (NA-9161 masters)
        )
        self.expedited_uploads = 0
        self._waiting: tuple[Deferred, Frame] | None = None
        self._idle()

    def attach(self, node: NodeHost) -> None:
        super().attach(node)
        self._add_parameter_object(node.od)
        self._load_cob_ids()

    def _add_parameter_object(self, od: Dictionary) -> None:
        """0x1200, the default channel; further channels (0x1201-0x127F) are :class:`.sdo_channel.SdoChannel`."""
        od.add_record(
            0x1200,
            "SDO server parameter",
            [
                (1, "COB-ID client to server", dt.UNSIGNED32, "ro", 0x600, {"relative": True}),
                (2, "COB-ID server to client", dt.UNSIGNED32, "ro", 0x580, {"relative": True}),
            ],
        )

    def _load_cob_ids(self) -> None:
        """0x1200 is read-only: its COB-IDs change only with the node-ID (reset communication)."""
        self.rx_cob = self.node.od.integer(0x1200, 1) & 0x7FF
        self.tx_cob = self.node.od.integer(0x1200, 2) & 0x7FF

    def deadline(self) -> float | None:
        if self._waiting is not None:
            return self.last_deadline
        return self.last_deadline if self.phase is not Phase.IDLE else None

    def poll(self, now: float) -> None:
        waiting = self._waiting
        if waiting is not None:
            if self.last_deadline is not None and now >= self.last_deadline:
                self._waiting = None
                self.counters["deferred_timeouts"] += 1
                wait = waiting[0]
                self._idle()
                self._send(b"\x80" + struct.pack("<HBI", wait.index, wait.subindex, wait.code))
            return
        if (
            self.phase is not Phase.IDLE
            and self.last_deadline is not None
            and now >= self.last_deadline
        ):
            self.counters["timeouts"] += 1
            self._abort(abort.TIMEOUT)

    def on_nmt_state(self, old: NmtState, new: NmtState, now: float) -> None:
        if new not in self.active_states and self.phase is not Phase.IDLE:  # Stopped, reset
            self.counters["dropped_by_state"] += 1
            self._idle()

    def on_reset_communication(self, now: float) -> None:
        self._waiting = None
        self._idle()
        self._load_cob_ids()

    # -- deferred answers ----------------------------------------------------------------
    def resolve(self, ticket: int, now: float) -> bool:
        """The outcome of deferred access ``ticket`` is ready: replay the request that waits
        on it (answered now from that outcome). False: no request of this channel waits on it."""
        waiting = self._waiting
        if waiting is None or waiting[0].ticket != ticket:
            return False
        self._waiting = None
        self.on_frame(waiting[1], now)
        return True

    def _state(self) -> dict[str, Any]:
        state = {k: v for k, v in vars(self).items() if k in _TRANSFER_STATE}
        state["data"] = bytearray(self.data)
        return state

    # -- frames ---------------------------------------------------------------------------
    def listen_ids(self) -> tuple[int, ...]:
        return () if self.rx_cob is None else (self.rx_cob,)

    def on_frame(self, frame: Frame, now: float) -> Taken:
        if frame.can_id != self.rx_cob:
            return False
        if frame.rtr:
            self.counters["rtr_dropped"] += 1
            return True
        if len(frame.data) != 8:
            self.counters["bad_dlc_dropped"] += 1
            return True
        if self.node.od.defers:
            return self._deferrable(frame, now)
        if frame.data[0] == 0x40 and self.phase is Phase.IDLE:
            answer = self._expedited_upload(frame.data)
            if answer is not None:
                self.expedited_uploads += 1  # a request and a transfer; status() adds them in
                self.node.send(answer)
                return QUIET
        self.counters["requests"] += 1
        self.last_deadline = now + self.timeout_s
        try:
            self._dispatch(bytes(frame.data))
        except SdoAbort as exc:
            self.counters["aborts"] += 1
            self._abort(exc.code)
        except (
            Exception
        ):  # a bug behind the dictionary (getter, setter, listener): answer, log, go on
            self.counters["internal_errors"] += 1
            log.exception("%s: SDO request %s failed", self.node.name, frame)
            self._abort(abort.GENERAL)
        return True

    def _deferrable(self, frame: Frame, now: float) -> Taken:
        """:meth:`on_frame` for a dictionary whose accesses may be deferred."""
        if self._waiting is not None:  # the client gave up waiting and sent something else
            self.counters["deferred_dropped"] += 1
            self._waiting = None
        saved = self._state()
        self.counters["requests"] += 1
        self.last_deadline = now + self.timeout_s
        try:
            self._dispatch(bytes(frame.data))
        except Deferred as wait:
            for key, value in saved.items():
                setattr(self, key, value)
            self.last_deadline = now + wait.timeout_s
            self._waiting = (wait, frame)
            self.counters["deferred"] += 1
        except SdoAbort as exc:
            self.counters["aborts"] += 1
            self._abort(exc.code)
        except Exception:
            self.counters["internal_errors"] += 1
            log.exception("%s: SDO request %s failed", self.node.name, frame)
            self._abort(abort.GENERAL)
        return True

    def _dispatch(self, d: bytes) -> None:
        ccs = d[0] >> 5
        phase = self.phase
        if phase is Phase.BLOCK_DOWN and d[0] != 0x80:  # segments; 0x80 (seqno 0) is an abort
            self._block_download_segment(d)
            return
        if ccs == 4:  # abort from the client
            self.counters["client_aborts"] += 1
            self._idle()
            return
        if ccs == 1:
            self._initiate_download(d)
        elif ccs == 2:
            self._initiate_upload(d)
        elif ccs == 5 and d[0] & 0x03 == 0:
            self._initiate_block_upload(d)
        elif ccs == 6 and d[0] & 0x01 == 0:
            self._initiate_block_download(d)
        elif ccs == 3 and phase is Phase.UPLOAD:
            self._upload_segment(d)
        elif ccs == 0 and phase is Phase.DOWNLOAD:
            self._download_segment(d)
        elif ccs == 5 and phase in (Phase.BLOCK_UP_START, Phase.BLOCK_UP_ACK, Phase.BLOCK_UP_END):
            self._block_upload_client(d)
        elif ccs == 6 and phase is Phase.BLOCK_DOWN_END:
            self._block_download_end(d)
        else:
            raise SdoAbort(abort.BAD_COMMAND)

    # -- expedited / segmented download ------------------------------------------------
    def _initiate_download(self, d: bytes) -> None:
        self._begin(d, Phase.IDLE)
        od = self.node.od
        expedited, sized = d[0] & 0x02, d[0] & 0x01
        if expedited:
            if sized:
                data = d[4 : 8 - ((d[0] >> 2) & 0x03)]
                if self.zero_extend:
                    data = self._zero_extended(data)
            else:  # size not indicated: the object's own size (CiA 301 allows it)
                var = od.check_download(self.index, self.subindex)
                data = d[4 : 4 + min(4, size_of(var) or 4)]
            od.write(self.index, self.subindex, data)
            self._send(b"\x60" + self._mux())
            self._done()
            return
        self.size = struct.unpack_from("<I", d, 4)[0] if sized else None
        od.check_download(self.index, self.subindex, self.size)
        self.phase = Phase.DOWNLOAD
        self._send(b"\x60" + self._mux())

    def _zero_extended(self, data: bytes) -> bytes:
        var = self.node.od.check_download(self.index, self.subindex)
        size = size_of(var)
        # the NA-9161 manual's form: a 2-byte (or longer) write to a wider unsigned entry
        if size is not None and 2 <= len(data) < size and var.data_type in UNSIGNED_TYPES:
            self.counters["zero_extended_writes"] += 1
            return data.ljust(size, b"\x00")
        return data

    def _download_segment(self, d: bytes) -> None:
        toggle = (d[0] >> 4) & 1
        if toggle != self.toggle:
            raise SdoAbort(abort.TOGGLE)
        self.data += d[1 : 8 - ((d[0] >> 1) & 0x07)]
        if self.size is not None and len(self.data) > self.size:
            raise SdoAbort(abort.LENGTH_MISMATCH)
        if d[0] & 0x01:
            if self.size is not None and len(self.data) != self.size:
                raise SdoAbort(abort.LENGTH_MISMATCH)
            self.node.od.write(self.index, self.subindex, bytes(self.data))
            self._send(bytes([0x20 | (toggle << 4)]))
            self._done()
            return
        self._send(bytes([0x20 | (toggle << 4)]))
        self.toggle ^= 1

    # -- expedited / segmented upload ----------------------------------------------------
    def answer_read(self, data: bytes | bytearray) -> Frame | None:
        """An expedited upload outside a transfer, answered from the CAN receive thread (see :class:`.service.Service`)."""
        if len(data) != 8 or data[0] != 0x40 or self.phase is not Phase.IDLE:
            return None
        index, subindex = data[1] | (data[2] << 8), data[3]
        value = self.node.od.read_quick(index, subindex)  # None: not from this thread, or an abort
        if value is None or not 0 < len(value) <= 4:
            return None
        self.expedited_uploads += 1
        return self._expedited_frame(index, subindex, value)

    def _expedited_upload(self, d: bytes | bytearray) -> Frame | None:
        """The answer to an upload request outside a transfer for a value of 1 to 4 bytes.

        The most frequent request there is (a master reading a value). It leaves the
        transfer state and every timer as they were; anything else (a longer value, an
        abort) gives None and takes the general path, which reads again and answers.
        """
        index, subindex = d[1] | (d[2] << 8), d[3]
        try:
            value = self.node.od.read(index, subindex)
        except SdoAbort:
            return None
        return self._expedited_frame(index, subindex, value) if 0 < len(value) <= 4 else None

    def _expedited_frame(self, index: int, subindex: int, value: bytes) -> Frame:
        return Frame(
            self.tx_cob,
            EXPEDITED_UPLOAD.pack(0x43 | ((4 - len(value)) << 2), index, subindex, value),
        )

    def _initiate_upload(self, d: bytes) -> None:
        self._begin(d, Phase.IDLE)
        self._answer_upload(self.node.od.read(self.index, self.subindex))

    def _answer_upload(self, value: bytes) -> None:
        if 0 < len(value) <= 4:  # expedited: nothing of the transfer state was touched
            self.node.send(self._expedited_frame(self.index, self.subindex, value))
            self.counters["transfers"] += 1
            self.index = self.subindex = 0
            return
        self.data = bytearray(value)
        self.phase = Phase.UPLOAD
        self._send(b"\x41" + self._mux() + struct.pack("<I", len(value)))

    def _upload_segment(self, d: bytes) -> None:
        toggle = (d[0] >> 4) & 1
        if toggle != self.toggle:
            raise SdoAbort(abort.TOGGLE)
        chunk = bytes(self.data[self.pos : self.pos + 7])
        self.pos += len(chunk)
        last = self.pos >= len(self.data)
        n = 7 - len(chunk)
        self._send(bytes([(toggle << 4) | (n << 1) | int(last)]) + chunk)
        if last:
            self._done()
        else:
            self.toggle ^= 1

    def status(self) -> dict[str, Any]:
        counts = Counter(self.counters)
        counts.update(requests=self.expedited_uploads, transfers=self.expedited_uploads)
        return {**counts, "phase": self.phase.name.lower()}
