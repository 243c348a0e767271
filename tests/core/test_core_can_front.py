"""core's CAN front base (fieldgate.can.front): a third party's CAN front, the way docs/plugins.md
shows it, is a sans-I/O engine and a few lines of front; the base opens the bus, boots the
engine, runs the wake-ups of one loop turn once, hears module health once per gateway, and
closes the bus at stop."""

from __future__ import annotations

import asyncio
import sys
import uuid
from typing import Literal

import can
import pytest
from pydantic import Field

from fieldgate.can.frame import Frame
from fieldgate.can.front import CanBusConfig, CanFront
from fieldgate.health import ErrorKind, ModuleHealth
from fieldgate.plugin import Registry, hookimpl, load_registry
from fieldgate.runtime import Gateway
from fieldgate.topology import FrontConfig


class EchoConfig(FrontConfig, CanBusConfig):
    type: Literal["echo"] = "echo"
    node: int = Field(1, ge=1, le=127, description="answers on 0x580 + node")


class EchoEngine:
    """Answers 0x600+node with the data reversed on 0x580+node; :meth:`note` queues a frame
    from outside its calls and wakes whoever drives it."""

    def __init__(self, node: int):
        self.node = node
        self.outbox: list[Frame] = []
        self.ticks = 0
        self.listen = frozenset({0x600 + node})
        self.wake = lambda: None

    deadline_after_call = None

    def boot(self, now: float) -> list[Frame]:
        return [Frame(0x700 + self.node, b"\x00")]

    def receive(self, frame: Frame, now: float) -> list[Frame]:
        return [Frame(0x580 + self.node, frame.data[::-1])]

    def tick(self, now: float) -> list[Frame]:
        self.ticks += 1
        return self.flush()

    def flush(self) -> list[Frame]:
        out, self.outbox = self.outbox, []
        return out

    def next_deadline(self) -> float | None:
        return None

    def on_bit_timing(self, callback) -> None:
        pass

    def listen_ids(self) -> frozenset[int]:
        return self.listen

    def on_wake(self, callback) -> None:
        self.wake = callback

    def note(self, value: int) -> None:
        self.outbox.append(Frame(0x180 + self.node, bytes([value])))
        self.wake()


class EchoFront(CanFront):
    def __init__(self, config: EchoConfig, context) -> None:
        super().__init__(config, context)
        self.heard: list[tuple[str, str]] = []

    def build(self) -> EchoEngine:
        return EchoEngine(self.config.node)

    def module_health(self, health, event) -> None:
        self.heard.append((health.back, event.value))


@hookimpl
def fieldgate_register(registry: Registry) -> None:
    registry.add_front("echo", EchoConfig, EchoFront, "echo front of the CanFront test")


@pytest.fixture
async def echo(tmp_path):
    channel = f"echo-{uuid.uuid4().hex[:8]}"
    topology = {
        "gateway": {"name": "echo", "state_dir": str(tmp_path)},
        "fronts": [{"name": "plc", "type": "echo", "interface": "virtual", "channel": channel}],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }
    peer = can.Bus(interface="virtual", channel=channel)
    gateway = Gateway.load(topology, registry=load_registry([sys.modules[__name__]]))
    await gateway.start()
    try:
        yield gateway, gateway.component("plc"), peer
    finally:
        await gateway.stop()
        peer.shutdown()


async def frames(peer: can.BusABC, count: int, timeout: float = 2.0) -> list[tuple[int, bytes]]:
    got: list[tuple[int, bytes]] = []
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while len(got) < count and loop.time() < end:
        msg = await asyncio.to_thread(peer.recv, 0.05)
        if msg is not None:
            got.append((msg.arbitration_id, bytes(msg.data)))
    return got


def test_the_bus_settings_default_to_socketcan_can0_at_125_kbit():
    cfg = EchoConfig(name="plc")
    assert (cfg.interface, cfg.channel, cfg.bitrate, cfg.bus_options) == (
        "socketcan",
        "can0",
        125_000,
        {},
    )


async def test_a_can_front_boots_its_engine_on_the_bus_and_answers(echo):
    gateway, front, peer = echo
    assert await frames(peer, 1) == [(0x701, b"\x00")]
    peer.send(can.Message(arbitration_id=0x601, data=b"\x01\x02\x03", is_extended_id=False))
    assert await frames(peer, 1) == [(0x581, b"\x03\x02\x01")]
    status = gateway.status()["fronts"]["plc"]
    assert front.bus_status()["interface"] == "virtual" and front.bus_status()["bus"]["rx"] == 1
    assert status["restarts"] == 0


async def test_the_wake_ups_of_one_loop_turn_run_the_engine_once(echo):
    _, front, peer = echo
    await frames(peer, 1)  # the boot-up
    engine = front.engine
    ticks = engine.ticks
    for value in range(5):  # e.g. five inputs of one poll reply, each queueing a frame
        engine.note(value)
    await asyncio.sleep(0)  # the next loop turn
    await asyncio.sleep(0)
    assert engine.ticks == ticks + 1
    assert await frames(peer, 5) == [(0x181, bytes([v])) for v in range(5)]


async def test_module_health_is_heard_once_however_often_the_front_restarts(echo):
    gateway, front, _ = echo
    await front.stop()
    await front.start()
    health = gateway.context.health.add(ModuleHealth("io", 7))
    while not health.record_failure(ErrorKind.TIMEOUT, "no answer"):
        pass
    assert front.heard.count(("io", "offline")) == 1


async def test_stop_closes_the_bus_and_run_ends_when_receiving_dies(echo):
    _, front, _ = echo
    adapter = front.adapter
    runner = asyncio.create_task(front.run())
    adapter.fail(can.CanOperationError("interface went down"))
    with pytest.raises(RuntimeError, match="CAN receive failed: interface went down"):
        await asyncio.wait_for(runner, 2.0)
    await front.stop()
    assert front.adapter is None and adapter.closed
