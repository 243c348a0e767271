"""Issue 34's "done when", against pymodbus's TCP and RTU servers as the devices (independent
peers: their memory is read back from pymodbus, the expected registers computed here from the
order's letters): a byte-swapped float, a 64-bit value, text and a scaled value read into the
image; writes from the Modbus TCP front (pymodbus's client) and from the OPC UA front (asyncua's
client) land in the devices' registers in the order they are read in."""

from __future__ import annotations

import asyncio
import struct
from typing import Any

import pytest
from netkit import free_port
from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType as PmType
from pymodbus.simulator import SimData, SimDevice

from fieldgate import Quality
from fieldgate.testing import wait_for_channel

LONG = {"ABCD": "ABCDEFGH", "CDAB": "GHEFCDAB", "BADC": "BADCFEHG", "DCBA": "HGFEDCBA"}


def words(fmt: str, value: Any, order: str) -> list[int]:
    """A value's registers, laid out as the order's letters say (test-side, independent)."""
    data = struct.pack(fmt, value)
    name = order if len(data) == 4 else LONG[order]
    laid = bytes(data[ord(c) - ord("A")] for c in name)
    return [int.from_bytes(laid[i : i + 2], "big") for i in range(0, len(laid), 2)]


def text(value: str, registers: int) -> list[int]:
    data = value.encode().ljust(2 * registers, b"\0")
    return [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]


ENERGY = -1_234_567_890_123
MEMORY = [0] * 40
MEMORY[0:2] = words(">f", 230.1, "BADC")  # a power meter's voltage, bytes swapped
MEMORY[2:6] = words(">q", ENERGY, "CDAB")  # 64-bit, words swapped
MEMORY[6:12] = text("FG-METER-042", 6)
MEMORY[12] = 235  # 23.5 °C in tenths

CHANNELS = [
    {"kind": "ai", "table": "holding_registers", "address": 0, "type": "float32", "order": "BADC"},
    {"kind": "ai", "table": "holding_registers", "address": 2, "type": "int64", "order": "CDAB"},
    {"kind": "ai", "table": "holding_registers", "address": 6, "type": "string", "length": 12},
    {
        "kind": "ai",
        "table": "holding_registers",
        "address": 12,
        "type": "uint16",
        "divider": 10,
        "decimals": 1,
        "unit": "°C",
        "range": [-40, 125],
    },
    {"kind": "ao", "table": "holding_registers", "address": 20, "type": "float32", "order": "BADC"},
    {"kind": "ao", "table": "holding_registers", "address": 22, "type": "int64", "order": "CDAB"},
    {"kind": "ao", "table": "holding_registers", "address": 26, "type": "string", "length": 8},
    {
        "kind": "ao",
        "table": "holding_registers",
        "address": 30,
        "type": "uint32",
        "order": "CDAB",
        "gain": 0.01,
        "unit": "bar",
        "range": [0, 100],
    },
]


def device() -> SimDevice:
    return SimDevice(
        1,
        simdata=(
            [SimData(0, count=16, values=False, datatype=PmType.BITS)],
            [SimData(0, count=16, values=False, datatype=PmType.BITS)],
            [SimData(0, values=list(MEMORY), datatype=PmType.REGISTERS)],
            [SimData(0, count=40, values=0, datatype=PmType.REGISTERS)],
        ),
    )


async def registers(server: Any, address: int, count: int) -> list[int]:
    """The peer's own memory (pymodbus's datastore), not what fieldgate thinks it wrote."""
    values = await server.context.async_getValues(1, 3, address, count)
    return list(values)


@pytest.fixture
async def peers(fieldgate_pty):
    pair = fieldgate_pty()
    tcp_port = free_port()
    tcp = ModbusTcpServer([device()], address=("127.0.0.1", tcp_port))
    rtu = ModbusSerialServer([device()], framer=FramerType.RTU, port=pair.b, baudrate=115200)
    tasks = [asyncio.ensure_future(tcp.serve_forever()), asyncio.ensure_future(rtu.serve_forever())]
    await asyncio.sleep(0.3)
    yield {"tcp": tcp, "rtu": rtu, "tcp_port": tcp_port, "pty": pair.a}
    await tcp.shutdown()
    await rtu.shutdown()
    for task in tasks:
        task.cancel()


