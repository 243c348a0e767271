"""End to end on python-can's virtual bus: a master (plain python-can) and the gateway with
the canopen front, first over the loopback test back, then over simulated Modbus modules."""

from __future__ import annotations

import asyncio
import uuid

import can
import pytest

from fieldgate import Gateway, load_registry


def channel() -> str:
    return f"fg-pdo-e2e-{uuid.uuid4().hex[:10]}"


async def wait_for(master: can.BusABC, predicate, timeout: float = 3.0) -> list[can.Message]:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    seen: list[can.Message] = []
    while loop.time() < deadline:
        msg = master.recv(timeout=0)
        if msg is None:
            await asyncio.sleep(0.002)
            continue
        seen.append(msg)
        if predicate(msg):
            return seen
    raise AssertionError(
        f"not seen within {timeout} s: {[(hex(m.arbitration_id), m.data.hex()) for m in seen]}"
    )


def send(master: can.BusABC, can_id: int, data: bytes) -> None:
    master.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))


async def sdo_write(
    master: can.BusABC, node: int, index: int, sub: int, value: int, size: int
) -> None:
    cs = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
    send(
        master,
        0x600 + node,
        bytes([cs, index & 0xFF, index >> 8, sub]) + value.to_bytes(size, "little").ljust(4, b"\0"),
    )
    seen = await wait_for(master, lambda m: m.arbitration_id == 0x580 + node)
    assert seen[-1].data[0] == 0x60, seen[-1].data.hex()


