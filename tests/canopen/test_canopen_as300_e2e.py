"""End to end per style: canopen's master drives the front the way a Delta AS300 would.

The examples (`examples/na9161-style.yaml`, `examples/i7232d-style.yaml`) run as shipped on
their simulated, animated Modbus modules (an AO wired to an AI, as the manuals' benches),
with ``master: delta-as300`` (or the master writing 0x1016 itself). The master (seed-002
§1.11, REQ-AS-23): reads the key parameters, configures the PDOs by SDO in pre-operational,
starts the node, sends its heartbeat every 200 ms and SYNC every 50 ms, exchanges PDOs, then
goes away (its heartbeat stops; in another test its SYNC).

Run through ``canopen_dut``: in-process on python-can's virtual bus here, and in the SocketCAN
stage over vcan0 with the gateway as its own process (`fieldgate run --simulate`).
"""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path

import can
import canopen
import pytest
from canopen_dut import BOOT_TIMEOUT, FRONT, bus_under_test, make_dut, write_eds
from ruamel.yaml import YAML
from socketcan_guest import scaled

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
NODE = 5
MASTER = 1
HEARTBEAT_S, SYNC_S = 0.2, 0.05  # the AS300's defaults
CONSUMER_S = 0.5  # master: delta-as300's 0x1016 entry (2.5 heartbeat periods)
POLL_S = 0.05  # the back's poll period in these tests
STYLES = {"na9161": "na9161-style.yaml", "icpdas": "i7232d-style.yaml"}


def example(style: str, state_dir: Path, **front) -> dict:
    topo = YAML(typ="safe").load((EXAMPLES / STYLES[style]).read_text())
    topo["gateway"]["state_dir"] = str(state_dir)
    topo["fronts"][0].update(name=FRONT, node_id=NODE, **front)
    topo["backs"][0]["poll_ms"] = int(POLL_S * 1000)
    return topo


class As300:
    """canopen's master as the AS300 uses its slaves; every frame it sees, with its time."""

    def __init__(self, interface: str, channel: str, eds: Path):
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.02
        self.network.connect(interface=interface, channel=channel)
        self.node = self.network.add_node(canopen.RemoteNode(NODE, str(eds)))
        self.node.sdo.RESPONSE_TIMEOUT = scaled(1.0)
        self.frames: list[tuple[float, int, bytes]] = []
        self._cv = threading.Condition()
        self.network.notifier.add_listener(self._seen)
        self.heartbeat = None
        self.syncing = False

    def _seen(self, msg: can.Message) -> None:
        with self._cv:
            self.frames.append((time.monotonic(), msg.arbitration_id, bytes(msg.data)))
            self._cv.notify_all()

    def wait(self, can_id: int, match=lambda data: True, timeout: float = 2.0, since: float = 0.0):
        """The first frame on ``can_id`` after ``since`` that ``match``es: (time, data) or None."""
        end = time.monotonic() + scaled(timeout)
        with self._cv:
            while True:
                for t, cid, data in self.frames:
                    if cid == can_id and t >= since and match(data):
                        return t, data
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self._cv.wait(left)

    def seen(self, can_id: int, since: float) -> list[bytes]:
        with self._cv:
            return [d for t, cid, d in self.frames if cid == can_id and t >= since]

    def start_like_an_as300(self, sync: bool = True) -> None:
        """Key parameters, PDO configuration in pre-operational, Start, heartbeat, SYNC."""
        sdo = self.node.sdo
        assert struct.unpack("<I", sdo.upload(0x1000, 0))[0] & 0xFFFF == 0x0191  # E5
        sdo.upload(0x1018, 1)
        self.node.tpdo.read()
        self.node.rpdo.read()
        for pdo in (self.node.rpdo[1], self.node.rpdo[2], self.node.tpdo[1]):
            pdo.trans_type = 255  # CANopen Builder's "ASYNC" (REQ-AS-11: invalidate, write, valid)
            pdo.save()
        self.heartbeat = self.network.send_periodic(0x700 + MASTER, b"\x05", HEARTBEAT_S)
        self.node.nmt.state = "OPERATIONAL"
        if sync:
            self.network.sync.start(SYNC_S)
            self.syncing = True

    def stop_heartbeat(self) -> float:
        self.heartbeat.stop()
        self.heartbeat = None  # a SocketCAN BCM task refuses a second stop
        return time.monotonic()

    def stop_sync(self) -> float:
        self.network.sync.stop()
        self.syncing = False
        return time.monotonic()

    def read_outputs(self) -> list[int]:
        """Every DO byte (0x6200) and AO (0x6411), as the slave serves them."""
        sdo, out = self.node.sdo, []
        for index, size, fmt in ((0x6200, 1, "<B"), (0x6411, 2, "<h")):
            count = sdo.upload(index, 0)[0]
            out += [struct.unpack(fmt, sdo.upload(index, s)[:size])[0] for s in range(1, count + 1)]
        return out

    def close(self) -> None:
        if self.syncing:
            self.stop_sync()
        if self.heartbeat is not None:
            self.stop_heartbeat()
        self.network.disconnect()


