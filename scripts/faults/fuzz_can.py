"""Fuzz targets of the CAN wires: the CANopen front's node (SDO, NMT/LSS, PDO,
SYNC/TIME/EMCY) and the DeviceNet front's slave, as ``fieldgate run`` builds them."""

from __future__ import annotations

import struct
from collections.abc import Sequence

from fuzz_base import NODE, Bytes, InvariantBroken, Target, one_front

from fieldgate import Gateway
from fieldgate.can.frame import Frame


class CanopenTarget(Target):
    """The CANopen front's node (CiA 301/401, LSS) as ``fieldgate run`` builds it."""

    ids: Sequence[int] = ()

    def setup(self) -> None:
        from fieldgate.plugins.canopen.plugin import CanopenFront

        topo = one_front(
            self.work_dir,
            {
                "name": "plc",
                "type": "canopen",
                "node_id": NODE,
                "heartbeat_consumers": 2,
                "identity": {"vendor_id": 0x1234, "product_code": 0x7232, "serial": 42},
            },
        )
        gateway = Gateway.load(topo, registry=self.registry)
        self.node = CanopenFront(gateway.topology.fronts[0], gateway.context).build()
        self.identity = [self.node.od.get(0x1018, s) for s in (1, 2, 3, 4)]
        self.indexes = sorted({(v.index, v.subindex) for v in self.node.od.variables()})
        self.now = 0.0
        self.node.boot(self.now)
        self.prepare()

    def prepare(self) -> None:
        """State the target fuzzes from (after setup)."""

    def send(self, can_id: int, data: bytes = b"", rtr: bool = False) -> list[Frame]:
        frame = Frame(can_id, b"" if rtr else data, rtr=rtr, dlc=len(data) if rtr else None)
        out: list[Frame] = self.node.receive(frame, self.now)
        return out

    def advance(self, seconds: float) -> None:
        end = self.now + seconds
        for _ in range(200):  # a 1 ms heartbeat fuzzed into 0x1017 must not make a hang
            due = self.node.next_deadline()
            if due is None or due > end:
                break
            self.now = max(self.now, due)
            self.node.tick(self.now)
        self.now = end
        self.node.tick(end)

    def sdo(self, data: bytes) -> list[Frame]:
        return self.send(0x600 + self.node.node_id, data.ljust(8, b"\0"))

    def raw_frame(self, b: Bytes) -> None:
        can_id = b.pick(self.ids) if not b.chance(16) else b.u16() & 0x7FF
        size = b.u8() % 9
        if b.chance(32):
            self.send(can_id, bytes(size), rtr=True)
        else:
            self.send(can_id, b.take(size))

    def sdo_request(self, b: Bytes) -> bytes:
        """An SDO request: any command byte, mostly a real index / subindex."""
        index, sub = b.pick(self.indexes) if not b.chance(8) else (b.u16(), b.u8())
        return bytes([b.u8()]) + struct.pack("<HB", index, sub) + b.take(4)

    def run(self, data: bytes) -> None:
        b = Bytes(data)
        while b.more():
            self.step(b)

    def step(self, b: Bytes) -> None:
        self.raw_frame(b)

    def check(self) -> None:
        if self.node.counters["internal_errors"]:
            raise InvariantBroken(f"internal errors: {self.node.counters['internal_errors']}")
        if not 1 <= self.node.node_id <= 127:
            raise InvariantBroken(f"node-ID {self.node.node_id}")
        self.restore()
        self.sdo(b"\x80\0\0\0\0\0\0\0")  # abort whatever transfer the input left open
        out = self.sdo(b"\x40\x00\x10\x00")
        answer = [f for f in out if f.can_id == 0x580 + self.node.node_id]
        if not answer or answer[0].data[:4] != b"\x43\x00\x10\x00":
            raise InvariantBroken(f"SDO upload of 0x1000 not answered: {out}")

    def restore(self) -> None:
        """What a master does to get the node back to pre-operational."""
        self.send(0x000, b"\x80\x00")


