"""A fake device that behaves as CANopenNode's Linux device ``canopend`` did when the
conformance tool was first run against it (issue 31), on python-can's virtual bus.

It is :class:`TinySlave` plus what exposed each of the tool's defects then:

* block download with CRC offered (A4); a segment with a wrong sequence number is ignored and
  acknowledged with ackseq 0 only when the SDO timeout (0.7 s) runs out; frames on the SDO
  channel during a sub-block are segments (a client abort 0x80 too: seqno 0 is ignored), and a
  second timeout aborts (0504 0000) (defects 1 and 2); block upload with CRC;
* a heartbeat with the old state right after an NMT command, then one with the new (3);
* a heartbeat consumer (0x1016:1) and SYNC-loss supervision (0x1006 in Operational) whose
  EMCYs carry the error register 0x10 without the generic bit (8); reset communication
  clears their errors without an error-reset EMCY, and 0x1006 = 0 does not end a SYNC loss (4);
* ``boot_error``: EMCY 0x5000 after the boot-up, 0x1001 = 0x01, Start refused while 0x1001 ≠ 0 (5);
* LSS without the optional identify remote / non-configured slave services, with fastscan,
  configure bit timing dropped silently (6);
* vendor-ID 0, name "CANopenNode" (7); its EDS has ``VendorNumber=`` and ``ProductNumber=``
  empty, as CANopenNode's shipped DS301_profile.eds (9).

``generic_bit`` makes its error EMCYs carry the generic bit (0x11), to grade defect 4 alone.
"""

from __future__ import annotations

import struct
import time

from canopen.sdo.base import CrcXmodem
from conformance_slave import TinySlave, eds_text

NAME = b"CANopenNode"
SERIAL = 0x0000CAFE
OBJECTS = {
    (0x1000, 0): (4, "ro", 0, None, None),
    (0x1001, 0): (1, "ro", 0, None, None),
    (0x1005, 0): (4, "rw", 0x80, None, None),
    (0x1006, 0): (4, "rw", 0, None, None),
    (0x1008, 0): (None, "const", NAME, None, None),
    (0x1014, 0): (4, "rw", "$NODEID+0x80", None, None),
    (0x1016, 0): (1, "const", 1, None, None),
    (0x1016, 1): (4, "rw", 0, None, None),
    (0x1017, 0): (2, "rw", 0, None, None),
    (0x1018, 0): (1, "const", 4, None, None),
    (0x1018, 1): (4, "ro", 0, None, None),  # vendor-ID 0, as the demo
    (0x1018, 2): (4, "ro", 0, None, None),
    (0x1018, 3): (4, "ro", 0, None, None),
    (0x1018, 4): (4, "ro", SERIAL, None, None),
    (0x1400, 0): (1, "const", 2, None, None),
    (0x1400, 1): (4, "rw", "$NODEID+0x200", None, None),
    (0x1400, 2): (1, "rw", 255, None, None),
    (0x1600, 0): (1, "rw", 0, None, None),
    (0x1600, 1): (4, "rw", 0, None, None),
    (0x2000, 0): (2, "rw", 100, 10, 1000),
    (0x2001, 0): (4, "rw", 0, None, None),
}
DEVICE_INFO = [
    "VendorName=CANopenNode",
    "VendorNumber=",
    "ProductName=CANopenNode",
    "ProductNumber=",
    "RevisionNumber=0",
    "LSS_Supported=1",
]
LSS_TX, LSS_RX = 0x7E5, 0x7E4
UNCONFIGURED = 0xFF


def canopend_eds() -> str:
    return eds_text(OBJECTS, DEVICE_INFO)