async def test_loopback_di_change_rpdo_and_master_lost(tmp_path):
    ch = channel()
    topology = {
        "gateway": {"name": "e2e", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "virtual",
                "channel": ch,
                "node_id": 3,
                "heartbeat_consumers": 1,  # the icpdas style has none: the master writes 0x1016
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
    gw = Gateway.load(topology, registry=load_registry())
    await gw.start()
    master = can.Bus(interface="virtual", channel=ch)
    try:
        await sdo_write(master, 3, 0x1016, 1, (0x7F << 16) | 150, 4)  # watch the master's heartbeat
        send(master, 0x77F, b"\x05")
        send(master, 0x000, b"\x01\x03")  # (no TPDO at Start in the icpdas style: TV-07)
        await sdo_write(master, 3, 0x1800, 5, 0, 2)  # an SDO round trip: the Start is in
        # RPDO -> DO written -> looped back to DI -> TPDO1 on the bus
        send(master, 0x203, b"\x5a")
        seen = await wait_for(master, lambda m: m.arbitration_id == 0x183 and m.data == b"\x5a")
        assert [m.data for m in seen if m.arbitration_id == 0x183] == [
            b"\x5a"
        ]  # one TPDO for 4 bit changes
        assert [gw.read(f"io/m1/do{i}") for i in range(8)] == [
            False,
            True,
            False,
            True,
            True,
            False,
            True,
            False,
        ]
        # a DI change from the back side alone also goes out
        gw.image.update_input("io/m1/di7", True)
        await wait_for(master, lambda m: m.arbitration_id == 0x183 and m.data == b"\xda")
        # master lost: heartbeat stops -> EMCY 8130 and the outputs go to their error values
        await wait_for(
            master, lambda m: m.arbitration_id == 0x83 and m.data[:2] == b"\x30\x81", timeout=2
        )
        await wait_for(
            master, lambda m: m.arbitration_id == 0x183 and m.data == b"\x80"
        )  # DO -> 0, di7 stays 1
        assert [gw.read(f"io/m1/do{i}") for i in range(8)] == [False] * 8
        assert gw.masters.is_ok("can") is False
    finally:
        master.shutdown()
        await gw.stop()


async def test_modbus_simulated_modules_end_to_end(tmp_path):
    registry = load_registry()
    if registry.lookup("back", "modbus") is None:
        pytest.skip("the modbus back plugin is not installed")
    ch = channel()
    topology = {
        "gateway": {"name": "i7232d", "state_dir": str(tmp_path)},
        "fronts": [
            {"name": "can", "type": "canopen", "interface": "virtual", "channel": ch, "node_id": 1}
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 10,
                "timeout_ms": 100,
                "modules": [
                    {"address": 1, "model": "M-7052D"},
                    {"address": 3, "model": "M-7055D", "counts": {"di": 0}},
                    {"address": 4, "model": "M-7024", "counts": {"ao": 1}},
                    {"address": 5, "model": "M-7017R", "counts": {"ai": 1}},
                ],
            }
        ],
    }
    gw = Gateway.load(topology, registry=registry, simulate=True)
    await gw.start()
    sim = gw.bench.simulator("rs485")
    master = can.Bus(interface="virtual", channel=ch)
    try:
        for index, sub, value, size in (
            (0x6206, 1, 0x31, 1),
            (0x6207, 1, 0xF8, 1),
            (0x6443, 1, 1, 1),
            (0x6444, 1, 0, 4),
            (0x100C, 0, 100, 2),
            (0x100D, 0, 2, 1),
        ):
            await sdo_write(master, 1, index, sub, value, size)
        send(master, 0x000, b"\x01\x01")
        await asyncio.sleep(0.05)
        # a DI change at a simulated module -> TPDO1 on the bus
        sim.set_input("rs485/m1/di6", True)
        await wait_for(master, lambda m: m.arbitration_id == 0x181 and m.data == b"\x40")
        # RPDO -> DO and AO written to the simulated modules
        send(master, 0x201, b"\x0f")
        send(master, 0x301, b"\x34\x12")
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 3
        while loop.time() < deadline and not (
            sim.get_output("rs485/m3/do3") is True and sim.get_output("rs485/m4/ao0") == 0x1234
        ):
            await asyncio.sleep(0.01)
        assert [sim.get_output(f"rs485/m3/do{i}") for i in range(8)] == [True] * 4 + [False] * 4
        assert sim.get_output("rs485/m4/ao0") == 0x1234
        # master lost (life guarding: one RTR, then silence) -> TV-23 error values written to the modules
        master.send(
            can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False)
        )
        await wait_for(
            master, lambda m: m.arbitration_id == 0x81 and m.data[:2] == b"\x30\x81", timeout=2
        )
        deadline = loop.time() + 3
        while loop.time() < deadline and sim.get_output("rs485/m4/ao0") != 0:
            await asyncio.sleep(0.01)
        do = sum(int(sim.get_output(f"rs485/m3/do{i}")) << i for i in range(8))
        assert do == (0x0F & 0xCE) | 0x30 and sim.get_output("rs485/m4/ao0") == 0
    finally:
        master.shutdown()
        await gw.stop()


async def test_fast_changing_input_is_never_starved(tmp_path):
    """An input changing on every loop turn still gives one TPDO per change (no endless coalescing)."""
    ch = channel()
    topology = {
        "gateway": {"name": "e2e", "state_dir": str(tmp_path)},
        "fronts": [
            {"name": "can", "type": "canopen", "interface": "virtual", "channel": ch, "node_id": 2}
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 8}]}],
    }
    gw = Gateway.load(topology, registry=load_registry())
    await gw.start()
    master = can.Bus(interface="virtual", channel=ch)
    try:
        send(master, 0x000, b"\x01\x02")
        await sdo_write(master, 2, 0x1800, 5, 0, 2)  # Operational (no TPDO at Start: TV-07)
        for k in range(50):
            gw.image.update_input("io/m1/di0", not k & 1)
            gw.image.update_input("io/m1/di1", not k & 1)  # two bits in the same turn: one TPDO
            await asyncio.sleep(0)
        seen: list[bytes] = []
        loop = asyncio.get_running_loop()
        end = loop.time() + 1
        while loop.time() < end and len(seen) < 50:
            msg = master.recv(timeout=0)
            if msg is None:
                await asyncio.sleep(0.005)
            elif msg.arbitration_id == 0x182:
                seen.append(msg.data)
        assert seen == [b"\x03", b"\x00"] * 25
    finally:
        master.shutdown()
        await gw.stop()
