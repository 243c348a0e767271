"""One fuzz target per wire: each turns a fuzz buffer into protocol input for a real engine,
then checks the engine still does its job (docs/reliability.md, scripts/faults/fuzz.py).

A target is stateful across inputs (a long-lived gateway sees one frame after another):
``run(data)`` feeds one input; ``check()`` is the invariant after it: the engine still
answers a valid request of its protocol and counted no internal error. Anything that
escapes ``run`` other than the wire's own error type is a crash.

The buffer is read by :class:`Bytes`: structure-aware choices (known COB-IDs, command
specifiers, dictionary indexes, CIP services, valid replies to mutate and re-checksum)
come from its bytes, so the fuzzer spends its inputs on frames the engine cannot reject
at the first byte.
"""

from __future__ import annotations

import struct
from abc import ABC, abstractmethod
from collections.abc import Coroutine, Sequence
from pathlib import Path
from typing import Any, TypeVar

from fieldgate import Gateway, load_registry
from fieldgate.can.frame import Frame
from fieldgate.plugin import Registry
from fieldgate.polling import CommError

T = TypeVar("T")
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


class InvariantBroken(AssertionError):
    """The engine took the input without an exception but no longer does its job."""


class Bytes:
    """Reads choices from a fuzz buffer; an exhausted buffer reads zeros."""

    def __init__(self, data: bytes):
        self.data = data
        self.pos = 0

    def more(self) -> bool:
        return self.pos < len(self.data)

    def u8(self) -> int:
        if self.pos >= len(self.data):
            return 0
        self.pos += 1
        return self.data[self.pos - 1]

    def u16(self) -> int:
        return self.u8() | self.u8() << 8

    def take(self, n: int) -> bytes:
        out = self.data[self.pos : self.pos + n]
        self.pos += len(out)
        return out.ljust(n, b"\0") if len(out) < n and self.pos >= len(self.data) else out

    def pick(self, items: Sequence[T]) -> T:
        return items[self.u8() % len(items)]

    def chance(self, one_in: int) -> bool:
        return self.u8() % one_in == 0


def run_sync(coro: Coroutine[Any, Any, T]) -> T:
    """Run a coroutine that never really suspends (fake links answer at once)."""
    try:
        coro.send(None)
    except StopIteration as stop:
        return stop.value  # type: ignore[no-any-return]
    coro.close()
    raise InvariantBroken("a transaction waited for I/O that a fake link never gives")


class Target(ABC):
    name: str
    max_len = 96  # bytes per input

    def __init__(self, work_dir: Path, registry: Registry | None = None):
        self.work_dir = work_dir
        self.registry = registry or load_registry()
        self.setup()

    @abstractmethod
    def setup(self) -> None:
        """Build the engine (again, after a failure)."""

    @abstractmethod
    def run(self, data: bytes) -> None: ...

    @abstractmethod
    def check(self) -> None: ...


# -- CANopen -----------------------------------------------------------------------------------
NODE = 5
CO_TOPOLOGY_BACK = {
    "name": "rs485",
    "type": "dcon",
    "port": "/dev/null",  # never opened: the fronts need the channels, not a running back
    "modules": [
        {"address": 1, "model": "I-7055"},
        {"address": 2, "model": "I-7017"},
        {"address": 3, "model": "I-7024"},
    ],
}


def one_front(work_dir: Path, front: dict[str, Any]) -> dict[str, Any]:
    """A topology of one front (on the virtual bus) over the never-started DCON back."""
    return {
        "gateway": {"name": "fuzz", "state_dir": str(work_dir)},
        "fronts": [{"interface": "virtual", **front}],
        "backs": [CO_TOPOLOGY_BACK],
    }


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


# -- DeviceNet ---------------------------------------------------------------------------------
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


# -- serial backs ------------------------------------------------------------------------------
def mutate(b: Bytes, valid: bytes) -> bytes:
    """A reply the way a line distorts one: flipped, cut, extended, spliced or random bytes."""
    kind = b.u8() % 6
    out = bytearray(valid)
    if kind == 0 and out:
        for _ in range(1 + b.u8() % 3):
            out[b.u8() % len(out)] ^= 1 << (b.u8() % 8)
    elif kind == 1:
        del out[b.u8() % (len(out) + 1) :]
    elif kind == 2:
        out += b.take(b.u8() % 12)
    elif kind == 3 and out:
        at = b.u8() % len(out)
        out[at : at + 1 + b.u8() % 4] = b.take(b.u8() % 6)
    elif kind == 4:
        out = bytearray(b.take(b.u8() % 24))
    return bytes(out)