class CanopendLike(TinySlave):
    objects = OBJECTS
    sdo_timeout = 0.7

    def __init__(self, channel: str, node_id: int = 5, faults: set[str] | None = None):
        super().__init__(channel, node_id, faults)
        self.block: dict | None = None
        self.lss_config = False
        self.pending_id: int | None = None
        self.fastscan_pos = 0
        self.consumer_seen: float | None = None
        self.consumer_error = False
        self.last_sync: float | None = None
        self.sync_error = False
        self.boot_error = False

    # -- boot, NMT, EMCY -------------------------------------------------------------------
    def _boot(self, comm_only: bool = False) -> None:
        self.block = None
        self.consumer_seen, self.consumer_error = None, False  # cleared without an EMCY (4)
        self.last_sync, self.sync_error = None, False
        if self.pending_id is not None:
            self.node_id, self.pending_id = self.pending_id, None
        if self.node_id == UNCONFIGURED:  # waits for LSS, sends nothing
            self.state, self.transfer = 0x7F, None
            return
        super()._boot(comm_only)
        if "boot_error" in self.faults:
            self.boot_error = True
            self._emcy(0x5000, 0x01)
        self._register()

    def _register(self) -> None:
        comm = self.consumer_error or self.sync_error
        value = (0x11 if comm else 0) | (0x01 if self.boot_error else 0)
        self.values[(0x1001, 0)] = bytes([value])

    def _emcy(self, code: int, register: int) -> None:
        cob = int.from_bytes(self.values[(0x1014, 0)], "little")
        if not cob & 0x80000000:
            self.send(cob & 0x7FF, struct.pack("<HB5x", code, register))

    def _error(self, code: int) -> None:
        self._emcy(code, 0x11 if "generic_bit" in self.faults else 0x10)  # (8)

    def _nmt(self, cs: int) -> None:
        if self.node_id == UNCONFIGURED:
            return
        new = {0x01: 0x05, 0x02: 0x04, 0x80: 0x7F}.get(cs)
        if new == 0x05 and self.values[(0x1001, 0)] != b"\x00":
            new = None  # CANopenNode: no Operational while the error register shows errors (5)
        if new is not None and self.next_heartbeat is not None and new != self.state:
            self.send(0x700 + self.node_id, bytes([self.state]))  # the old state first (3)
            self.state = new
            self.send(0x700 + self.node_id, bytes([self.state]))
            return
        super()._nmt(cs)

    # -- frames ------------------------------------------------------------------------------
    def _handle(self, msg) -> None:
        cob, data = msg.arbitration_id, bytes(msg.data)
        if cob == LSS_TX and len(data) == 8:
            return self._lss(data)
        if self.node_id == UNCONFIGURED:
            return
        watched = int.from_bytes(self.values[(0x1016, 1)], "little")
        if watched and cob == 0x700 + (watched >> 16) and data[:1] != b"\x00":
            self.consumer_seen = time.monotonic()
            if self.consumer_error:
                self.consumer_error = False
                self._register()
                self._emcy(0x0000, self.values[(0x1001, 0)][0])
        if (
            cob == (int.from_bytes(self.values[(0x1005, 0)], "little") & 0x7FF)
            and self.state == 0x05
        ):
            self.last_sync = time.monotonic()
            if self.sync_error:
                self.sync_error = False
                self._register()
                self._emcy(0x0000, self.values[(0x1001, 0)][0])
        if cob == 0x600 + self.node_id and len(data) == 8 and self.block is not None:
            return self._block(data)
        if cob == 0x700 + self.node_id and msg.is_remote_frame:
            return  # no node guarding (CANopenNode's default build)
        super()._handle(msg)

    def _timers(self) -> None:
        super()._timers()
        now = time.monotonic()
        watched = int.from_bytes(self.values[(0x1016, 1)], "little")
        limit = (watched & 0xFFFF) / 1000
        if watched and limit and self.consumer_seen is not None and not self.consumer_error:
            if now - self.consumer_seen > limit:
                self.consumer_error = True
                self._register()
                self._error(0x8130)
        period = int.from_bytes(self.values[(0x1006, 0)], "little") / 1e6
        if period and self.state == 0x05 and self.last_sync is not None and not self.sync_error:
            if now - self.last_sync > 1.5 * period:
                self.sync_error = True
                self._register()
                self._error(0x8100)
        if self.block is not None and now - self.block["activity"] > self.sdo_timeout:
            if self.block["kind"] == "down" and not self.block["acked"]:
                # the sub-block timer: acknowledge what came (ackseq), wait for the rest (2)
                self.block.update(acked=True, activity=now, seq=1)
                self._reply(bytes([0xA2, self.block["good"], 127]))
            else:
                self._abort(self.block["index"], self.block["sub"], 0x05040000)
                self.block = None

    def _store(self, index: int, sub: int, value: bytes, reply: bool = True) -> bool:
        number = int.from_bytes(value, "little")
        if index in (0x1005, 0x1014) and len(value) == 4:
            old = int.from_bytes(self.values[(index, 0)], "little")
            restricted = (number & 0x7FF) in range(0x601, 0x680) or (number & 0x7FF) in range(
                0x701, 0x780
            )
            moved = index == 0x1014 and not old & 0x80000000 and not number & 0x80000000
            if restricted or (moved and (number ^ old) & 0x7FF):
                self._abort(index, sub, 0x06090030)
                return False
        ok = super()._store(index, sub, value, reply)
        if ok and (index, sub) == (0x1016, 1) and not int.from_bytes(value, "little"):
            self.consumer_seen = None
            if self.consumer_error:
                self.consumer_error = False
                self._register()
                self._emcy(0x0000, self.values[(0x1001, 0)][0])
        if ok and index == 0x1006 and self.last_sync is None:
            self.last_sync = time.monotonic()
        return ok  # 0x1006 = 0 leaves a SYNC loss as it is (4)

    # -- SDO block transfers -------------------------------------------------------------------
    def _sdo(self, data: bytes) -> None:
        b0 = data[0]
        index, sub = struct.unpack_from("<HB", data, 1)
        if b0 & 0xF9 == 0xC0:  # block download initiate
            error = self._lookup(index, sub)
            if error:
                return self._abort(index, sub, error)
            self.block = dict(
                kind="down",
                index=index,
                sub=sub,
                crc=bool(b0 & 0x04),
                data=b"",
                seq=1,
                good=0,
                acked=False,
                last=False,
                activity=time.monotonic(),
            )
            return self._reply(bytes([0xA4]) + struct.pack("<HBB", index, sub, 127))
        if b0 & 0xFB == 0xA0:  # block upload initiate
            error = self._lookup(index, sub)
            if error:
                return self._abort(index, sub, error)
            if not 0 < data[4] <= 127:
                return self._abort(index, sub, 0x05040002)
            value = self.values[(index, sub)]
            self.block = dict(
                kind="up",
                index=index,
                sub=sub,
                crc=bool(b0 & 0x04),
                data=value,
                blksize=data[4],
                activity=time.monotonic(),
            )
            return self._reply(bytes([0xC6]) + struct.pack("<HBI", index, sub, len(value)))
        super()._sdo(data)

    def _block(self, data: bytes) -> None:
        block = self.block
        assert block is not None
        b0 = data[0]
        if block["kind"] == "up":
            if b0 == 0x80:
                self.block = None
            elif b0 == 0xA3:
                self._upload_sub_block()
            elif b0 == 0xA2:
                self._upload_end()
            elif b0 == 0xA1:
                self.block = None
            return
        if block["last"]:  # waiting for the end of the block download
            if b0 & 0xE3 != 0xC1:
                return
            n = (b0 >> 2) & 7
            payload = block["data"][: len(block["data"]) - n]
            if block["crc"]:
                crc = CrcXmodem()
                crc.process(payload)
                if crc.final() != struct.unpack_from("<H", data, 1)[0]:
                    self.block = None
                    return self._abort(block["index"], block["sub"], 0x05040004)
            self.block = None
            if self._store(block["index"], block["sub"], payload, reply=False):
                self._reply(bytes([0xA1]))
            return
        seq, last = b0 & 0x7F, bool(b0 & 0x80)
        if seq != block["seq"]:
            return  # ignored: a wrong sequence number is acknowledged at the timeout (2)
        block["data"] += data[1:8]
        block.update(good=seq, seq=seq + 1, activity=time.monotonic(), acked=False)
        if last or seq == 127:
            block.update(last=last, seq=1)
            self._reply(bytes([0xA2, seq, 127]))

    def _upload_sub_block(self) -> None:
        block = self.block
        assert block is not None
        rest = block["data"]
        chunks = [rest[i : i + 7] for i in range(0, max(len(rest), 1), 7)][: block["blksize"]]
        for seq, chunk in enumerate(chunks, 1):
            last = seq == len(chunks)
            self.send(
                0x580 + self.node_id, bytes([seq | (0x80 if last else 0)]) + chunk.ljust(7, b"\0")
            )
        block["n"] = 7 - len(chunks[-1])
        block["activity"] = time.monotonic()

    def _upload_end(self) -> None:
        block = self.block
        assert block is not None
        crc = CrcXmodem()
        crc.process(block["data"])
        value = crc.final() if block["crc"] else 0
        self._reply(bytes([0xC1 | block["n"] << 2]) + struct.pack("<H", value))
        block["activity"] = time.monotonic()

    # -- LSS (CiA 305) ---------------------------------------------------------------------------
    def _lss_answer(self, data: bytes) -> None:
        self.send(LSS_RX, data.ljust(8, b"\0"))

    def _lss(self, data: bytes) -> None:
        cs = data[0]
        ident = [int.from_bytes(self.values[(0x1018, s)], "little") for s in (1, 2, 3, 4)]
        if cs == 0x04:
            if (
                data[1] == 0
                and self.lss_config
                and self.node_id == UNCONFIGURED
                and self.pending_id
            ):
                self.lss_config = False
                self._boot()  # an unconfigured device takes its new node-ID at once
                return
            self.lss_config = data[1] == 1
        elif 0x40 <= cs <= 0x43:
            self._selective = getattr(self, "_selective", [])
            if cs == 0x40:
                self._selective = []
            self._selective.append(struct.unpack_from("<I", data, 1)[0])
            if cs == 0x43:
                if self._selective == ident:
                    self.lss_config = True
                    self._lss_answer(b"\x44")
                self._selective = []
        elif 0x5A <= cs <= 0x5D and self.lss_config:
            self._lss_answer(bytes([cs]) + struct.pack("<I", ident[cs - 0x5A]))
        elif cs == 0x5E and self.lss_config:
            self._lss_answer(bytes([0x5E, self.node_id]))
        elif cs == 0x11 and self.lss_config:
            new = data[1]
            if 1 <= new <= 127 or new == UNCONFIGURED:
                self.pending_id = new
                self._lss_answer(b"\x11\x00")
            else:
                self._lss_answer(b"\x11\x01")
        elif cs == 0x17 and self.lss_config:
            self._lss_answer(b"\x17\x01")
        elif cs == 0x51 and self.node_id == UNCONFIGURED and not self.lss_config:
            self._fastscan(data, ident)
        # 0x13 configure bit timing: dropped (a deviation of the device, issue 31)
        # 0x46-0x4B identify remote slave, 0x4C identify non-configured: optional, not offered

    def _fastscan(self, data: bytes, ident: list[int]) -> None:
        number, bit, sub, nxt = struct.unpack_from("<IBBB", data, 1)
        if bit == 0x80:
            self.fastscan_pos = 0
            return self._lss_answer(b"\x4f")
        if sub != self.fastscan_pos or bit > 31:
            return
        if (number ^ ident[sub]) >> bit:
            return
        self._lss_answer(b"\x4f")
        if bit == 0:
            self.fastscan_pos = nxt
            if sub == 3:
                self.lss_config = True
