"""End to end: examples/i7231d-style.yaml (CANopen front + DCON back) on simulated DCON modules,
wired like the manual's demo bench, driven by a CAN master over python-can's virtual bus
through the first steps of the seed-001 PDO walk-through (TV-P00..P02, P04, P10)."""

import asyncio
import uuid
from pathlib import Path

import can
import pytest

from fieldgate import Gateway

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "i7231d-style.yaml"


class Master:
    def __init__(self, channel):
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.reader = can.AsyncBufferedReader()
        self.notifier = can.Notifier(self.bus, [self.reader], loop=asyncio.get_running_loop())

    def send(self, cob, data="", rtr=False):
        payload = bytes.fromhex(data)
        self.bus.send(
            can.Message(
                arbitration_id=cob,
                data=payload,
                is_extended_id=False,
                is_remote_frame=rtr,
                dlc=0 if rtr else len(payload),
            )
        )

    async def until(self, cob, predicate=lambda data: True, timeout=3.0):
        """The first frame on ``cob`` whose data satisfies ``predicate``; earlier ones are skipped."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise AssertionError(f"no matching frame on 0x{cob:X}")
            try:
                msg = await asyncio.wait_for(self.reader.get_message(), remaining)
            except TimeoutError:
                continue
            if msg.arbitration_id == cob and not msg.is_remote_frame and predicate(bytes(msg.data)):
                return bytes(msg.data)

    def close(self):
        self.notifier.stop()
        self.bus.shutdown()


@pytest.fixture
def registry(dcon_registry):
    if dcon_registry.lookup("front", "canopen") is None:
        pytest.skip("the canopen front plugin is not installed")
    return dcon_registry


async def test_i7231d_example_on_simulated_dcon_modules(registry, tmp_path):
    channel = f"fg-7231d-{uuid.uuid4().hex[:8]}"
    overrides = {
        "fronts.can.channel": channel,
        "fronts.can.node_id": 1,  # the manual's walk-through talks to node 1
        "backs.rs485.poll_ms": 10,
        "backs.rs485.timeout_ms": 150,
        "gateway.state_dir": str(tmp_path),
    }
    gw = Gateway.load(EXAMPLE, overrides, registry, simulate=True)
    await gw.start()
    master = Master(channel)
    try:
        sim = gw.bench.simulator("rs485")
        for n in range(
            16
        ):  # the manual's bench: I-7043 DO n drives I-7053 DI n, a DI reads 1 when OFF
            sim.wire((1, "do", n), (2, "di", n), invert=True)
        sim.wire((3, "ao", 0), (4, "ai", 0))  # I-7021 AO0 -> I-7012 AI0
        sim.set_input("rs485/m4/di0", True)  # I-7012 DI0 OFF
        await asyncio.sleep(0.3)  # first poll cycles
        # P00: NMT start: "No reply. The node goes to OPERATIONAL"; the TxPDO1 read by RTR
        master.send(0x000, "01 01 00 00 00 00 00 00")
        with pytest.raises(AssertionError, match="no matching frame"):
            await master.until(0x181, timeout=0.3)
        master.send(0x181, rtr=True)
        assert await master.until(0x181) == bytes.fromhex("FF FF 01")
        # P01: RxPDO1 writes the I-7043 outputs; the wired I-7053 inputs change -> TxPDO1
        master.send(0x201, "34 12 00 00 00 00 00 00")
        assert await master.until(0x181, lambda d: d == bytes.fromhex("CB ED 01")) == bytes.fromhex(
            "CB ED 01"
        )
        assert sim.module(1).do_bits == 0x1234
        # P02: RxPDO2 writes AO0 = 0x07FF (5 V); read AI0 with an RTR: about 0x3FF5 (a few LSB of "noise")
        master.send(0x301, "FF 07 00 00 00 00 00 00")
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 3
        while True:
            master.send(0x281, rtr=True)
            data = await master.until(0x281)
            if abs(int.from_bytes(data, "little") - 0x3FF5) <= 16 or loop.time() > deadline:
                break
            await asyncio.sleep(0.05)
        assert len(data) == 2 and abs(int.from_bytes(data, "little") - 0x3FF5) <= 16
        assert sim.get_output("rs485/m3/ao0") == 0x07FF
        # P04: RxPDO1 type 0: outputs change only at SYNC
        master.send(0x601, "2F 00 14 02 00 00 00 00")
        await master.until(0x581)
        master.send(0x201, "78 56 00 00 00 00 00 00")
        await asyncio.sleep(0.2)
        assert sim.module(1).do_bits == 0x1234  # not yet
        master.send(0x080)
        assert await master.until(0x181, lambda d: d == bytes.fromhex("87 A9 01")) == bytes.fromhex(
            "87 A9 01"
        )
        assert sim.module(1).do_bits == 0x5678
        # the module status objects: every module online, no errors on the line
        assert all(m["online"] and m["error_counter"] == 0 for m in gw.status()["modules"])
    finally:
        master.close()
        await gw.stop()


async def test_0x2003_clears_a_watchdog_that_ran_out_while_the_master_was_away(registry, tmp_path):
    """The simulated modules model a real one: the host watchdog keeps running while ~** is
    paused, and ~AA1 does not restart it. After the master's return a 0 written to 0x2003
    sends ~** first, then ~AA1: the flag reads 0 at the next poll and stays 0."""
    channel = f"fg-7231d-wd-{uuid.uuid4().hex[:8]}"
    overrides = {
        "fronts.can.channel": channel,
        "fronts.can.node_id": 1,  # the frames below address node 1, as the manual's
        "backs.rs485.poll_ms": 10,
        "backs.rs485.timeout_ms": 150,
        "backs.rs485.modules.0.watchdog.timeout_ms": 300,
        "gateway.state_dir": str(tmp_path),
    }
    gw = Gateway.load(EXAMPLE, overrides, registry, simulate=True)
    await gw.start()
    master = Master(channel)

    async def sdo_read_2003() -> int:
        master.send(0x601, "40 03 20 01 00 00 00 00")
        return (await master.until(0x581, lambda d: d[1:4] == bytes.fromhex("03 20 01")))[4]

    async def poll_until(predicate, timeout=3.0):
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not predicate():
            assert loop.time() < deadline, "condition not met in time"
            await asyncio.sleep(0.02)

    try:
        sim, back = gw.bench.simulator("rs485"), gw.component("rs485")
        await poll_until(lambda: sim.module(1).watchdog_enabled and back.host_ok_sent > 2)
        gw.context.masters.lost("can", "heartbeat timeout")  # as the front reports it
        await poll_until(lambda: back.watchdog_status(1))
        assert await sdo_read_2003() == 1
        gw.context.masters.ok("can")
        master.send(0x601, "2F 03 20 01 00 00 00 00")  # clear
        assert await master.until(0x581) == bytes.fromhex("60 03 20 01 00 00 00 00")
        await poll_until(lambda: not back.watchdog_status(1))
        assert await sdo_read_2003() == 0
        await asyncio.sleep(0.7)  # more than two watchdog timeouts
        assert await sdo_read_2003() == 0 and not sim.module(1).timed_out
    finally:
        master.close()
        await gw.stop()