def output_values(image: Any, outputs: list[str], b: Bytes) -> dict[str, Any]:
    """Output values as a front sets them: through the image, which refuses what a channel's
    type cannot hold (such a value never reaches a back)."""
    for cid in outputs:
        value = bool(b.u8() & 1) if image[cid].spec.kind.is_digital else b.u16() - b.u8() * 128
        try:
            image.write_output(cid, value, origin="fuzz")
        except ValueError:
            pass
    return {cid: image.value(cid) for cid in outputs}


class FakeModbusClient:
    """pymodbus's client calls as ModbusLink makes them, answered from the fuzz buffer.

    The request goes through our codec to the simulator's module (the valid reply), the
    wire bytes (mutated, usually with a fixed CRC so the mutation reaches the decoders) go
    through ModbusLink's trace hook and pymodbus's own RTU framer and PDU decoder, exactly
    the way pymodbus hands a received frame to its caller.
    """

    connected = True

    def __init__(self, target: ModbusTarget):
        from pymodbus.framer import FramerRTU
        from pymodbus.pdu import DecodePDU

        self.target = target
        self.framer = FramerRTU(DecodePDU(False))

    async def _ask(self, unit: int, pdu: bytes) -> Any:
        from pymodbus.exceptions import ModbusIOException

        from fieldgate.plugins.modbus import codec

        request = codec.frame(unit, pdu)
        module = self.target.sim.get(unit)
        valid = module.handle(codec.parse_request(request)) if module else b""
        wire = self.target.reply(valid)
        self.target.link._trace(False, wire)
        _, reply = self.framer.handleFrame(wire, unit, 0)
        if reply is None or reply.dev_id != unit:
            raise ModbusIOException("no valid reply")  # what pymodbus raises at its timeout
        return reply

    def _req(self, fc: int, address: int, value: int, device_id: int) -> Any:
        return self._ask(device_id, struct.pack(">BHH", fc, address, value))

    def read_coils(self, address: int, count: int, device_id: int) -> Any:
        return self._req(1, address, count, device_id)

    def read_discrete_inputs(self, address: int, count: int, device_id: int) -> Any:
        return self._req(2, address, count, device_id)

    def read_holding_registers(self, address: int, count: int, device_id: int) -> Any:
        return self._req(3, address, count, device_id)

    def read_input_registers(self, address: int, count: int, device_id: int) -> Any:
        return self._req(4, address, count, device_id)

    def write_coil(self, address: int, value: bool, device_id: int) -> Any:
        return self._req(5, address, 0xFF00 if value else 0, device_id)

    def write_register(self, address: int, value: int, device_id: int) -> Any:
        return self._req(6, address, value, device_id)

    def write_coils(self, address: int, values: list[bool], device_id: int) -> Any:
        from fieldgate.plugins.modbus.codec import pack_bits

        data = pack_bits(values)
        pdu = struct.pack(">BHHB", 15, address, len(values), len(data)) + data
        return self._ask(device_id, pdu)

    def write_registers(self, address: int, values: list[int], device_id: int) -> Any:
        pdu = struct.pack(
            f">BHHB{len(values)}H", 16, address, len(values), 2 * len(values), *values
        )
        return self._ask(device_id, pdu)