@pytest.fixture
def bus():
    return bus_under_test()


def run(bus, tmp_path, style: str, **front):
    interface, channel, external = bus
    topo = example(style, tmp_path / "state", **front)
    eds = write_eds(topo, tmp_path)
    master = As300(interface, channel, eds)
    dut = make_dut(topo, interface, channel, external, tmp_path, simulate=True)
    dut.start()
    assert master.wait(0x700 + NODE, lambda d: d == b"\x00", BOOT_TIMEOUT), "no boot-up"
    return master, dut


def wait_outputs_zero(master: As300, until: float) -> list[int]:
    """Poll every output over SDO until all are 0 or ``until`` (monotonic) passed; the last read."""
    outputs = master.read_outputs()
    while any(outputs) and time.monotonic() < until:
        time.sleep(0.01)
        outputs = master.read_outputs()
    return outputs


def write_ao(master: As300, value: int) -> float:
    """RPDO2 (AO 1.., type 255): AO 1 = ``value``, the others 0; returns when it went out."""
    rpdo = master.node.rpdo[2]
    length = sum(v.length for v in rpdo.map) // 8
    data = struct.pack("<h", value).ljust(length, b"\0")
    master.network.send_message(0x300 + NODE, data)
    return time.monotonic()


def test_na9161_under_an_as300(bus, tmp_path):
    master, dut = run(bus, tmp_path, "na9161", master="delta-as300")
    try:
        master.start_like_an_as300()
        started = time.monotonic()
        assert master.wait(0x280 + NODE, since=started - 1), "TPDO2 not sent after Start"
        # an AI change (AO 1 wired to AI 1) sends TPDO2 within the inhibit time plus a poll:
        # no SDO write to any 0x6423 (the NA-9161 has none)
        time.sleep(scaled(0.6))  # the Start transmission's inhibit time has passed
        sent = write_ao(master, 0x1234)
        got = master.wait(0x280 + NODE, lambda d: d[:2] == b"\x34\x12", 3.0, since=sent)
        assert got, "TPDO2 never carried the AI change"
        # AO written at the next poll, AI read at the one after: two poll turns, then the inhibit
        assert got[0] - sent <= scaled(0.5 + 3 * POLL_S + 0.15), got[0] - sent
        # RPDO1: DO bytes go out to the modules
        master.network.send_message(0x200 + NODE, bytes([0xA5, 0x0F]))
        assert master.wait(0x180 + NODE, since=time.monotonic() - 0.05), "TPDO1 silent"
        assert master.read_outputs()[:2] == [0xA5, 0x0F]
        # the master goes away: its heartbeat stops
        last = master.stop_heartbeat()
        emcy = master.wait(0x80 + NODE, lambda d: d[:4] == bytes.fromhex("30811107"), 3.0, last)
        assert emcy and emcy[1][4] == MASTER, "no EMCY for the master's heartbeat"
        assert emcy[0] - last <= scaled(CONSUMER_S + HEARTBEAT_S + 0.1), emcy[0] - last
        # every digital output 0, every analog output its error value 0 (NA-9161 defaults)
        outputs = wait_outputs_zero(master, emcy[0] + scaled(POLL_S + 0.3))
        assert not any(outputs), outputs
        # and the modules got them within a poll period (in-process: the simulator's registers)
        if dut.gateway is not None:
            sim = dut.gateway.bench.simulator("rs485")

            def at_modules() -> bool:
                return not sim.get_output("rs485/m1/do0") and sim.get_output("rs485/m4/ao0") == 0

            deadline = emcy[0] + scaled(POLL_S + 0.2)
            while not at_modules() and time.monotonic() < deadline:
                time.sleep(0.005)
            assert at_modules(), (sim.get_output("rs485/m1/do0"), sim.get_output("rs485/m4/ao0"))
        # pre-operational: the heartbeat the node produces (0x1017 = 1000 ms) says 0x7F
        beat = master.wait(0x700 + NODE, lambda d: d == b"\x7f", 2.5, since=emcy[0])
        assert beat, "the node did not go to pre-operational"
    finally:
        master.close()
        dut.stop()


