"""What an SDO server channel holds of a transfer, and the block protocol (CiA 301 7.2.4.3.9
to 7.2.4.3.16): :class:`SdoTransfer` is the base of :class:`.sdo.SdoServer`, which adds the
expedited and segmented transfers, deferred answers and the frame dispatch."""

from __future__ import annotations

import binascii
import struct
from enum import Enum, auto

from fieldgate.can.frame import Frame

from . import abort
from .abort import SdoAbort
from .service import Service

MAX_BLOCK_SIZE = 127


def crc16(data: bytes) -> int:
    """CRC-16-CCITT as CiA 301 block transfers use it (poly 0x1021, init 0)."""
    return binascii.crc_hqx(data, 0)


class Phase(Enum):
    IDLE = auto()
    UPLOAD = auto()  # segmented upload, waiting for a segment request
    DOWNLOAD = auto()  # segmented download, waiting for a segment
    BLOCK_UP_START = auto()  # block upload initiated, waiting for "start upload"
    BLOCK_UP_ACK = auto()  # a sub-block was sent, waiting for its acknowledge
    BLOCK_UP_END = auto()  # end sent, waiting for the client's end response
    BLOCK_DOWN = auto()  # receiving sub-block segments
    BLOCK_DOWN_END = auto()  # last segment received, waiting for the end request


class SdoTransfer(Service):
    """The state of the transfer in progress and the block transfers."""

    tx_cob: int  # the answer COB-ID
    block_size: int  # the block size this server asks for in a block download

    # -- state ---------------------------------------------------------------------------
    def _idle(self) -> None:
        self.phase = Phase.IDLE
        self.index = 0
        self.subindex = 0
        self.data = bytearray()
        self.pos = 0
        self.toggle = 0
        self.size: int | None = None
        self.crc = False
        self.blksize = self.block_size
        self.seqno = 0
        self.block_start = 0
        self.last_deadline: float | None = None

    def _begin(self, d: bytes, phase: Phase) -> None:
        if self.phase is not Phase.IDLE:
            self.counters["superseded"] += 1
            deadline = self.last_deadline
            self._idle()
            self.last_deadline = deadline
        self.index = d[1] | (d[2] << 8)
        self.subindex = d[3]
        self.phase = phase

    def _mux(self) -> bytes:
        return struct.pack("<HB", self.index, self.subindex)

    def _send(self, data: bytes) -> None:
        self.node.send(Frame(self.tx_cob, data.ljust(8, b"\x00")))

    def _abort(self, code: int) -> None:
        self._send(b"\x80" + self._mux() + struct.pack("<I", code))
        self._idle()

    def _done(self) -> None:
        self.counters["transfers"] += 1
        self._idle()

    def _answer_upload(self, value: bytes) -> None:
        """Answer an upload expedited or segmented (:class:`.sdo.SdoServer`): a block upload
        of a short value switches to it (the client's protocol switch threshold)."""
        raise NotImplementedError

    # -- block upload ------------------------------------------------------------------
    def _initiate_block_upload(self, d: bytes) -> None:
        self._begin(d, Phase.IDLE)
        blksize, pst = d[4], d[5]
        if not 1 <= blksize <= MAX_BLOCK_SIZE:
            raise SdoAbort(abort.BAD_BLOCK_SIZE)
        value = self.node.od.read(self.index, self.subindex)
        if pst and len(value) <= pst:
            self.counters["block_protocol_switch"] += 1
            self._answer_upload(value)
            return
        self.data = bytearray(value)
        self.crc = bool(d[0] & 0x04)
        self.blksize = blksize
        self.phase = Phase.BLOCK_UP_START
        self._send(
            bytes([0xC2 | (int(self.crc) << 2)]) + self._mux() + struct.pack("<I", len(value))
        )

    def _block_upload_client(self, d: bytes) -> None:
        cs = d[0] & 0x03
        if cs == 3 and self.phase is Phase.BLOCK_UP_START:
            self._send_sub_block()
        elif cs == 2 and self.phase is Phase.BLOCK_UP_ACK:
            self._block_upload_ack(d[1], d[2])
        elif cs == 1 and self.phase is Phase.BLOCK_UP_END:
            self._done()
        else:
            raise SdoAbort(abort.BAD_COMMAND)

    def _send_sub_block(self) -> None:
        self.block_start = self.pos
        seq = 0
        while seq < self.blksize:
            seq += 1
            chunk = bytes(self.data[self.pos : self.pos + 7])
            self.pos += 7
            last = self.pos >= len(self.data)
            self._send(bytes([seq | (0x80 if last else 0)]) + chunk)
            if last:
                break
        self.seqno = seq
        self.phase = Phase.BLOCK_UP_ACK

    def _block_upload_ack(self, ackseq: int, blksize: int) -> None:
        if ackseq > self.seqno:
            raise SdoAbort(abort.BAD_SEQUENCE)
        if not 1 <= blksize <= MAX_BLOCK_SIZE:
            raise SdoAbort(abort.BAD_BLOCK_SIZE)
        self.pos = self.block_start + 7 * ackseq
        self.blksize = blksize
        if self.pos < len(self.data):
            self._send_sub_block()
            return
        last = len(self.data) % 7 or (7 if self.data else 0)
        n = 7 - last
        crc = crc16(bytes(self.data)) if self.crc else 0
        self.phase = Phase.BLOCK_UP_END
        self._send(bytes([0xC1 | (n << 2)]) + struct.pack("<H", crc))

    # -- block download --------------------------------------------------------------------
    def _initiate_block_download(self, d: bytes) -> None:
        self._begin(d, Phase.IDLE)
        self.size = struct.unpack_from("<I", d, 4)[0] if d[0] & 0x02 else None
        self.node.od.check_download(self.index, self.subindex, self.size)
        self.crc = bool(d[0] & 0x04)
        self.blksize = self.block_size
        self.seqno = 0
        self.phase = Phase.BLOCK_DOWN
        self._send(bytes([0xA0 | (int(self.crc) << 2)]) + self._mux() + bytes([self.blksize]))

    def _block_download_segment(self, d: bytes) -> None:
        seq, last = d[0] & 0x7F, bool(d[0] & 0x80)
        if seq == 0 or seq > self.blksize:
            raise SdoAbort(abort.BAD_SEQUENCE)
        in_order = seq == self.seqno + 1
        if in_order:
            self.seqno = seq
            self.data += d[1:8]
            if self.size is not None and len(self.data) > self.size + 6:
                raise SdoAbort(abort.LENGTH_TOO_HIGH)
        else:  # a segment was lost: ignore the rest, acknowledge short at the block end
            self.counters["block_segments_out_of_order"] += 1
        if last or seq == self.blksize:
            self._send(bytes([0xA2, self.seqno, self.blksize]))
            self.seqno = 0
            if last and in_order:
                self.phase = Phase.BLOCK_DOWN_END

    def _block_download_end(self, d: bytes) -> None:
        if d[0] & 0x03 != 1:
            raise SdoAbort(abort.BAD_COMMAND)
        n = (d[0] >> 2) & 0x07
        data = bytes(self.data[: len(self.data) - n])
        if self.size is not None and len(data) != self.size:
            raise SdoAbort(abort.LENGTH_MISMATCH)
        if self.crc and crc16(data) != struct.unpack_from("<H", d, 1)[0]:
            raise SdoAbort(abort.CRC_ERROR)
        self.node.od.write(self.index, self.subindex, data)
        self._send(b"\xa1")
        self._done()