class ModbusTarget(Target):
    """Modbus RTU replies into the back's real link and module code (DI, DO, AI, AO models)."""

    name = "modbus"
    MODULES = [
        {"address": 1, "model": "M-7052D"},
        {"address": 3, "model": "M-7055D"},
        {"address": 4, "model": "M-7024"},
        {"address": 5, "model": "M-7017R"},
    ]

    def setup(self) -> None:
        from fieldgate import ProcessImage
        from fieldgate.plugins.modbus import codec
        from fieldgate.plugins.modbus.back import ModbusModule
        from fieldgate.plugins.modbus.client import ModbusLink
        from fieldgate.plugins.modbus.config import ModbusBackConfig
        from fieldgate.plugins.modbus.simulator import SimModule

        self.codec = codec
        config = ModbusBackConfig(name="rs485", port="unused", modules=self.MODULES)
        self.image = ProcessImage(lambda: 0.0)
        for spec in config.channel_specs():
            self.image.add(spec)
        points = config.points()
        self.sim_modules = {
            m.address: SimModule(m.address, points[m.address]) for m in config.modules
        }
        self.sim = self.sim_modules
        self.link = ModbusLink("fuzz", inter_frame=0)
        self.link._client = FakeModbusClient(self)
        self.modules = [
            ModbusModule(
                m,
                [c.spec for c in self.image.channels(module=m.address)],
                self.link,
                points[m.address],
                retry_period=0.0,
                clock=lambda: 0.0,
            )
            for m in config.modules
        ]
        self.b = Bytes(b"")
        self.valid_only = False

    def reply(self, valid: bytes) -> bytes:
        if self.valid_only:
            return valid
        b = self.b
        if b.chance(4):
            return valid
        out = mutate(b, valid)
        if len(out) > 2 and not b.chance(4):  # fix the CRC: the mutation reaches the decoders
            out = self.codec.frame(out[0], out[1:-2])
        return out

    def transactions(self, b: Bytes) -> None:
        module = b.pick(self.modules)
        action = b.u8() % 4
        try:
            if action == 0:
                run_sync(module.probe())
            elif action == 3 and module.outputs:
                run_sync(module.write_outputs(output_values(self.image, module.outputs, b)))
            else:
                run_sync(module.read_inputs())
        except CommError:
            pass  # the wire's own error: counted by the scheduler

    def run(self, data: bytes) -> None:
        self.b = Bytes(data)
        while self.b.more():
            self.transactions(self.b)

    def check(self) -> None:
        self.valid_only = True
        try:
            for module in self.modules:
                readings = run_sync(module.read_inputs())
                if module.inputs and not isinstance(readings, dict):
                    raise InvariantBroken(f"module {module.unit}: {readings!r}")
        except CommError as exc:
            raise InvariantBroken(f"a valid reply refused: {exc}") from exc
        finally:
            self.valid_only = False


class FakeDconSerial:
    """AsyncSerial's surface for DconLink: the command goes to the DCON simulator, its
    reply comes back mutated from the fuzz buffer."""

    def __init__(self, target: DconTarget):
        self.target = target
        self.reply = b""
        self.pending = 0

    def reset_input(self) -> None:
        self.pending = 0

    async def write(self, data: bytes) -> None:
        answers = self.target.bus.feed(data, 0.0)
        valid = answers[0][0] if answers else b""
        self.reply = self.target.wire(valid)

    async def read_until(self, terminator: bytes, timeout: float) -> bytes:
        end = self.reply.find(terminator)
        if end < 0:
            self.pending = len(self.reply)
            raise TimeoutError
        return self.reply[: end + 1]


