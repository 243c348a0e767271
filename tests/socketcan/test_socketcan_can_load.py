"""CAN fronts under other nodes' traffic over real SocketCAN (vcan0 inside User-Mode Linux).

The gateway runs in this test process (its status counters are read directly); the foreign
traffic comes from another process (bench/can_flood.py: a raw AF_CAN socket as fast as it
goes). Proves, over the kernel's CAN stack:

* each CANopen test twice: reading SocketCAN's raw socket (fieldgate.can.socketcan_raw) and
  through python-can's public recv/send (the fallback);
* a foreign flood reaches the CANopen engine as zero frames (the kernel's CAN_RAW_FILTER from
  the node's listen set), while SDO reads sent during it are all answered;
* a PDO COB-ID rewritten by SDO is received at once under its new ID, no longer under the old;
* an LSS node-ID switch moves the SDO (and guarding) filter;
* DeviceNet: the same flood does not stop explicit messages and polled I/O from being answered.

Each flood lasts FLOOD_S seconds, so the stage grows by seconds, not minutes
(bench/can_load.py is the long, measured version; docs/canopen-bench.md).
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from pathlib import Path

import can
import pytest
from socketcan_guest import in_guest, scaled

from fieldgate import Gateway, load_registry
from fieldgate.can import socketcan_raw

CHANNEL = "vcan0"
REPO = Path(__file__).resolve().parents[2]
NODE = 5
FLOOD_S = 3.0
# other nodes' TPDO1s (0x181-0x1FF) without ours (0x185, a TPDO that answers remote requests)
FOREIGN = "0x181-0x184,0x186-0x1FF"

pytestmark = in_guest(CHANNEL)

sys.path.insert(0, str(REPO / "tests" / "devicenet"))
from dnet_master import Master  # noqa: E402  (tests/devicenet is not a package)


def start_flood(seconds: float = FLOOD_S, ids: str = FOREIGN) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [
            sys.executable,
            str(REPO / "bench" / "can_flood.py"),
            "--channel",
            CHANNEL,
            "--seconds",
            str(seconds),
            "--ids",
            ids,
        ],
        stdout=subprocess.PIPE,
        text=True,
    )


def flood_result(proc: subprocess.Popen[str]) -> dict:
    out, _ = proc.communicate(timeout=scaled(60))
    assert proc.returncode == 0
    result = json.loads(out.strip().splitlines()[-1])
    assert result["frames"] > 1000, result  # it was a flood
    return result


class SdoClient:
    """Raw SDO requests on a socketcan bus that hears only the answers (kernel filter)."""

    def __init__(self, node: int = NODE):
        self.bus = can.Bus(interface="socketcan", channel=CHANNEL)
        self.watch(node)

    def watch(self, node: int, *extra: int) -> None:
        self.node = node
        self.bus.set_filters(
            [
                {"can_id": i, "can_mask": 0x7FF, "extended": False}
                for i in (0x580 + node, 0x700 + node, 0x180 + node, 0x7E4, *extra)
            ]
        )

    def send(self, can_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    async def expect(self, can_id: int, timeout: float = 1.0) -> bytes | None:
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while loop.time() < end:
            msg = await asyncio.to_thread(self.bus.recv, 0.05)
            if msg is not None and msg.arbitration_id == can_id:
                return bytes(msg.data)
        return None

    async def read(self, index: int, sub: int, timeout: float = 1.0) -> bytes | None:
        self.send(0x600 + self.node, bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]))
        return await self.expect(0x580 + self.node, timeout)

    async def write(self, index: int, sub: int, value: int) -> None:
        self.send(
            0x600 + self.node,
            bytes([0x23, index & 0xFF, index >> 8, sub]) + value.to_bytes(4, "little"),
        )
        answer = await self.expect(0x580 + self.node)
        assert answer is not None and answer[0] == 0x60, answer


def canopen_topology(state_dir: Path) -> dict:
    return {
        "gateway": {"name": "can-load-uml", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "socketcan",
                "channel": CHANNEL,
                "node_id": NODE,
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": 1, "digital": 8, "analog": 1, "error_mode": {"value": 0}}],
            }
        ],
    }


@pytest.fixture(params=["raw", "python-can"])
async def canopen(request, tmp_path, monkeypatch):
    """The gateway reading SocketCAN's raw socket (the fast path), or through python-can's
    public recv/send (the fallback, forced by switching the fast path off)."""
    if request.param == "python-can":
        monkeypatch.setattr(socketcan_raw, "ENABLED", False)
    gw = Gateway.load(canopen_topology(tmp_path), registry=load_registry())
    client = SdoClient()
    await gw.start()
    try:
        assert await client.expect(0x700 + NODE, 3.0) == b"\x00"  # boot-up
        front = gw.component("can")
        expected = "socketcan-raw" if request.param == "raw" else "add-reader"
        assert front.adapter.receiving.receiver.mode == expected
        if request.param == "raw":  # room for bursts (root in the guest: beyond rmem_max)
            assert front.adapter.status()["rx_buffer_bytes"] >= 2 * 1024 * 1024
        yield gw, front, client
    finally:
        client.bus.shutdown()
        await gw.stop()


async def test_a_foreign_flood_reaches_the_engine_as_zero_frames_and_sdo_reads_go_on(canopen):
    _, front, client = canopen
    node, adapter = front.node, front.adapter
    assert adapter.status()["filters"]  # the kernel filters are set
    before_node, before_bus = node.frames_received, adapter.rx_frames
    flood = start_flood()
    reads = lost = 0
    while flood.poll() is None:
        answer = await client.read(0x1000, 0)
        reads += 1
        if answer is None or answer[0] != 0x43:
            lost += 1
    result = flood_result(flood)
    assert lost == 0, f"{lost} of {reads} SDO reads unanswered during {result}"
    assert reads > 0
    assert node.frames_received - before_node == reads  # the SDO reads, no foreign frame
    assert adapter.rx_frames - before_bus == reads
    assert adapter.rx_ignored == 0 and node.counters["ignored"] == 0
    print(f"flood {result}, {reads} SDO reads answered, 0 foreign frames in the engine")


async def test_a_pdo_cob_id_rewritten_by_sdo_is_heard_at_once_and_the_old_one_no_more(canopen):
    gw, front, client = canopen
    old, new = 0x200 + NODE, 0x321
    await client.write(0x1400, 1, 0x8000_0000 | old)
    await client.write(0x1400, 1, new)
    client.send(0x000, bytes([0x01, NODE]))  # Operational (no TPDO at Start: TV-07)
    assert (await client.read(0x1000, 0))[0] == 0x43  # (the Start is in)
    client.send(new, b"\x81")  # at once after the write's answer
    assert await client.expect(0x180 + NODE) is not None  # the DO loop back to DI: a TPDO
    assert [gw.read(f"io/m1/do{i}") for i in range(8)] == [True] + [False] * 6 + [True]
    received = front.node.frames_received
    client.send(old, b"\xff")
    assert (await client.read(0x1000, 0))[0] == 0x43
    assert front.node.frames_received == received + 1  # the old ID never reached the node
    assert front.adapter.rx_ignored == 0
    assert gw.read("io/m1/do1") is False


async def test_an_lss_node_id_switch_moves_the_sdo_filter(canopen):
    _, front, client = canopen
    new = 9
    client.send(0x7E5, bytes.fromhex("0401000000000000"))
    client.send(0x7E5, bytes([0x11, new, 0, 0, 0, 0, 0, 0]))
    assert (await client.expect(0x7E4))[:2] == b"\x11\x00"
    client.send(0x7E5, bytes.fromhex("0400000000000000"))
    client.watch(new)
    client.send(0x000, bytes([0x82, NODE]))  # reset communication: the new node-ID
    assert await client.expect(0x700 + new, 3.0) == b"\x00"
    assert (await client.read(0x1000, 0))[0] == 0x43  # on 0x609 at once
    received = front.node.frames_received
    client.send(0x600 + NODE, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))  # the old SDO ID
    assert (await client.read(0x1000, 0))[0] == 0x43
    assert front.node.frames_received == received + 1
    filters = front.adapter.status()["filters"]
    assert filters is not None and front.adapter.listen is not None
    assert 0x600 + new in front.adapter.listen and 0x600 + NODE not in front.adapter.listen


class VcanMaster(Master):
    """tests/devicenet's master on vcan0, hearing only its slave's answers (kernel filter)."""

    def __init__(self, slave: int, mac: int = 0x0A):
        self.bus = can.Bus(interface="socketcan", channel=CHANNEL)
        self.slave, self.mac = slave, mac
        self.bus.set_filters(
            [
                {"can_id": 0x400 | slave << 3, "can_mask": 0x7F8, "extended": False},
                {"can_id": 0x3C0 | slave, "can_mask": 0x7FF, "extended": False},
            ]
        )


async def test_devicenet_explicit_and_polled_io_are_answered_during_a_flood(tmp_path):
    mac = 9
    topo = {
        "gateway": {"name": "dnet-load-uml", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "dnet",
                "type": "devicenet",
                "interface": "socketcan",
                "channel": CHANNEL,
                "mac_id": mac,
                "baudrate": 500000,
                "dup_mac_timeout_ms": 50,
                "identity": {"vendor_id": 803, "serial": 4711},
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": 3, "digital": 8, "analog": 2, "error_mode": {"value": 0}}],
            }
        ],
    }
    master = VcanMaster(mac)
    gw = Gateway.load(topo, registry=load_registry())
    await gw.start()
    try:
        await master.wait_online()
        assert await master.allocate(0x03) == bytes.fromhex("0A CB 00")
        # the poll connection's expected packet rate: 1 s (established, watchdog 4 s)
        assert await master.request(bytes.fromhex("10 05 02 09 E8 03")) == bytes.fromhex("90 E8 03")
        adapter = gw.component("dnet").adapter
        before = adapter.rx_frames
        flood = start_flood()
        requests = polls = 0
        value = 0
        while flood.poll() is None:
            assert await master.request(bytes.fromhex("0E 01 01 01")) == bytes.fromhex("8E 23 03")
            requests += 1
            value = (value + 1) & 0xFF
            outputs = bytes([value, 0x34, 0x12, 0xCD, 0xAB])
            assert await master.poll(outputs) == outputs  # the loopback wires DO to DI, AO to AI
            polls += 1
        flood_result(flood)
        assert requests > 0 and polls > 0
        # everything the engine got was the master's: one frame per request and per poll
        assert adapter.rx_frames - before == requests + polls
        assert adapter.rx_ignored == 0
        assert gw.read("io/m3/do0") == bool(value & 1)
    finally:
        master.close()
        await gw.stop()