class SdoTarget(CanopenTarget):
    """Expedited, segmented and block transfers, every client command specifier."""

    name = "sdo"

    def step(self, b: Bytes) -> None:
        kind = b.u8() % 8
        if kind < 3:  # one request of any command byte
            self.sdo(self.sdo_request(b))
        elif kind == 3:  # a segmented download: initiate, then segments (toggle mostly right)
            index, sub = b.pick(self.indexes)
            size = b.u8()
            self.sdo(bytes([0x21]) + struct.pack("<HBI", index, sub, size))
            toggle = 0
            for n in range(b.u8() % 6):
                last = n == 5 or b.chance(4)
                cmd = toggle << 4 | (b.u8() % 8) << 1 | last
                self.sdo(bytes([cmd if not b.chance(8) else b.u8()]) + b.take(7))
                toggle ^= 1
                if last:
                    break
        elif kind == 4:  # a segmented upload
            index, sub = b.pick(self.indexes)
            self.sdo(bytes([0x40]) + struct.pack("<HB", index, sub))
            for n in range(b.u8() % 6):
                self.sdo(bytes([0x60 | (n & 1) << 4 if not b.chance(8) else b.u8()]))
        elif kind == 5:  # a block download: initiate, sub-blocks, end
            index, sub = b.pick(self.indexes)
            size = b.u8()
            self.sdo(bytes([0xC0 | (b.u8() & 0x06)]) + struct.pack("<HBI", index, sub, size))
            seq = 1
            for _ in range(b.u8() % 8):
                last = b.chance(3)
                self.sdo(bytes([seq | last << 7 if not b.chance(8) else b.u8()]) + b.take(7))
                seq += 1
                if last:
                    break
            self.sdo(bytes([0xC1 | (b.u8() % 8) << 2]) + b.take(2))
        elif kind == 6:  # a block upload: initiate, start, acknowledgements, end
            index, sub = b.pick(self.indexes)
            self.sdo(bytes([0xA0 | (b.u8() & 0x04)]) + struct.pack("<HBB", index, sub, b.u8()))
            for _ in range(b.u8() % 4):
                self.sdo(bytes([b.pick((0xA3, 0xA2, 0xA1, b.u8()))]) + b.take(2))
        else:
            self.advance(b.u8() / 500)  # SDO timeouts


class NmtLssTarget(CanopenTarget):
    """NMT commands, node guarding and every LSS service (selective, fastscan, store...)."""

    name = "nmt_lss"
    ids = (0x000, 0x7E5, 0x705, 0x7E4)
    LSS_CS = (
        0x04, 0x11, 0x13, 0x15, 0x17, 0x40, 0x41, 0x42, 0x43, 0x46, 0x47, 0x48, 0x49,
        0x4A, 0x4B, 0x4C, 0x4D, 0x51, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E,
    )  # fmt: skip

    def lss(self, cs: int, payload: bytes = b"") -> None:
        self.send(0x7E5, (bytes([cs]) + payload).ljust(8, b"\0")[:8])

    def step(self, b: Bytes) -> None:
        kind = b.u8() % 8
        if kind == 0:
            cs = b.pick((0x01, 0x02, 0x80, 0x81, 0x82, b.u8()))
            self.send(0x000, bytes([cs, b.pick((0, NODE, self.node.node_id, b.u8()))]))
        elif kind == 1:
            self.send(0x700 + self.node.node_id, b"", rtr=True)  # node guarding
        elif kind == 2:  # switch state global: waiting / configuration (what the rest needs)
            self.lss(0x04, bytes([b.pick((0, 1, 1, b.u8()))]))
        elif kind == 3:  # switch selective: the four parts in order, some of them wrong
            for cs, value in zip((0x40, 0x41, 0x42, 0x43), self.identity, strict=True):
                self.lss(cs, struct.pack("<I", value if not b.chance(6) else b.u16()))
        elif kind == 4:
            cs = b.pick(self.LSS_CS)
            if cs in (0x40, 0x41, 0x42, 0x43, 0x46, 0x47, 0x48, 0x49, 0x4A, 0x4B) and b.chance(2):
                value = self.identity[min(cs & 0x03, 3)]  # right identity: the switch can match
                payload = struct.pack("<I", value) + b.take(3)
            elif cs == 0x51:  # fastscan: IDNumber, bit checked, LSS sub, LSS next
                payload = b.take(4) + bytes([b.pick((0x80, 31, 0, b.u8())), b.u8() % 5, b.u8() % 5])
            elif cs in (0x11, 0x13):  # configure node-ID / bit timing: mostly valid values
                payload = bytes([b.pick((1, 127, 0xFF, 0, 128, b.u8())), b.u8() % 10])
            else:
                payload = b.take(7)
            self.lss(cs, payload)
        elif kind == 5:
            self.raw_frame(b)
        else:
            self.advance(b.u8() / 250)

    def restore(self) -> None:
        self.send(0x7E5, bytes([0x04, 0x01]).ljust(8, b"\0"))  # configuration state
        if not self.node.configured:
            self.send(0x7E5, bytes([0x11, NODE]).ljust(8, b"\0"))
        self.send(0x7E5, bytes([0x04, 0x00]).ljust(8, b"\0"))  # waiting: an unconfigured one boots
        self.send(0x000, b"\x80\x00")

    def check(self) -> None:
        if self.node.counters["internal_errors"]:
            raise InvariantBroken(f"internal errors: {self.node.counters['internal_errors']}")
        self.restore()
        if not 1 <= self.node.node_id <= 127:
            raise InvariantBroken(f"node-ID {self.node.node_id} after configuring {NODE}")
        super().check()


