"""The python-can adapter on its own: timers on the loop, bit-rate switch, bus state polling."""

from __future__ import annotations

import asyncio
import json
import uuid

import can
import pytest
from canopen_rig import seed_node

from fieldgate.can import adapter as adapter_mod
from fieldgate.can.adapter import CanAdapter, open_bus
from fieldgate.can.busrx import start_receiver
from fieldgate.can.frame import Frame
from fieldgate.plugin import PluginStartError


async def _recv(bus: can.BusABC, can_id: int, timeout: float = 2.0) -> can.Message:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while loop.time() < end:
        msg = await asyncio.to_thread(bus.recv, 0.05)
        if msg is not None and msg.arbitration_id == can_id:
            return msg
    raise AssertionError(f"no {can_id:03X}")


@pytest.fixture
async def setup():
    channel = f"adapter-{uuid.uuid4().hex[:8]}"
    peer = can.Bus(interface="virtual", channel=channel)
    node = seed_node(1, heartbeat_ms=20)
    lost = []
    adapter = CanAdapter(
        node,
        open_bus("virtual", channel, 125000),
        asyncio.get_running_loop(),
        on_bus_state=lambda off, now: (
            lost.append(off),
            node.service("error_control").bus_state(off, now),
        ),
        reopen=lambda rate: open_bus("virtual", channel, rate),
    )
    adapter.start()
    yield adapter, peer, lost
    adapter.close()
    peer.shutdown()


async def test_heartbeat_runs_on_loop_timers(setup):
    adapter, peer, _ = setup
    assert bytes((await _recv(peer, 0x701)).data) == b"\x00"
    beats = [bytes((await _recv(peer, 0x701)).data) for _ in range(3)]
    assert beats == [b"\x7f"] * 3


async def test_bit_rate_switch_reopens_the_bus(setup):
    adapter, peer, _ = setup
    old = adapter.bus
    adapter.node.request_bit_timing(250000, 0.0)
    await asyncio.sleep(0.05)
    assert adapter.bus is not old and adapter.counters["bit_timing_switches"] == 1
    peer.send(
        can.Message(
            arbitration_id=0x601, data=bytes.fromhex("4000140000000000"), is_extended_id=False
        )
    )
    assert bytes((await _recv(peer, 0x581)).data) == bytes.fromhex("4F00140002000000")


async def test_bus_state_error_is_bus_off(setup, monkeypatch):
    adapter, peer, lost = setup
    monkeypatch.setattr(adapter_mod, "STATE_POLL_S", 0.01)
    monkeypatch.setattr(
        type(adapter.bus), "state", property(lambda self: can.BusState.ERROR), raising=False
    )
    adapter._poll_bus_state()
    assert lost == [True]
    monkeypatch.setattr(
        type(adapter.bus), "state", property(lambda self: can.BusState.ACTIVE), raising=False
    )
    adapter._poll_bus_state()
    assert lost == [True, False]
    assert bytes((await _recv(peer, 0x81)).data) == bytes.fromhex("4081110800000000")
    json.dumps(adapter.status())


def test_open_bus_errors_are_one_line():
    with pytest.raises(PluginStartError, match="unknown CAN interface 'nope'"):
        open_bus("nope", "x", 125000)
    with pytest.raises(PluginStartError) as err:
        open_bus("socketcan", "fieldgate-nope0", 125000)
    assert "\n" not in str(err.value)


class RaisingBus(can.BusABC):
    """An interface whose driver fails on receive (no descriptor: a receive thread reads it)."""

    def __init__(self):
        super().__init__(channel="raising")

    def _recv_internal(self, timeout):
        raise can.CanOperationError("interface went down")

    def send(self, msg, timeout=None):
        pass


async def test_dead_receiver_fails_the_adapter(setup):
    adapter, peer, _ = setup

    class FailingReader:
        errors = 0

    real = adapter.receiving.receiver
    try:
        adapter.receiving.receiver = FailingReader()
        adapter.check_receiver()
        FailingReader.errors = 5
        adapter.check_receiver()
        assert not adapter.failed.done()  # a few errors are survivable
        FailingReader.errors = 5 + adapter_mod.RX_ERRORS_FATAL
        adapter.check_receiver()
        assert adapter.failed.done()
        with pytest.raises(RuntimeError, match="CAN receive failed: 100 receive errors"):
            adapter.failed.result()

        adapter.failed = asyncio.get_running_loop().create_future()
        bus = RaisingBus()
        adapter.receiving.receiver = receiver = start_receiver(
            bus, asyncio.get_running_loop(), lambda msg: None
        )
        assert receiver.mode == "thread"
        receiver._thread.join(2)
        assert not receiver._thread.is_alive() and isinstance(
            receiver.exception, can.CanOperationError
        )
        adapter.check_receiver()
        with pytest.raises(RuntimeError, match="interface went down"):
            adapter.failed.result()
        receiver.stop()
        bus.shutdown()
    finally:
        adapter.receiving.receiver = real