def test_na9161_sync_loss_drives_the_outputs_to_0(bus, tmp_path):
    master, dut = run(bus, tmp_path, "na9161", master="delta-as300")
    try:
        master.node.sdo.download(0x1006, 0, struct.pack("<I", int(SYNC_S * 1e6)))  # 50 ms
        master.start_like_an_as300()
        master.network.send_message(0x200 + NODE, bytes([0x3C, 0x03]))
        time.sleep(scaled(0.3))
        assert master.read_outputs()[:2] == [0x3C, 0x03]
        stopped = master.stop_sync()
        emcy = master.wait(0x80 + NODE, lambda d: d[:2] == b"\x00\x81", 2.0, since=stopped)
        assert emcy, "no EMCY for the SYNC loss"
        outputs = wait_outputs_zero(master, time.monotonic() + scaled(0.5))
        assert not any(outputs), outputs
        beat = master.wait(0x700 + NODE, lambda d: d == b"\x7f", 2.5, since=emcy[0])
        assert beat, "the node did not go to pre-operational"
    finally:
        master.close()
        dut.stop()


def test_na9161_master_writes_0x1016_itself(bus, tmp_path):
    """master: generic: the same outcome once the master configured the consumer by SDO."""
    master, dut = run(bus, tmp_path, "na9161")
    try:
        assert master.node.sdo.upload(0x1016, 1) == bytes(4)  # nothing watched by default
        master.node.sdo.download(0x1016, 1, struct.pack("<I", MASTER << 16 | 500))
        master.start_like_an_as300(sync=False)
        master.network.send_message(0x200 + NODE, bytes([0xFF, 0xFF]))
        time.sleep(scaled(0.3))
        last = master.stop_heartbeat()
        assert master.wait(0x80 + NODE, lambda d: d[:4] == bytes.fromhex("30811107"), 3.0, last)
        outputs = wait_outputs_zero(master, time.monotonic() + scaled(0.5))
        assert not any(outputs), outputs
    finally:
        master.close()
        dut.stop()


def test_icpdas_under_an_as300(bus, tmp_path):
    master, dut = run(bus, tmp_path, "icpdas", master="delta-as300")
    try:
        # the I-7232D has no heartbeat; the AS300 profile adds it (no SDO write by the master)
        assert struct.unpack("<H", master.node.sdo.upload(0x1017, 0))[0] == 1000
        assert struct.unpack("<I", master.node.sdo.upload(0x1016, 1))[0] == MASTER << 16 | 500
        master.start_like_an_as300()
        started = time.monotonic()
        # the AS300 waits for each TPDO after Start (E2): the profile sends them, the style
        # (TV-07) would not
        assert master.wait(0x180 + NODE, since=started - 1), "TPDO1 not sent after Start"
        assert master.wait(0x280 + NODE, since=started - 1), "TPDO2 not sent after Start"
        time.sleep(scaled(0.2))
        # an analog change is no TPDO event (I-7232D §2.7), but the AS300 profile gives the
        # analog TPDO an event timer of 100 ms (REQ-AS-15): the new value arrives anyway
        sent = write_ao(master, 0x0777)
        assert master.wait(0x280 + NODE, lambda d: d[:2] == b"\x77\x07", 2.0, sent), (
            "the analog value never reached the master (frozen analog inputs, audit 002 a17)"
        )
        assert struct.unpack("<H", master.node.sdo.upload(0x1801, 5))[0] == 100
        # RPDO1 with TV-23's error modes on the M-7055D: 0x6206:1 = 0x31, 0x6207:1 = 0xF8
        master.network.send_message(0x200 + NODE, bytes([0xFF]))
        time.sleep(scaled(0.2))
        last = master.stop_heartbeat()
        emcy = master.wait(0x80 + NODE, lambda d: d[:4] == bytes.fromhex("30811107"), 3.0, last)
        assert emcy and emcy[1][4] == MASTER, "master loss not detected by heartbeat"
        assert emcy[0] - last <= scaled(CONSUMER_S + HEARTBEAT_S + 0.1), emcy[0] - last
        # TV-23: 0xFF -> 0xFE (DO0 to 0; DO4/DO5 already 1); the example's AO error value is 0
        deadline = time.monotonic() + scaled(POLL_S + 0.3)
        while master.read_outputs()[0] != 0xFE and time.monotonic() < deadline:
            time.sleep(0.01)
        assert master.read_outputs() == [0xFE, 0]
        # the I-7232D keeps its NMT state (0x1029 no change): heartbeats still say operational
        assert master.wait(0x700 + NODE, lambda d: d == b"\x05", 2.5, since=emcy[0])
    finally:
        master.close()
        dut.stop()