class PdoTarget(CanopenTarget):
    """RPDOs (any length), TPDO remote requests, SYNC, and PDO re-configuration by SDO."""

    name = "pdo"
    PDO_PARAMS = [i for base in (0x1400, 0x1600, 0x1800, 0x1A00) for i in range(base, base + 4)]

    def prepare(self) -> None:
        base = self.node.node_id
        self.ids = [
            *(p + base for p in (0x200, 0x300, 0x400, 0x500)),
            *(p + base for p in (0x180, 0x280, 0x380, 0x480)),
            0x080,
        ]
        self.mappable = [
            (i, s) for i, s in self.indexes if 0x6000 <= i < 0x7000 and s > 0
        ] or self.indexes
        self.send(0x000, b"\x01\x00")  # operational

    def step(self, b: Bytes) -> None:
        kind = b.u8() % 6
        if kind < 3:
            self.raw_frame(b)
        elif kind == 3:  # write a PDO parameter: COB-ID, transmission type, mapping entry
            index, sub = b.pick(self.PDO_PARAMS), b.u8() % 9
            if index & 0x0200 and sub:  # a mapping entry naming a real object, any length
                i, s = b.pick(self.mappable)
                value = i << 16 | s << 8 | b.pick((1, 8, 16, 32, b.u8()))
            else:
                value = struct.unpack("<I", b.take(4))[0]
            self.sdo(bytes([0x23]) + struct.pack("<HBI", index, sub, value))
        elif kind == 4:
            self.send(0x000, bytes([b.pick((0x01, 0x80, 0x02)), 0]))
        else:
            self.advance(b.u8() / 500)

    def check(self) -> None:
        super().check()
        self.send(0x000, b"\x01\x00")


class SyncTimeEmcyTarget(CanopenTarget):
    """SYNC (with and without counter), TIME stamps, EMCY-looking and heartbeat frames of
    other nodes, and the objects that configure them."""

    name = "sync_time_emcy"
    PARAMS = (0x1005, 0x1006, 0x1007, 0x1012, 0x1014, 0x1015, 0x1016, 0x1017, 0x1019)

    def prepare(self) -> None:
        self.ids = [0x080, 0x100, *range(0x081, 0x100, 7), 0x720, 0x721, 0x77F, 0x701]
        # consume node 0x20's heartbeat every 100 ms: heartbeats and their loss get fuzzed too
        self.sdo(bytes([0x23, 0x16, 0x10, 0x01]) + struct.pack("<I", 0x20 << 16 | 100))
        self.send(0x000, b"\x01\x00")

    def step(self, b: Bytes) -> None:
        kind = b.u8() % 8
        if kind < 2:
            self.raw_frame(b)
        elif kind == 2:  # well-formed SYNC (no counter / counter) and TIME (6 bytes)
            self.send(0x080, b.take(b.u8() % 2))
        elif kind == 5:
            self.send(0x100, b.take(6))
        elif kind == 3:
            index = b.pick(self.PARAMS)
            value = struct.unpack("<I", b.take(4))[0]
            self.sdo(
                bytes([b.pick((0x23, 0x2B, 0x2F))]) + struct.pack("<HBI", index, b.u8() % 3, value)
            )
        elif kind == 4:
            self.send(0x720, bytes([b.pick((0x05, 0x7F, 0x04, 0x00, b.u8()))]))
        else:
            self.advance(b.u8() / 250)

    def check(self) -> None:
        super().check()
        self.send(0x000, b"\x01\x00")


MASTER = 0x0A