async def test_pump_on_every_loop_turn_does_not_postpone_the_timers(setup):
    """An I/O service may flush the node on every loop turn; the heartbeat must still run."""
    adapter, peer, _ = setup
    assert bytes((await _recv(peer, 0x701)).data) == b"\x00"
    loop = asyncio.get_running_loop()
    end = loop.time() + 0.2
    beats = []

    async def collect():
        while loop.time() < end:
            msg = await asyncio.to_thread(peer.recv, 0.05)
            if msg is not None and msg.arbitration_id == 0x701:
                beats.append(bytes(msg.data))

    collector = asyncio.create_task(collect())
    pumps = 0
    while loop.time() < end:
        adapter.pump()
        pumps += 1
        await asyncio.sleep(0)
    await collector
    assert pumps > 100
    assert len(beats) >= 3 and set(beats) == {b"\x7f"}  # 20 ms heartbeat over 200 ms, under load


@pytest.mark.parametrize(
    "frame",
    [
        Frame(0x585, bytes(range(8))),
        Frame(0x185, b"\x01"),
        Frame(0x705, b""),
        Frame(0x705, b"", rtr=True, dlc=1),
    ],
)
def test_frames_become_the_same_messages_as_with_keyword_arguments(frame):
    """to_message builds can.Message positionally for speed: it must match the keyword form field by field."""
    if frame.rtr:
        expected = can.Message(
            arbitration_id=frame.can_id, is_extended_id=False, is_remote_frame=True, dlc=1
        )
    else:
        expected = can.Message(arbitration_id=frame.can_id, is_extended_id=False, data=frame.data)
    got = adapter_mod.to_message(frame)
    for field in can.Message.__slots__:
        if field != "__weakref__":
            assert getattr(got, field) == getattr(expected, field), field
    assert type(got.data) is bytearray
    assert adapter_mod.to_frame(got) == frame


READ_1014 = can.Message(
    arbitration_id=0x601, data=bytes.fromhex("4014100000000000"), is_extended_id=False
)


async def _routed(adapter, peer) -> None:
    """One read through the loop's path, so the node has routed its SDO COB-ID."""
    peer.send(READ_1014)
    assert bytes((await _recv(peer, 0x581)).data)[:4] == bytes.fromhex("43141000")
    assert adapter.receiving.quick(READ_1014)


async def test_quick_answers_stop_while_the_bus_is_reopened_and_after_close(setup):
    adapter, peer, _ = setup
    peer.send(
        can.Message(
            arbitration_id=0x601, data=bytes.fromhex("2B17100000000000"), is_extended_id=False
        )
    )
    assert (
        bytes((await _recv(peer, 0x581)).data)[:1] == b"\x60"
    )  # heartbeat off: no timer falls due
    await _routed(adapter, peer)
    during = []
    reopen = adapter.reopen

    def reopening(rate):
        would = adapter.node.quick_answer(0x601, READ_1014.data, adapter.now) is not None
        during.append(
            (would, adapter.receiving.quick(READ_1014))
        )  # the receive thread of the old bus, late
        return reopen(rate)

    adapter.reopen = reopening
    adapter.node.request_bit_timing(250000, 0.0)
    await asyncio.sleep(0.05)
    assert during == [(True, False)] and adapter.counters["bit_timing_switches"] == 1
    assert adapter.receiving.quick(READ_1014)  # the new bus's receive thread answers again
    adapter.close()
    answered = adapter.quick_answers
    assert not adapter.receiving.quick(READ_1014) and adapter.quick_answers == answered


async def test_a_quick_answer_whose_send_fails_is_not_answered_again(setup):
    adapter, peer, _ = setup
    await _routed(adapter, peer)

    def broken_send(msg, timeout=None):
        raise TypeError("driver bug")

    rx, answered, uploads = (
        adapter.rx_frames,
        adapter.quick_answers,
        adapter.node.service("sdo").expedited_uploads,
    )
    adapter.bus.send = broken_send
    assert adapter.receiving.quick(READ_1014)  # handled: the loop must not read and count it again
    assert (adapter.rx_frames, adapter.quick_answers) == (rx + 1, answered + 1)
    assert adapter.node.service("sdo").expedited_uploads == uploads + 1
    assert adapter.counters["tx_errors"] == 1
