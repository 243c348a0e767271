"""End to end: examples/i7241d-style.yaml (DeviceNet front + DCON back) on simulated DCON modules.

I-7055 (8 DI + 8 DO) at 1, I-7017 (8 AI) at 2, I-7024 (4 AO) at 3: the poll consumes DO
(1 byte) + AO (8 bytes) = 9 bytes and produces DI (1) + AI (16) = 17 bytes, so both
directions are I/O-fragmented (seed-003 §2.4).
"""

import asyncio
import uuid
from pathlib import Path

import pytest
from dnet_master import Master

from fieldgate import Gateway, load_registry

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "i7241d-style.yaml"


async def test_i7241d_example_polls_simulated_dcon_modules(tmp_path):
    registry = load_registry()
    if registry.lookup("back", "dcon") is None or registry.lookup("front", "devicenet") is None:
        pytest.skip("the dcon back or devicenet front plugin is not installed")
    channel = f"fg-7241d-{uuid.uuid4().hex[:8]}"
    overrides = {
        "fronts.dnet.interface": "virtual",
        "fronts.dnet.channel": channel,
        "fronts.dnet.dup_mac_timeout_ms": 50,
        "backs.rs485.poll_ms": 10,
        "backs.rs485.timeout_ms": 150,
        "gateway.state_dir": str(tmp_path),
    }
    gw = Gateway.load(EXAMPLE, overrides, registry, simulate=True)
    master = Master(channel, slave=1)
    await gw.start()
    try:
        sim = gw.bench.simulator("rs485")
        for n in range(8):
            sim.wire((1, "do", n), (1, "di", n))
        sim.set_input("rs485/m2/ai3", 0x1234)
        await master.wait_online()
        assert await master.allocate(0x03) == bytes.fromhex("0A CB 00")
        assert await master.request(bytes.fromhex("0E 04 00 02")) == bytes.fromhex(
            "8E 69 00"
        )  # 0x64 DO, 0x65 AO, 0x66 DI, 0x67 AI, 0x68 all outputs, 0x69 all inputs
        assert await master.request(bytes.fromhex("0E 05 02 07")) == bytes.fromhex(
            "8E 11 00"
        )  # produced 17
        assert await master.request(bytes.fromhex("0E 05 02 08")) == bytes.fromhex(
            "8E 09 00"
        )  # consumed 9
        assert await master.request(bytes.fromhex("10 05 02 09 F4 01")) == bytes.fromhex("90 F4 01")
        outputs = bytes([0x5A]) + (0x07FF).to_bytes(2, "little") + bytes(6)
        for _ in range(100):
            inputs = await master.poll_fragmented_reply(outputs, 17)
            if inputs[0] == 0x5A and inputs[7:9] == bytes.fromhex("34 12"):
                break
            await master.frames(0.03)
        assert inputs[0] == 0x5A and inputs[7:9] == bytes.fromhex(
            "34 12"
        )  # DI byte (wired DO) and AI3
        assert sim.module(1).do_bits == 0x5A and sim.get_output("rs485/m3/ao0") == 0x07FF
        assert gw.read("rs485/m1/do1") is True
        await master.frames(2.2)  # no polls for more than 4 x 500 ms
        assert not gw.masters.is_ok("dnet")
        assert sim.module(1).do_bits == 0x5A  # the example's error mode is "hold"
    finally:
        master.close()
        await gw.stop()


MODBUS_EXAMPLE = EXAMPLE.with_name("devicenet-modbus.yaml")


async def test_devicenet_modbus_example_on_simulated_modbus_modules(tmp_path):
    """M-7055D (8 DI + 8 DO) at 1, M-7017R (8 AI) at 2: 1 byte consumed, 17 produced.

    The example's parity E stays as written: simulated (pty) lines run without parity.
    """
    registry = load_registry()
    if registry.lookup("back", "modbus") is None:
        pytest.skip("the modbus back plugin is not installed")
    channel = f"fg-dnmb-{uuid.uuid4().hex[:8]}"
    overrides = {
        "fronts.dnet.interface": "virtual",
        "fronts.dnet.channel": channel,
        "fronts.dnet.dup_mac_timeout_ms": 50,
        "backs.rs485.poll_ms": 10,
        "gateway.state_dir": str(tmp_path),
    }
    gw = Gateway.load(MODBUS_EXAMPLE, overrides, registry, simulate=True)
    master = Master(channel, slave=5)
    await gw.start()
    try:
        # A bound of our own: a stall shows where it happened (the await in the traceback),
        # where pytest-timeout could only show the idle event loop (seen once in CI under load).
        async with asyncio.timeout(60):
            sim = gw.bench.simulator("rs485")
            sim.set_input("rs485/m1/di6", True)
            sim.set_input("rs485/m2/ai7", -2)
            await master.wait_online()
            assert await master.allocate(0x03) == bytes.fromhex("0A CB 00")
            assert await master.request(bytes.fromhex("10 05 02 09 F4 01")) == bytes.fromhex(
                "90 F4 01"
            )
            for _ in range(100):
                inputs = await master.poll_fragmented_reply(bytes([0x81]), 17)
                if (
                    inputs[0] == 0x40
                    and inputs[15:17] == bytes.fromhex("FE FF")
                    and sim.get_output("rs485/m1/do7")
                ):
                    break
                await master.frames(0.03)
            assert inputs[0] == 0x40 and inputs[15:17] == bytes.fromhex("FE FF")
            assert (
                sim.get_output("rs485/m1/do0")
                and sim.get_output("rs485/m1/do7")
                and not sim.get_output("rs485/m1/do1")
            )
    finally:
        master.close()
        await gw.stop()