class DeviceNetTarget(Target):
    """The DeviceNet front's slave: allocation, explicit messages (fragmented too), I/O,
    duplicate MAC frames and the Offline Connection Set."""

    name = "devicenet"
    SERVICES = (0x0E, 0x10, 0x01, 0x05, 0x4B, 0x4C, 0x4E, 0x02, 0x15, 0x8E, 0x7F)
    CLASSES = (0x01, 0x02, 0x03, 0x04, 0x05, 0x64, 0x2B, 0x00, 0xFF)

    def setup(self) -> None:
        from fieldgate.plugins.devicenet.plugin import DeviceNetFront

        topo = one_front(
            self.work_dir,
            {"name": "dnet", "type": "devicenet", "mac_id": 9, "dup_mac_timeout_ms": 50},
        )
        gateway = Gateway.load(topo, registry=self.registry)
        self.front = DeviceNetFront(gateway.topology.fronts[0], gateway.context)
        self.slave = self.front.build()
        self.now = 100.0
        self.slave.boot(self.now)
        self.faults_expected = 0
        self.settle()

    def send(self, can_id: int, data: bytes) -> list[Frame]:
        out: list[Frame] = self.slave.receive(Frame(can_id, data), self.now)
        return out

    def g2(self, message: int) -> int:
        mac: int = self.slave.mac_id
        return 0x400 | mac << 3 | message

    def settle(self) -> None:
        for _ in range(200):
            if self.slave.state != "dup-mac-check":
                return
            self.now += 0.05
            self.slave.tick(self.now)

    def body(self, b: Bytes) -> bytes:
        service = b.pick(self.SERVICES)
        path = bytes([b.pick(self.CLASSES), b.pick((1, 0, 2, b.u8())), b.u8() % 12])
        return bytes([service]) + path[: b.u8() % 4] + b.take(b.u8() % 8)

    def run(self, data: bytes) -> None:
        b = Bytes(data)
        while b.more():
            kind = b.u8() % 10
            if kind == 0:  # allocate / release on the unconnected port
                service = b.pick((0x4B, 0x4C, b.u8()))
                self.send(
                    self.g2(6),
                    bytes([MASTER, service, 0x03, 0x01, b.u8(), b.pick((MASTER, b.u8()))])[
                        : 2 + b.u8() % 5
                    ],
                )
            elif kind in (1, 2):  # an unfragmented explicit request
                self.send(
                    self.g2(4), bytes([b.pick((MASTER, MASTER | 0x40, b.u8()))]) + self.body(b)
                )
            elif kind == 3:  # a fragmented request: first, middles, last (counts mostly right)
                payload = self.body(b) + b.take(b.u8() % 24)
                chunks = [payload[i : i + 6] for i in range(0, len(payload), 6)] or [b""]
                for n, chunk in enumerate(chunks):
                    ftype = 0x00 if n == 0 else 0x80 if n == len(chunks) - 1 else 0x40
                    count = n if not b.chance(6) else b.u8()
                    self.send(self.g2(4), bytes([MASTER | 0x80, ftype | count & 0x3F]) + chunk)
            elif kind == 4:  # an acknowledgement of our fragments
                self.send(self.g2(4), bytes([MASTER | 0x80, 0xC0 | b.u8() & 0x3F, b.u8()]))
            elif kind == 5:  # poll (fragmented or not), strobe, COS ack
                message = b.pick((5, 5, 2))
                self.send(self.g2(message), b.take(b.u8() % 9))
                if b.chance(4):
                    self.send(0x400 | MASTER << 3, b.take(8))  # bit strobe from the master
            elif kind == 6:  # duplicate MAC check frames
                self.send(self.g2(7), bytes([b.u8() & 0x80]) + b.take(6))
            elif kind == 7:  # Group 4: Offline Connection Set, ours or not
                self.send(0x7C0 | b.pick((0x2D, 0x2C, b.u8() & 0x3F)), b.take(b.u8() % 9))
            elif kind == 8:
                self.send(b.u16() & 0x7FF, b.take(b.u8() % 9))
            else:
                self.now += b.u8() / 50
                self.slave.tick(self.now)

    def check(self) -> None:
        counters = self.slave.counters
        if counters["rx_internal_errors"]:
            raise InvariantBroken(f"internal errors: {counters['rx_internal_errors']}")
        self.settle()
        if self.slave.state == "comm-fault":  # a duplicate MAC reply: the right answer
            if not counters["dup_mac_faults"]:
                raise InvariantBroken("comm-fault without a duplicate MAC")
            self.setup()  # an operator power-cycles it; fuzzing goes on from a fresh slave
        from fieldgate.plugins.devicenet.allocation import UNALLOCATED
        from fieldgate.plugins.devicenet.connection import EXPLICIT

        # a valid request as the master that owns the slave (a fuzzed allocation may name
        # another master MAC: the slave is then rightly refused to anyone else)
        owner = MASTER if self.slave.master_mac == UNALLOCATED else self.slave.master_mac
        explicit = self.slave.connections[EXPLICIT]
        if not (explicit.exists and explicit.established):
            out = self.send(self.g2(6), bytes([owner, 0x4B, 0x03, 0x01, 0x01, owner]))
            if not out or out[-1].data[:2] != bytes([owner, 0xCB]):
                raise InvariantBroken(f"allocation refused: {[f.data.hex() for f in out]}")
        out = self.send(self.g2(4), bytes([owner, 0x0E, 0x01, 0x01, 0x01]))  # vendor ID
        if not out or out[-1].data[:2] != bytes([owner, 0x8E]):
            raise InvariantBroken(f"Get_Attribute_Single unanswered: {[f.data.hex() for f in out]}")
