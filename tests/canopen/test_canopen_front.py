"""The canopen front inside a Gateway: start errors, master lost, module EMCY, bus-off, status."""

from __future__ import annotations

import asyncio
import json
import uuid

import can
import pytest
from canopen_dut import topology

from fieldgate import Gateway, load_registry
from fieldgate.can.filters import matches
from fieldgate.health import ErrorKind, ModuleHealth
from fieldgate.runtime import GatewayStartError

NODE = 5


@pytest.fixture(scope="module")
def registry():
    return load_registry()


class Peer:
    """The test's side of the virtual bus."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="virtual", channel=channel)

    def send(self, can_id: int, data: bytes = b"", rtr: bool = False, error: bool = False) -> None:
        self.bus.send(
            can.Message(
                arbitration_id=can_id,
                data=data,
                is_remote_frame=rtr,
                is_error_frame=error,
                is_extended_id=False,
                dlc=len(data) if not rtr else 1,
            )
        )

    async def expect(self, can_id: int, timeout: float = 2.0) -> bytes:
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while loop.time() < end:
            msg = await asyncio.to_thread(self.bus.recv, 0.05)
            if msg is not None and msg.arbitration_id == can_id:
                return bytes(msg.data)
        raise AssertionError(f"no frame {can_id:03X} within {timeout} s")

    async def quiet(self, seconds: float) -> list:
        loop = asyncio.get_running_loop()
        end, got = loop.time() + seconds, []
        while loop.time() < end:
            msg = await asyncio.to_thread(self.bus.recv, 0.02)
            if msg is not None:
                got.append(msg)
        return got


@pytest.fixture
async def gw(tmp_path, registry):
    channel = f"front-{uuid.uuid4().hex[:8]}"
    peer = Peer(channel)
    topo = topology(tmp_path / "state", NODE)
    topo["fronts"][0]["channel"] = channel
    gateway = Gateway.load(topo, registry=registry)
    await gateway.start()
    assert await peer.expect(0x700 + NODE) == b"\x00"
    yield gateway, peer
    await gateway.stop()
    peer.bus.shutdown()


async def test_unknown_interface_is_a_one_line_start_error(tmp_path, registry):
    topo = topology(tmp_path, NODE, interface="no-such-can")
    gateway = Gateway.load(topo, registry=registry)
    with pytest.raises(GatewayStartError) as err:
        await gateway.start()
    assert "unknown CAN interface 'no-such-can'" in str(err.value) and "\n" not in str(err.value)


async def test_missing_channel_is_a_start_error(tmp_path, registry):
    topo = topology(tmp_path, NODE, interface="socketcan", channel="fieldgate-missing0")
    gateway = Gateway.load(topo, registry=registry)
    with pytest.raises(GatewayStartError) as err:
        await gateway.start()
    assert "socketcan" in str(err.value) and "\n" not in str(err.value)


async def test_life_guarding_loss_applies_output_error_modes(gw):
    gateway, peer = gw
    gateway.write("io/m3/do2", True)
    peer.send(0x605, bytes.fromhex("2B0C100032000000"))  # guard time 50 ms
    await peer.expect(0x585)
    peer.send(0x605, bytes.fromhex("2F0D100002000000"))  # factor 2
    await peer.expect(0x585)
    peer.send(0x705, rtr=True)
    assert await peer.expect(0x705) == b"\x7f"
    assert await peer.expect(0x85, 1.0) == bytes.fromhex("3081110700000000")
    assert gateway.masters.is_ok("plc") is False
    assert gateway.read("io/m3/do2") is False  # error value 0
    peer.send(0x705, rtr=True)
    await peer.expect(0x705)
    assert await peer.expect(0x85) == bytes(8)
    assert gateway.masters.is_ok("plc") is True


async def test_module_offline_and_back_emcy(gw):
    gateway, peer = gw
    try:
        health = gateway.health.get("io", 3)
    except KeyError:
        health = gateway.health.add(ModuleHealth("io", 3))
    for _ in range(4):
        health.record_failure(ErrorKind.TIMEOUT, "no answer")
    assert await peer.expect(0x85) == bytes.fromhex("00FF810B03000000")
    health.record_failure(ErrorKind.TIMEOUT, "still no answer")
    assert [m for m in await peer.quiet(0.1) if m.arbitration_id == 0x85] == []
    health.record_success()
    assert await peer.expect(0x85) == bytes(8)


async def test_bus_off_error_frames(gw):
    gateway, peer = gw
    # SocketCAN delivers error frames beside the acceptance filters (CAN_RAW_ERR_FILTER);
    # python-can's own filtering on the virtual bus would drop them: open it up here.
    gateway.component("plc").adapter.bus.set_filters(None)
    peer.send(0x40, bytes(8), error=True)
    await asyncio.sleep(0.1)
    assert gateway.masters.is_ok("plc") is False
    peer.send(0x100, bytes(8), error=True)
    assert await peer.expect(0x85) == bytes.fromhex("4081110800000000")
    assert gateway.masters.is_ok("plc") is True


async def test_status_shows_counters(gw):
    gateway, peer = gw
    peer.send(0x605, b"\x40\x00\x10")  # short SDO frame
    peer.send(0x000, b"\x01")  # short NMT frame
    peer.bus.send(can.Message(arbitration_id=0x605, data=bytes(8), is_extended_id=True))
    peer.send(0x605, bytes.fromhex("4000100000000000"))
    await peer.expect(0x585)
    st = gateway.status()["fronts"]["plc"]
    assert "rx_extended_dropped" not in st["bus"]  # the acceptance filters admit 11-bit only
    assert st["bus"]["rx_ignored"] == 0
    filters = [tuple(int(x, 16) for x in f.split("/")) for f in st["bus"]["filters"]]
    assert matches(filters, 0x605) and not matches(filters, 0x181)
    assert st["node_id"] == NODE and st["nmt_state"] == "PRE-OPERATIONAL"
    assert st["services"]["sdo"]["bad_dlc_dropped"] == 1
    assert st["counters"]["nmt_malformed"] == 1
    assert st["bus"]["rx"] >= 3
    json.loads(json.dumps(gateway.status()))  # the CLI and embedding code serialise it


READ_1000 = bytes.fromhex("4000100000000000")


async def test_sdo_reads_are_answered_on_the_receive_thread_and_counted(gw):
    gateway, peer = gw
    for _ in range(20):
        peer.send(0x600 + NODE, READ_1000)
        assert (await peer.expect(0x580 + NODE))[:4] == bytes.fromhex("43001000")
    bus = gateway.status()["fronts"]["plc"]["bus"]
    assert (
        bus["quick_answers"] >= 10
    )  # the first read routes the COB-ID on the loop; a due timer may take one
    assert bus["rx"] >= 20 and bus["tx"] >= 21  # boot-up and answers, whichever thread sent them


async def test_a_read_right_behind_an_nmt_stop_is_never_answered(gw):
    """The receive thread never overtakes a frame the loop has not handled yet."""
    gateway, peer = gw
    for _ in range(25):
        peer.send(0x600 + NODE, READ_1000)
        await peer.expect(0x580 + NODE)  # routed: the next read could be answered quickly
        peer.send(0x000, bytes([0x02, NODE]))  # stop, then at once a read
        peer.send(0x600 + NODE, READ_1000)
        got = await peer.quiet(0.04)
        assert [m for m in got if m.arbitration_id == 0x580 + NODE] == []
        peer.send(0x000, bytes([0x80, NODE]))
    peer.send(0x600 + NODE, READ_1000)
    await peer.expect(0x580 + NODE)  # pre-operational again: answered
    assert gateway.status()["fronts"]["plc"]["counters"]["ignored"] >= 25  # the reads in Stopped


async def test_the_receive_thread_never_waits_for_the_loop(gw):
    gateway, peer = gw
    adapter = gateway.component("plc").adapter
    request = can.Message(arbitration_id=0x600 + NODE, data=READ_1000, is_extended_id=False)
    peer.send(0x600 + NODE, READ_1000)
    await peer.expect(0x580 + NODE)
    assert await asyncio.to_thread(adapter.receiving.quick, request)  # answered on another thread
    assert (await peer.expect(0x580 + NODE))[:4] == bytes.fromhex("43001000")
    with adapter.engine_lock:  # the loop is busy with the engine: declined at once, not waited for
        assert not await asyncio.wait_for(asyncio.to_thread(adapter.receiving.quick, request), 1.0)
    assert all(m.arbitration_id != 0x580 + NODE for m in await peer.quiet(0.05))


async def test_dead_bus_restarts_the_front(tmp_path, registry):
    channel = f"front-{uuid.uuid4().hex[:8]}"
    peer = Peer(channel)
    topo = topology(tmp_path / "state", NODE, channel=channel, restart_backoff_s=0.05)
    gateway = Gateway.load(topo, registry=registry)
    await gateway.start()
    try:
        assert await peer.expect(0x700 + NODE) == b"\x00"
        front = gateway.component("plc")
        front.adapter.fail(can.CanOperationError("interface went down"))
        assert await peer.expect(0x700 + NODE, 3.0) == b"\x00"  # booted again
        assert gateway.status()["fronts"]["plc"]["restarts"] == 1
        peer.send(0x605, bytes.fromhex("4000100000000000"))
        answer = await peer.expect(0x585)
        assert answer[:4] == bytes.fromhex("43001000")  # the new node answers SDO
    finally:
        await gateway.stop()
        peer.bus.shutdown()


@pytest.mark.parametrize(
    "expose, expected",
    [
        (None, 0x000F0191),
        (["io/m3/di*"], 0x00010191),
        (["io/m3/do*", "io/m3/ai*"], 0x00060191),
        (["io/m3/ao*"], 0x00080191),
    ],
)
def test_device_type_is_the_io_layouts(tmp_path, registry, expose, expected):
    """0x1000 has one source, the CiA 401 layout of the channels the front serves."""
    from fieldgate.plugins.canopen.plugin import CanopenFront

    def front(topo):
        gateway = Gateway.load(topo, registry=registry)
        return CanopenFront(gateway.topology.fronts[0], gateway.context)

    topo = topology(tmp_path / "state", NODE, expose=expose)
    served = front(topo)
    assert served.build().od.get(0x1000) == expected == served.io.device_type
    topo["fronts"][0]["identity"]["device_type"] = 0x12345678
    assert front(topo).build().od.get(0x1000) == 0x12345678


@pytest.mark.parametrize(
    "cob_id, ok", [(0x80, True), (0x100, True), (0x601, False), (0x07F, False), (0x701, False)]
)
def test_configured_sync_cob_id_follows_the_restricted_can_id_rule(tmp_path, registry, cob_id, ok):
    from fieldgate.topology import TopologyError

    topo = topology(tmp_path / "state", NODE, sync_cob_id=cob_id)
    if ok:
        assert Gateway.load(topo, registry=registry).topology.fronts[0].sync_cob_id == cob_id
        return
    with pytest.raises(TopologyError) as err:
        Gateway.load(topo, registry=registry)
    assert "sync_cob_id" in str(err.value) and "restricted" in str(err.value)
