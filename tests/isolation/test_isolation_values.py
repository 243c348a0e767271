"""64-bit integers and text cross the process boundary both ways unchanged: down to a child in
the feed's pickles, up from it in a write's JSON (where the fieldbus process checks each value:
a number or text, nothing else)."""

from __future__ import annotations

import asyncio

from netkit import free_port
from pymodbus.client import AsyncModbusTcpClient

from fieldgate import Gateway, Quality
from fieldgate.isolation import wire
from fieldgate.testing import wait_for_channel

BIG = 2**64 - 1
SMALL = -(2**63)


def test_the_wire_keeps_64_bit_integers_and_text_exact():
    frame = wire.down(("chg", [("x", BIG, "good", 1.0, ""), ("s", "Ünï ✓", "good", None, "")]))
    down = wire.read_down(frame[4:])
    assert down[1][0][1] == BIG and down[1][1][1] == "Ünï ✓"
    body = wire.up({"t": "write", "id": 1, "values": {"a": BIG, "b": SMALL, "c": "Ünï ✓"}})[4:]
    values = wire.read_up(body)["values"]
    assert values == {"a": BIG, "b": SMALL, "c": "Ünï ✓"}
    assert type(values["a"]) is int


def registers(value: int, count: int, signed: bool = False) -> list[int]:
    data = value.to_bytes(2 * count, "big", signed=signed)
    return [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]


async def test_a_child_front_reads_and_writes_64_bit_values_and_text_exactly(registry, tmp_path):
    port = free_port()
    channels = [
        {"kind": "ai", "table": "input_registers", "address": 0, "type": "uint64"},
        {"kind": "ai", "table": "input_registers", "address": 4, "type": "string", "length": 8},
        {"kind": "ao", "table": "holding_registers", "address": 0, "type": "int64"},
        {"kind": "ao", "table": "holding_registers", "address": 4, "type": "string", "length": 8},
    ]
    topology = {
        "gateway": {"name": "iso", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "mb",
                "type": "modbus-tcp",
                "listen": f"127.0.0.1:{port}",
                "writable": ["rs485/m1/ao*"],
            }
        ],
        "backs": [
            {
                "name": "rs485",
                "type": "modbus",
                "port": "/dev/null",
                "baudrate": 115200,
                "poll_ms": 50,
                "modules": [{"address": 1, "channels": channels}],
            }
        ],
    }
    async with Gateway.load(topology, registry=registry, simulate=True) as gw:
        assert gw.bench is not None
        sim = gw.bench.simulator("rs485")
        sim.set_input("rs485/m1/ai0", BIG)
        sim.set_input("rs485/m1/ai1", "Ünï")
        await wait_for_channel(gw.image, "rs485/m1/ai0", BIG, Quality.GOOD)
        client = AsyncModbusTcpClient("127.0.0.1", port=port)
        await client.connect()
        try:
            # down: the child's mirror has the exact values (its map serves them)
            for _ in range(100):
                reply = await client.read_input_registers(0, count=8)
                if reply.registers[:4] == registers(BIG, 4):
                    break
                await asyncio.sleep(0.05)
            assert reply.registers[:4] == registers(BIG, 4)
            assert (
                bytes(b for r in reply.registers[4:] for b in r.to_bytes(2, "big")).rstrip(b"\0")
                == "Ünï".encode()
            )
            # up: a write of the smallest int64 and of text, as JSON, applied exactly
            assert not (await client.write_registers(0, registers(SMALL, 4, True))).isError()
            text = "ÄB✓".encode().ljust(8, b"\0")
            words = [int.from_bytes(text[i : i + 2], "big") for i in range(0, 8, 2)]
            assert not (await client.write_registers(4, words)).isError()
        finally:
            client.close()
        assert gw.read("rs485/m1/ao0") == SMALL
        assert gw.read("rs485/m1/ao1") == "ÄB✓"
        assert gw.image["rs485/m1/ao1"].written_by == "mb"
