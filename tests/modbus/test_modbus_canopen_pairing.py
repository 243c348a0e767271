"""The I-7232D demo path end to end: CANopen front, Modbus back, simulated modules.

A CANopen master on python-can's virtual bus writes the DO byte with RxPDO1 (seed-000
TV-08: 0x34); the gateway writes it to the M-7055D over Modbus RTU; the simulated bench
wires those DO to the M-7052D's DI; the gateway polls them and sends TxPDO1 with 0x34.
"""

import asyncio
import itertools

import can
import pytest
from modbus_line import I7232D_MODULES

from fieldgate import Gateway

_channels = itertools.count()


async def test_rxpdo1_do_byte_comes_back_as_txpdo1_di_byte(registry, tmp_path):
    if registry.lookup("front", "canopen") is None:
        pytest.skip("the canopen front plugin is not installed")
    channel = f"fg-modbus-pairing-{next(_channels)}"
    topology = {
        "gateway": {"name": "i7232d", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "virtual",
                "channel": channel,
                "node_id": 1,
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 10,
                "timeout_ms": 100,
                "modules": I7232D_MODULES,
            }
        ],
    }
    gateway = Gateway.load(topology, registry=registry, simulate=True, animate=True)
    await gateway.start()
    master = can.Bus(interface="virtual", channel=channel)
    try:
        master.send(
            can.Message(arbitration_id=0x000, data=[0x01, 0x01], is_extended_id=False)
        )  # NMT start node 1
        await asyncio.sleep(0.1)
        master.send(
            can.Message(arbitration_id=0x201, data=[0x34], is_extended_id=False)
        )  # RxPDO1: DO byte
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 5
        di_bytes = []
        while loop.time() < deadline and 0x34 not in di_bytes:
            msg = master.recv(timeout=0)
            if msg is None:
                await asyncio.sleep(0.005)
            elif msg.arbitration_id == 0x181:
                di_bytes.append(msg.data[0])
        assert 0x34 in di_bytes, f"TxPDO1 DI bytes seen: {di_bytes}"
        assert gateway.bench.simulator("rs485").get_output("rs485/m3/do2") is True
        assert [gateway.read(f"rs485/m1/di{i}") for i in range(8)] == [
            False,
            False,
            True,
            False,
            True,
            True,
            False,
            False,
        ]
    finally:
        master.shutdown()
        await gateway.stop()