class DconTarget(Target):
    """DCON replies into the back's real link and module code (DIO, AI, AO, counters)."""

    name = "dcon"
    MODULES = [
        {"address": 1, "model": "I-7055"},
        {"address": 2, "model": "I-7017", "data_format": "engineering"},
        {"address": 3, "model": "I-7024"},
        {"address": 4, "model": "I-7012"},
        {"address": 5, "model": "I-7060", "watchdog": {"enabled": True, "timeout_ms": 500}},
    ]

    def setup(self) -> None:
        from fieldgate import ProcessImage
        from fieldgate.plugins.dcon.config import DconBackConfig
        from fieldgate.plugins.dcon.link import DconLink
        from fieldgate.plugins.dcon.module import DconModule
        from fieldgate.plugins.dcon.simulated import SimBus, SimModule

        config = DconBackConfig(name="rs485", port="unused", modules=self.MODULES)
        self.image = ProcessImage(lambda: 0.0)
        for spec in config.channel_specs():
            self.image.add(spec)
        self.bus = SimBus(checksum=False)
        for m in config.modules:
            self.bus.add(SimModule(m.profile, m.address))
        self.serial = FakeDconSerial(self)
        self.link = DconLink(self.serial, False, 0.1, settle_after_timeout=False)
        self.modules = [
            DconModule(
                m, [c.spec for c in self.image.channels(module=m.address)], self.image, self.link
            )
            for m in config.modules
        ]
        self.b = Bytes(b"")
        self.valid_only = False
        for module in self.modules:  # learn the modules as the back does when they come online
            self.valid_only = True
            run_sync(module.on_online())
        self.valid_only = False

    def wire(self, valid: bytes) -> bytes:
        if self.valid_only:
            return valid
        b = self.b
        if b.chance(4):
            return valid
        out = mutate(b, valid)
        if b.chance(2) and out and out[-1:] != b"\r":
            out += b"\r"  # mostly a complete line: the mutation reaches the parsers
        return out

    def run(self, data: bytes) -> None:
        self.b = b = Bytes(data)
        while b.more():
            module = b.pick(self.modules)
            action = b.u8() % 6
            try:
                if action == 0:
                    run_sync(module.probe())
                elif action == 1:
                    run_sync(module.on_online())
                elif action == 2 and module.outputs:
                    run_sync(module.write_outputs(output_values(self.image, module.outputs, b)))
                elif action == 3:
                    run_sync(module.read_status())
                else:
                    run_sync(module.read_inputs())
            except CommError:
                pass

    def check(self) -> None:
        """Every module reads good data within two polls of a clean line: without a checksum
        a distorted $AA2 reply can set a wrong data format; the read that does not fit it
        makes the next poll read $AA2 again (tests/faults/test_fuzz_findings.py)."""
        self.valid_only = True
        try:
            for module in self.modules:
                try:
                    run_sync(module.read_inputs())
                except CommError:
                    run_sync(module.read_inputs())
        except CommError as exc:
            raise InvariantBroken(f"a valid reply refused twice: {exc}") from exc
        finally:
            self.valid_only = False


# -- YAML topologies ---------------------------------------------------------------------------
TOKENS = (
    b"-1", b"1e309", b"null", b"[", b"{", b"}", b"]", b"!!python/object:os.system", b"&a", b"*a",
    b"~", b"0x7FF", b"true", b"\t", b"- ", b": ", b"'", b'"', b"\xff", b"\x00", b"<<: *a",
    b"99999999999999999999", b".nan", b"modules:", b"type: canopen", b"--- ", b"%YAML 1.1\n",
)  # fmt: skip


class YamlTarget(Target):
    """Topology files: the examples mutated (bytes, lines, YAML tokens) into the loader."""

    name = "yaml"
    max_len = 48

    def setup(self) -> None:
        from fieldgate.topology import TopologyError, load_topology

        self.error = TopologyError
        self.load = load_topology
        self.examples = [p.read_bytes() for p in sorted(EXAMPLES.glob("*.yaml"))]
        self.file = self.work_dir / "fuzz.yaml"
        self.valid = self.work_dir / "valid.yaml"
        self.valid.write_bytes(self.examples[0])

    def run(self, data: bytes) -> None:
        b = Bytes(data)
        text = bytearray(b.pick(self.examples))
        while b.more():
            at = (b.u16() * 7) % (len(text) + 1)
            kind = b.u8() % 5
            if kind == 0:
                text[at : at + b.u8() % 8] = b""
            elif kind == 1:
                text[at:at] = b.pick(TOKENS)
            elif kind == 2:
                text[at:at] = b.take(b.u8() % 4)
            elif kind == 3:
                lines = text.split(b"\n")
                i = b.u8() % len(lines)
                lines.insert(b.u8() % len(lines), lines[i])
                text = bytearray(b"\n".join(lines))
            else:
                end = text.find(b"\n", at)
                text[at : end if end >= 0 else len(text)] = b.pick(TOKENS)
        self.file.write_bytes(bytes(text))
        try:
            self.load(self.file, self.registry)
        except self.error:
            pass

    def check(self) -> None:
        try:
            self.load(self.valid, self.registry)
        except self.error as exc:
            raise InvariantBroken(f"the valid example no longer loads: {exc}") from exc


TARGETS: dict[str, type[Target]] = {
    t.name: t
    for t in (
        SdoTarget,
        NmtLssTarget,
        PdoTarget,
        SyncTimeEmcyTarget,
        DeviceNetTarget,
        ModbusTarget,
        DconTarget,
        YamlTarget,
    )
}
FULL_INPUTS = {name: 1_000_000 for name in TARGETS} | {"yaml": 20_000}