async def test_types_orders_and_scaling_read_and_written_through_both_fronts(
    peers, fieldgate_gateway, tmp_path
):
    from asyncua import Client, ua

    mb_port, ua_port = free_port(), free_port()
    topology = {
        "gateway": {"name": "peer", "state_dir": str(tmp_path)},
        "fronts": [
            {
                "name": "mb",
                "type": "modbus-tcp",
                "listen": f"127.0.0.1:{mb_port}",
                "order": "DCBA",  # the SCADA's own order, unlike either device's
                "writable": ["*/m1/ao0", "*/m1/ao3"],
            },
            {
                "name": "ua",
                "type": "opcua",
                "listen": f"127.0.0.1:{ua_port}",
                "writable": ["*/m1/ao1", "*/m1/ao2"],
            },
        ],
        "backs": [
            {
                "name": "tcp",
                "type": "modbus-tcp-client",
                "host": f"127.0.0.1:{peers['tcp_port']}",
                "poll_ms": 50,
                "modules": [{"address": 1, "channels": CHANNELS}],
            },
            {
                "name": "rtu",
                "type": "modbus",
                "port": peers["pty"],
                "baudrate": 115200,
                "poll_ms": 50,
                "modules": [{"address": 1, "channels": CHANNELS}],
            },
        ],
    }
    async with fieldgate_gateway(topology, simulate=False) as gw:
        for back in ("tcp", "rtu"):
            await wait_for_channel(gw.image, f"{back}/m1/ai3", 23.5, Quality.GOOD)
            assert gw.image.value(f"{back}/m1/ai0") == pytest.approx(230.1, rel=1e-6)
            assert gw.image.value(f"{back}/m1/ai1") == ENERGY
            assert gw.image.value(f"{back}/m1/ai2") == "FG-METER-042"

        # the Modbus TCP front, DCBA: a SCADA writes 12.5 (float32) and 42.42 bar (float view)
        client = AsyncModbusTcpClient("127.0.0.1", port=mb_port)
        await client.connect()
        try:
            front = {p.what: p.address for p in _front_map(gw, "mb")}
            for back in ("tcp", "rtu"):
                for cid, value in ((f"{back}/m1/ao0", 12.5), (f"{back}/m1/ao3", 42.42)):
                    reply = await client.write_registers(
                        front[cid], words(">f", value, "DCBA"), device_id=1
                    )
                    assert not reply.isError(), reply
                # a setpoint outside its range (0..100 bar) is answered 03, nothing written
                reply = await client.write_registers(
                    front[f"{back}/m1/ao3"], words(">f", 150.0, "DCBA"), device_id=1
                )
                assert reply.isError() and reply.exception_code == 3
                # and it reads the device's 64-bit input back in its own order
                reply = await client.read_input_registers(front[f"{back}/m1/ai1"], count=4)
                assert reply.registers == words(">q", ENERGY, "DCBA")
        finally:
            client.close()

        # the OPC UA front: a 64-bit setpoint and a text
        async with Client(f"opc.tcp://127.0.0.1:{ua_port}/", timeout=10) as ua_client:
            idx = await ua_client.get_namespace_index("urn:fieldgate:peer")
            for back in ("tcp", "rtu"):
                await ua_client.get_node(f"ns={idx};s={back}/m1/ao1").write_value(
                    ua.DataValue(ua.Variant(-(2**40) - 3, ua.VariantType.Int64))
                )
                await ua_client.get_node(f"ns={idx};s={back}/m1/ao2").write_value(
                    ua.DataValue(ua.Variant("ÜBER-8", ua.VariantType.String))
                )
            # scaling shows in OPC UA: the unit and the range on the variable itself
            node = ua_client.get_node(f"ns={idx};s=tcp/m1/ai3")
            assert await node.read_value() == 23.5
            eu = await ua_client.get_node(f"ns={idx};s=tcp/m1/ai3/EngineeringUnits").read_value()
            assert eu.DisplayName.Text == "°C"
            rng = await ua_client.get_node(f"ns={idx};s=tcp/m1/ai3/EURange").read_value()
            assert (rng.Low, rng.High) == (-40, 125)
            # text into a 64-bit variable is refused, nothing written
            with pytest.raises(ua.UaStatusCodeError, match="BadTypeMismatch"):
                await ua_client.get_node(f"ns={idx};s=tcp/m1/ao1").write_value(
                    ua.DataValue(ua.Variant("x", ua.VariantType.String))
                )

        expected = {
            20: words(">f", 12.5, "BADC"),
            22: words(">q", -(2**40) - 3, "CDAB"),
            26: text("ÜBER-8", 4),
            30: words(">I", 4242, "CDAB"),  # 42.42 bar / 0.01
        }
        for back in ("tcp", "rtu"):
            server = peers[back]
            for address, want in expected.items():
                deadline = asyncio.get_running_loop().time() + 5
                while await registers(server, address, len(want)) != want:
                    assert asyncio.get_running_loop().time() < deadline, (
                        back,
                        address,
                        await registers(server, address, len(want)),
                        want,
                    )
                    await asyncio.sleep(0.05)


def _front_map(gw: Any, name: str) -> list[Any]:
    from fieldgate.plugins.modbus_tcp.map import ModbusMap

    front = gw.topology.front(name)
    return ModbusMap.from_channels(
        gw.context.front_channels(front), front.writable, front.byte_order
    ).points
